"""Process-wide allocator tuning for the per-frame FE update.

An update allocates and frees tens of multi-megabyte temporaries (element tangents, stiffness
blocks). glibc returns each freed block to the OS (mmap/munmap) and the next allocation pays
a page fault per 4 KiB touched: measured on the coarse Diamond, that is half the time of a
corotational tangent. Keeping freed memory in the heap removes it. Called by the command line
and the benchmarks; a library user may call it too. A no-op where glibc is absent.
"""

from __future__ import annotations

import ctypes
import ctypes.util

# mallopt parameters (glibc malloc.h) and the values used, in bytes.
_M_TRIM_THRESHOLD, _M_TOP_PAD, _M_MMAP_THRESHOLD = -1, -2, -3
_SETTINGS = {_M_MMAP_THRESHOLD: 256 << 20, _M_TRIM_THRESHOLD: 1 << 30, _M_TOP_PAD: 64 << 20}


def keep_freed_memory() -> bool:
    """Ask glibc to keep freed memory for reuse; True if it accepted."""
    name = ctypes.util.find_library("c")
    if name is None:
        return False
    try:
        mallopt = ctypes.CDLL(name).mallopt
    except (OSError, AttributeError):
        return False
    return all(mallopt(param, value) == 1 for param, value in _SETTINGS.items())
