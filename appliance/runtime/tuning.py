"""Process-level tuning for the numerical workload.

glibc serves every allocation above its mmap threshold (128 KiB at start) with a fresh
``mmap`` and returns it with ``munmap`` when freed, so each 320x240 float32 array the
solvers allocate (~300 KiB) arrives as new zero-filled pages and faults them in one by
one. The threshold only grows after a larger block has been freed, so speed depended on
what the process did before: measured on this project's machine, the Brox flow took 46 ms
per 320x240 pair in a fresh process and 30 ms after one Middlebury-sized run; a 120 s
appliance run showed 9.6 million minor page faults and 29 s of system time. Fixing both
thresholds makes the fast case the normal one. Freed memory then stays in the process
(up to the trim threshold), which costs a little resident memory and nothing else.

Still needed after the solvers moved to preallocated workspaces
(:mod:`processing.variational`): without these settings a warm triple of the chain still
took 3700 minor page faults and 8 ms of system time (measured, issue 15), from the
full-size numpy and OpenCV temporaries around the solvers.
"""

from __future__ import annotations

import ctypes
import ctypes.util

#: Allocations below this come from the heap and are reused; above, from mmap.
MMAP_THRESHOLD_BYTES = 64 * 1024 * 1024
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3


def keep_freed_memory(threshold_bytes: int = MMAP_THRESHOLD_BYTES) -> bool:
    """Raise glibc's mmap and trim thresholds; False where that is not possible.

    Safe to call more than once; a no-op on C libraries other than glibc.
    """
    name = ctypes.util.find_library("c")
    if name is None:
        return False
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    ok = mallopt(_M_MMAP_THRESHOLD, int(threshold_bytes)) == 1
    return bool(mallopt(_M_TRIM_THRESHOLD, int(threshold_bytes)) == 1 and ok)
