"""The process that compiles the chain's kernels computes what later processes, which load
them from numba's cache, compute: to the bit.

``fastmath`` kernels compiled into a caller (the solvers' data terms and SOR sweeps under
:func:`processing.solvers.lagged.lagged_iterations`, the segmentation's region statistics
under :func:`processing.segmentation.level_set.descend`) were optimised together with that
caller when compiled fresh and bound separately from the cache: the first run after an
install or a code change read other numbers than every run after it (flow 0.006 px mean,
single pixels up to 6 px after warm starts, the level set up to 0.17). A reprocessed archive
must read the same whichever process ran it first.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent

# Six warm triples of the analytic bench input through the whole chain (registration, depth
# gate, both solvers, segmentation); every array of every result is saved.
_RUN_CHAIN = """
import sys
import numpy as np
from appliance.evaluation.bench_input import blob_frames, geometry, iter_triples
from processing.chain import ChainParameters, ChainState, compute_scene_flow

frames = blob_frames(n_frames=8)
geo, params, state = geometry(frames.image_size), ChainParameters(), ChainState()
triples = iter_triples(frames)
out = {}
for i in range(6):
    result = compute_scene_flow(*next(triples), geo, params, state)
    for name in ("flow", "disparity", "disparity_change", "velocity", "gas_mask", "phi"):
        out[f"{name}{i}"] = np.asarray(getattr(result, name))
np.savez(sys.argv[1], **out)
"""


def _run(cache: Path, out: Path) -> dict[str, np.ndarray]:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), PYTHONPATH=str(ROOT))
    subprocess.run([sys.executable, "-c", _RUN_CHAIN, str(out)], env=env, cwd=ROOT,
                   check=True, timeout=600)
    with np.load(out) as saved:
        return dict(saved)


def test_the_compiling_process_computes_what_the_cached_ones_compute(tmp_path) -> None:
    cache = tmp_path / "numba-cache"  # empty: the first process compiles every kernel
    compiled = _run(cache, tmp_path / "compiled.npz")
    assert any(cache.rglob("*.nbc")), "the first process left no compiled kernel behind"
    cached = _run(cache, tmp_path / "cached.npz")
    assert compiled.keys() == cached.keys()
    differ = [k for k in compiled
              if not np.array_equal(compiled[k], cached[k], equal_nan=True)]
    assert not differ, f"compiled and cached kernels differ in {differ}"
    # The run measured something: a gas mask and a moving flow.
    assert any(compiled[f"gas_mask{i}"].any() for i in range(6))
    assert np.nanmax(np.abs(compiled["flow5"])) > 1.0
