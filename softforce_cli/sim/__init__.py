"""Synthetic recordings: scenarios, ground truth, the virtual RGB-D camera."""
