"""How the daemon's workers share the stream of triples."""

from __future__ import annotations

from appliance.runtime.workers import share_of_stream


def test_two_workers_take_every_other_triple_one_or_many_take_all() -> None:
    assert share_of_stream(0, 2) == (2, 0)
    assert share_of_stream(1, 2) == (2, 1)
    assert share_of_stream(0, 1) == (1, 0)
    # beyond two workers no state could prove succession (no shared frame): all phases
    assert [share_of_stream(i, 3) for i in range(3)] == [(1, 0)] * 3


def test_freed_memory_is_returned_to_the_kernel() -> None:
    """With the workers' malloc settings a freed burst stays resident (holes between live
    blocks are never trimmed from the top of the heap); release_freed_memory gives it back.
    Run in a child: the settings are process-wide."""
    import subprocess
    import sys

    code = """
import os
import numpy as np
from appliance.runtime.tuning import keep_freed_memory, release_freed_memory
def rss_mb():
    return int(open('/proc/self/statm').read().split()[1]) * os.sysconf('SC_PAGE_SIZE') / 1e6
assert keep_freed_memory()
base = rss_mb()
burst, keep = [], []
for _ in range(1500):  # ~300 KB blocks (one 320x240 float32 field) between small live ones
    burst.append(np.ones(75_000, np.float32))
    keep.append(np.ones(16, np.float32))
del burst
held = rss_mb()
assert release_freed_memory()
print(round(held - base), round(rss_mb() - base))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, timeout=60).stdout.split()
    held, after = (int(v) for v in out)
    assert held > 300  # the burst (450 MB) stayed resident after it was freed
    assert after < 50
