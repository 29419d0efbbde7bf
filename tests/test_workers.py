"""How the daemon's workers share the stream of triples."""

from __future__ import annotations

import pickle
from types import SimpleNamespace

import numpy as np
import pytest

from appliance.runtime.worker_result import WorkerResult, pack_result
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
from appliance.memory import keep_freed_memory, release_freed_memory
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


def _chain_result(h: int = 6, w: int = 8) -> SimpleNamespace:
    """The attributes of a SceneFlowResult that pack_result reads."""
    mask = np.zeros((h, w), bool)
    mask[2:4, 3:6] = True
    return SimpleNamespace(
        summary=SimpleNamespace(to_dict=lambda: {"valid": True}), timings_ms={"flow": 1.0},
        dt_s=0.033, diff_scale=1.0, rejected_shifts=0, warm=True, offset_steps=(0.0, 0.0),
        diff_left=np.full((3, h, w), 0.5), diff_right=np.full((3, h, w), 0.5),
        flow=np.ones((h, w, 2), np.float32), disparity=np.full((h, w), 4.0, np.float32),
        disparity_change=np.zeros((h, w), np.float32),
        velocity=np.ones((h, w, 3), np.float32), valid=np.ones((h, w), bool), gas_mask=mask,
        position=np.ones((h, w, 3), np.float32))


@pytest.mark.parametrize("fields", [True, False])
def test_a_result_without_fields_keeps_what_every_result_needs(fields: bool) -> None:
    base = WorkerResult(worker=0, pair_indices=(0, 1, 2), t_mono_ns=(0, 1, 2), t_wall_ns=0,
                        skipped=0, done_mono_ns=0)
    raw = np.zeros((6, 8), np.uint16)
    res = pack_result(_chain_result(), base, raw_left=raw, fields=fields)  # type: ignore[arg-type]
    # the leak events (gas mask, flow at the gas pixels), the arrows and the summary travel
    # always
    assert res.gas_mask is not None and res.summary == {"valid": True}
    assert res.gas_flow is not None and res.gas_flow.shape == (6, 2)
    np.testing.assert_array_equal(res.gas_flow, _chain_result().flow[res.gas_mask])
    assert res.points3d is not None and len(res.points3d) == 6 and res.warm
    heavy = (res.flow, res.velocity, res.disparity, res.disparity_change, res.valid,
             res.diff_left, res.diff_right, res.raw_left)
    assert res.has_fields is fields
    assert all((a is not None) is fields for a in heavy)


def test_a_result_without_fields_is_a_tenth_of_the_bytes_to_send() -> None:
    sizes = {}
    for fields in (True, False):
        base = WorkerResult(worker=0, pair_indices=(0, 1, 2), t_mono_ns=(0, 1, 2),
                            t_wall_ns=0, skipped=0, done_mono_ns=0)
        res = pack_result(_chain_result(240, 320), base,  # type: ignore[arg-type]
                          raw_left=np.zeros((240, 320), np.uint16), fields=fields)
        sizes[fields] = len(pickle.dumps(res, protocol=pickle.HIGHEST_PROTOCOL))
    assert sizes[True] > 2.5e6 and sizes[False] < 0.1 * sizes[True], sizes


@pytest.mark.parametrize("camera", ["left", "right"])
def test_a_single_camera_result_says_which_camera_stepped(camera: str) -> None:
    """The single-camera chain levels a camera's offset step out of I_diff(N + 1) as the
    stereo chain does, and its result reports it for that camera alone (the health count)."""
    from scipy import ndimage

    from appliance.runtime.single_camera import mono_triple
    from appliance.runtime.worker_result import pack_single

    rng = np.random.default_rng(3)
    base = 20000 + 300 * ndimage.gaussian_filter(rng.standard_normal((120, 160)), 3)
    frames = [base, np.roll(base, 1, axis=1), np.roll(base, 2, axis=1) + 500]
    imgs = [np.clip(f + rng.normal(0, 2, f.shape), 0, 65535).astype(np.uint16) for f in frames]
    results = []
    for stepped in (imgs, [*imgs[:2], imgs[1]]):
        tr = mono_triple(0, stepped, scale=200.0, register=False, denoise_lambda=2.0)
        res = WorkerResult(worker=0, pair_indices=(0, 1, 2), t_mono_ns=(0, 1, 2), t_wall_ns=0,
                           skipped=0, done_mono_ns=3)
        pack_single(tr, res, camera)
        results.append((tr.offset_step1, res.offset_levelled))
    (step, levelled), (none, quiet) = results
    assert step == pytest.approx(-500, abs=20) and none == 0.0
    assert levelled == ((True, False) if camera == "left" else (False, True))
    assert quiet == (False, False)
