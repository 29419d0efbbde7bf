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

Since the solvers work in one workspace buffer per thread
(:mod:`processing.solvers.variational`), the chain itself hardly allocates: a warm triple
faults 14 pages with these settings or without them (a process after three triples; in
its first hundred triples 107 against 130), and a 120 s one-worker run read the same
(2026-12-07, docs/performance.md). The settings stay because nothing measured says they
cost anything there and the bench's two workers read slightly more pairs/s with them (72.6
against 71.1 pairs/s, three runs each, within their spread).

The price is that the process's resident memory is the high-water mark of its heap: a
burst (a cold start's full pyramid, results queued while the daemon was starved of CPU)
stayed resident for the rest of the run, measured as steps of 130-160 MB in the workers of
a one-hour soak. :func:`release_freed_memory`, called by the workers once a minute,
returns what is free to the kernel; the next triple faults its pages in again (a few
milliseconds once a minute).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import time
from collections.abc import Mapping

#: Seconds between two returns of a process's free heap to the kernel
#: (:func:`release_freed_memory`): the workers' loop and the daemon's main loop.
TRIM_EVERY_S = 60.0

#: Allocations below this come from the heap and are reused; above, from mmap.
MMAP_THRESHOLD_BYTES = 64 * 1024 * 1024
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3

#: mimalloc, the allocator of the Rerun SDK (the daemon's live view) and of the viewer
#: server, returns a freed page to the kernel only once the thread that owns it allocates
#: again after ``purge_delay`` (1000 ms in v3): not a timer, so memory freed after a burst
#: by a thread that then idles stays resident. A browser on the live view is such a burst
#: (the server reads slowly, the SDK holds the stream meanwhile): in a one-hour soak
#: the daemon's mimalloc arenas grew from 9 to 76 MB over an 8-minute browser session and
#: kept 72 MB after it, the second browser added 10 MB more. With purging at free time the
#: same 8 minutes took them from 9 to 63 MB and back to 9 MB when the browser left; the
#: viewer server's anonymous memory three minutes after the browser left was 124 MB
#: against 181 MB. Applied to those two processes only; a value in the environment wins.
MIMALLOC_PURGE_AT_FREE = {"MIMALLOC_PURGE_DELAY": "0"}


def _libc() -> ctypes.CDLL | None:
    name = ctypes.util.find_library("c")
    if name is None:
        return None
    try:
        return ctypes.CDLL(name)
    except OSError:
        return None


def keep_freed_memory(threshold_bytes: int = MMAP_THRESHOLD_BYTES) -> bool:
    """Raise glibc's mmap and trim thresholds; False where that is not possible.

    Safe to call more than once; a no-op on C libraries other than glibc.
    """
    libc = _libc()
    mallopt = getattr(libc, "mallopt", None)
    if mallopt is None:
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    ok = mallopt(_M_MMAP_THRESHOLD, int(threshold_bytes)) == 1
    return bool(mallopt(_M_TRIM_THRESHOLD, int(threshold_bytes)) == 1 and ok)


def release_freed_memory() -> bool:
    """Return the heap's free memory to the kernel (glibc ``malloc_trim(0)``, every arena);
    False where that is not possible (not glibc) or nothing was released."""
    trim = getattr(_libc(), "malloc_trim", None)
    if trim is None:
        return False
    trim.argtypes = (ctypes.c_size_t,)
    trim.restype = ctypes.c_int
    return bool(trim(0) == 1)


def with_mimalloc_purge(env: Mapping[str, str]) -> dict[str, str]:
    """``env`` plus :data:`MIMALLOC_PURGE_AT_FREE` where ``env`` does not set it.

    mimalloc reads its options once, when the library loads: for this process, put the
    result into ``os.environ`` before ``rerun`` is first imported; for a child process,
    pass it as the child's environment.
    """
    return {**MIMALLOC_PURGE_AT_FREE, **env}


class PeriodicTrim:
    """Calls :func:`release_freed_memory` from a loop at most every ``every_s`` seconds.

    For the workers' loop and the daemon's main loop: a burst (results piling up while the
    process was starved of CPU, a slow viewer backing up the live view) otherwise stays
    resident for the rest of a months-long run, glibc keeping freed memory in its arenas.
    """

    def __init__(self, every_s: float = TRIM_EVERY_S) -> None:
        self.every_s = every_s
        self._last = time.monotonic()

    def tick(self) -> None:
        """Trim if ``every_s`` has passed since the last trim (cheap otherwise)."""
        if time.monotonic() - self._last >= self.every_s:
            release_freed_memory()
            self._last = time.monotonic()
