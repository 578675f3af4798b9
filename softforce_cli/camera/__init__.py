"""RealSense capture (live and from .bag/.db3 files)."""
