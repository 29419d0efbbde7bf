"""The active region: the box the solvers work on during a warm run."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from appliance.evaluation.bench_input import blob_frames, geometry
from processing.chain import ChainParameters, ChainState, compute_scene_flow
from processing.chain.region import (
    Box,
    bounding_box,
    choose_region,
    measured_area,
    paste_fields,
    right_shift,
)
from processing.chain.state import WarmStart


def test_bounding_box_grows_by_the_margin_and_snaps_outwards_to_the_grid() -> None:
    mask = np.zeros((240, 320), bool)
    mask[100:121, 50:91] = True
    box = bounding_box(mask, margin_px=10, align=8)
    assert box == Box(88, 136, 40, 104)
    assert box.mask(mask.shape)[mask].all()


def test_bounding_box_is_clipped_to_the_frame_and_none_when_empty() -> None:
    mask = np.zeros((240, 320), bool)
    assert bounding_box(mask, margin_px=10) is None
    mask[0, 319] = True
    assert bounding_box(mask, margin_px=30) == Box(0, 32, 288, 320)


def test_the_right_crop_is_shifted_by_the_smallest_disparity_but_stays_in_the_frame() -> None:
    d = np.full((240, 320), 40.0, np.float32)
    d[100, 200] = 31.7
    assert right_shift(Box(80, 160, 120, 240), d).shift == 31
    assert right_shift(Box(80, 160, 16, 240), d).shift == 16
    box = right_shift(Box(80, 160, 16, 240), d)
    assert box.right == (slice(80, 160), slice(0, 224))


def test_a_box_over_most_of_the_frame_means_the_whole_frame() -> None:
    rng = np.random.default_rng(1)
    shape = (240, 320)
    diff = (0.5 + 0.01 * rng.standard_normal(shape)).astype(np.float32)
    flow = np.zeros((*shape, 2), np.float32)
    d = np.full(shape, 30.0, np.float32)
    wide = np.zeros(shape, bool)
    wide[10:230, 10:310] = True
    assert choose_region((diff, diff), flow, d, wide, margin_px=8, max_fraction=0.7) is None
    small = np.zeros(shape, bool)
    small[100:140, 100:160] = True
    box = choose_region((diff, diff), flow, d, small, margin_px=8, max_fraction=0.7)
    assert box is not None and box.fraction(shape) < 0.2
    assert box.mask(shape)[small].all()


def test_the_next_start_keeps_the_motion_outside_the_box_the_result_does_not() -> None:
    shape = (60, 80)
    previous = WarmStart(flow=np.full((*shape, 2), -3.0, np.float32),
                         disparity=np.full(shape, 30.0, np.float32),
                         change=np.full(shape, 0.2, np.float32))
    box = Box(20, 40, 16, 48, shift=10)
    flow = np.full((20, 32, 2), -2.5, np.float32)
    d = np.full((20, 32), 21.0, np.float32)  # the box's disparity, less its shift
    dd = np.full((20, 32), 0.3, np.float32)
    (r_flow, r_d, r_dd), (s_flow, s_d, s_dd) = paste_fields(box, flow, d, dd, previous)
    inside = box.mask(shape)
    for f, ch in ((r_flow, -2.5), (s_flow, -2.5)):
        assert (f[inside] == ch).all()
    assert (r_flow[~inside] == 0).all() and (r_dd[~inside] == 0).all()
    # A box that grows next time starts its new pixels from their last motion, not from none.
    assert (s_flow[~inside] == -3.0).all() and (s_dd[~inside] == np.float32(0.2)).all()
    assert (r_d[inside] == 31.0).all() and (r_d[~inside] == 30.0).all()
    assert s_d is r_d


def test_without_a_box_the_fields_are_the_next_start() -> None:
    flow = np.ones((8, 8, 2), np.float32)
    d = np.ones((8, 8), np.float32)
    measured, start = paste_fields(None, flow, d, d, None)
    assert all(a is b for a, b in zip(measured, start, strict=True))


@pytest.fixture(scope="module")
def blob_runs() -> dict[bool, list]:
    frames = blob_frames(n_frames=10)
    geo = geometry()
    out = {}
    for on in (False, True):
        params = ChainParameters(active_region=on, d0=20.0, region_margin_px=16)
        state = ChainState()
        out[on] = [
            compute_scene_flow(list(frames.left[k:k + 3]), list(frames.right[k:k + 3]),
                               frames.times_s[k:k + 3], geo, params, state)
            for k in range(len(frames.times_s) - 2)
        ]
    return out


def test_warm_triples_solve_only_the_box_and_flag_the_rest_unmeasured(blob_runs) -> None:
    runs = blob_runs[True]
    assert runs[0].region is None  # cold start: nothing says yet where the gas is
    boxed = [r for r in runs if r.region is not None]
    assert boxed, "no warm triple used the active region"
    for r in boxed:
        y0, y1, x0, x1 = r.region
        outside = np.ones(r.valid.shape, bool)
        outside[y0:y1, x0:x1] = False
        assert not r.valid[outside].any()
        assert not r.gas_mask[outside].any()
        assert not r.flow[outside].any()
    assert all(r.region is None for r in blob_runs[False])


def test_the_boxed_fields_agree_with_the_whole_frame_on_the_gas(blob_runs) -> None:
    for full, boxed in zip(blob_runs[False], blob_runs[True], strict=True):
        if boxed.region is None:
            continue
        gas = full.gas_mask & boxed.gas_mask
        assert gas.sum() > 500
        flow_err = np.linalg.norm(full.flow[gas] - boxed.flow[gas], axis=-1)
        assert np.median(flow_err) < 0.1
        assert np.median(np.abs(full.disparity[gas] - boxed.disparity[gas])) < 0.2
        # The masks differ more (the level set sees no motion outside the box: the reason
        # the active region is off by default); bounded so that a worse one fails.
        overlap = gas.sum() / max(full.gas_mask.sum(), boxed.gas_mask.sum())
        assert overlap > 0.5


def test_the_measured_area_leaves_out_the_box_outside_and_the_border_strip() -> None:
    shape = (240, 320)
    assert measured_area(shape, None, 0) is None
    area = measured_area(shape, None, 3)
    assert area is not None
    assert not area[:3].any() and not area[-3:].any()
    assert not area[:, :3].any() and not area[:, -3:].any()
    assert area[3:-3, 3:-3].all()
    boxed = measured_area(shape, Box(0, 120, 100, 320), 3)
    assert boxed is not None
    assert boxed.sum() == (120 - 3) * (320 - 3 - 100)


def _shaken(frames: list[np.ndarray], shifts: list[tuple[float, float]]) -> list[np.ndarray]:
    """Each frame translated by its (dx, dy) px, as a shaking camera would see it."""
    out = []
    for f, (dx, dy) in zip(frames, shifts, strict=True):
        m = np.float32([[1, 0, dx], [0, 1, dy]])
        moved = cv2.warpAffine(f.astype(np.float32), m, (f.shape[1], f.shape[0]),
                               flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
        out.append(np.rint(moved).astype(np.uint16))
    return out


def test_no_gas_and_no_velocity_in_the_strip_the_registration_filled() -> None:
    frames = blob_frames(n_frames=3)
    shake = [(0.0, 0.0), (0.6, -0.5), (-0.4, 0.7)]
    left = _shaken([frames.left[i] for i in range(3)], shake)
    right = _shaken([frames.right[i] for i in range(3)], shake)
    res = compute_scene_flow(left, right, frames.times_s[:3], geometry(frames.image_size),
                             ChainParameters())
    moved = max(abs(v) for s in (*res.shifts_left, *res.shifts_right) for v in s)
    assert moved > 0.3  # the registration did warp the frames
    b = int(np.ceil(moved)) + 2
    strip = ~measured_area(res.valid.shape, None, b)
    assert not (res.gas_mask & strip).any()
    assert not (res.valid & strip).any() and not (res.u_sf_valid & strip).any()
    # the rest of the frame is still measured
    assert res.valid[~strip].mean() > 0.5
