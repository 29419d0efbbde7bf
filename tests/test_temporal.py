"""Temporal reuse in the chain: warm starts agree with cold starts, and only follow on."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from processing.chain import ChainParameters, ChainState, StereoGeometry, compute_scene_flow
from tests.scene_flow_plane import B_M, PP, S_PX, SIZE, render, texture

GEOMETRY = StereoGeometry(
    camera_constant=S_PX, principal_point=PP, baseline=B_M, image_size=(SIZE[1], SIZE[0])
)
# temporal_weight 0: this file tests the warm start alone; with the d' coherence filter
# (processing.stereo.coherence) a warm triple also blends the previous d' on purpose.
PARAMS = ChainParameters(register=False, disparity_init="d0", d0=60.0, temporal_weight=0.0)
V_TRUE = np.array([0.3, -0.2, -0.5])
DT = 1 / 30
REGION = (slice(20, -20), slice(110, -20))  # seen by both cameras, away from borders


def _sequence(n: int) -> tuple[list[np.ndarray], list[np.ndarray], list[float]]:
    """n stereo frames (16-bit counts) of a textured plane at 2 m moving with V_TRUE."""
    tex = texture(0)
    left, right = [], []
    for k in range(n):
        z = 2.0 + V_TRUE[2] * DT * k
        shift = (V_TRUE[0] * DT * k, V_TRUE[1] * DT * k)
        for frames, cam_x in ((left, 0.0), (right, B_M)):
            frames.append(np.rint(1000.0 + 20000.0 * render(tex, z, shift, cam_x))
                          .astype(np.uint16))
    return left, right, [10.0 + k * DT for k in range(n)]


def _triple(seq: tuple, k: int) -> tuple:
    left, right, times = seq
    return left[k:k + 3], right[k:k + 3], times[k:k + 3]


def _mean_velocity(result) -> np.ndarray:
    valid = result.valid[REGION]
    return result.velocity[REGION][valid].astype(np.float64).mean(axis=0)


@pytest.mark.parametrize("stride", [1, 2])
def test_warm_started_results_agree_with_cold_ones(stride: int) -> None:
    """Bounds: flow within 0.05 px, d within 0.05 px, d' within 0.02 px (median over the
    region), mean velocity within 2 % and 1 deg of the cold start of the same triple."""
    seq = _sequence(3 + 2 * stride)
    state = ChainState(stride=stride)
    results = [compute_scene_flow(*_triple(seq, k), GEOMETRY, PARAMS, state)
               for k in range(0, 2 * stride + 1, stride)]
    assert [r.warm for r in results] == [False, True, True]
    assert (state.warm_starts, state.cold_starts) == (2, 1)
    for k, warm in zip(range(0, 2 * stride + 1, stride), results, strict=True):
        cold = compute_scene_flow(*_triple(seq, k), GEOMETRY, PARAMS)
        assert not cold.warm
        for a, b, bound in ((warm.flow, cold.flow, 0.05), (warm.disparity, cold.disparity, 0.05),
                            (warm.disparity_change, cold.disparity_change, 0.02)):
            assert np.median(np.abs(a[REGION] - b[REGION])) < bound
        vw, vc = _mean_velocity(warm), _mean_velocity(cold)
        assert abs(np.linalg.norm(vw) / np.linalg.norm(vc) - 1) < 0.02
        cos = vw @ vc / np.linalg.norm(vw) / np.linalg.norm(vc)
        assert np.degrees(np.arccos(min(cos, 1.0))) < 1.0


def test_non_consecutive_triple_never_uses_a_warm_start() -> None:
    seq = _sequence(8)
    state = ChainState()
    assert not compute_scene_flow(*_triple(seq, 0), GEOMETRY, PARAMS, state).warm
    assert compute_scene_flow(*_triple(seq, 1), GEOMETRY, PARAMS, state).warm
    # A dropped frame (triple 3 after triple 1), a repeated and an earlier triple: cold.
    for k in (3, 3, 1):
        res = compute_scene_flow(*_triple(seq, k), GEOMETRY, PARAMS, state)
        assert not res.warm, k
    # A stride-1 state does not take a triple two frames on as consecutive.
    assert not compute_scene_flow(*_triple(seq, 3), GEOMETRY, PARAMS, state).warm
    assert compute_scene_flow(*_triple(seq, 4), GEOMETRY, PARAMS, state).warm
    # A stride-2 state takes exactly the triple two frames on.
    s2 = ChainState(stride=2)
    compute_scene_flow(*_triple(seq, 0), GEOMETRY, PARAMS, s2)
    assert not compute_scene_flow(*_triple(seq, 1), GEOMETRY, PARAMS, s2).warm
    assert compute_scene_flow(*_triple(seq, 3), GEOMETRY, PARAMS, s2).warm


def test_warm_start_can_be_switched_off_and_the_state_reset() -> None:
    seq = _sequence(5)
    off = dataclasses.replace(PARAMS, warm_start=False)
    state = ChainState()
    for k in range(3):
        assert not compute_scene_flow(*_triple(seq, k), GEOMETRY, off, state).warm
    state = ChainState()
    compute_scene_flow(*_triple(seq, 0), GEOMETRY, PARAMS, state)
    state.reset()
    assert not compute_scene_flow(*_triple(seq, 1), GEOMETRY, PARAMS, state).warm


def test_cold_every_bounds_a_warm_run() -> None:
    """Every cold_every-th triple of an unbroken warm run starts cold (so a wrong state
    cannot live longer), and the run counts again from there."""
    seq = _sequence(9)
    params = dataclasses.replace(PARAMS, cold_every=3)
    state = ChainState()
    warm = [compute_scene_flow(*_triple(seq, k), GEOMETRY, params, state).warm
            for k in range(7)]
    assert warm == [False, True, True, False, True, True, False]
    assert (state.warm_starts, state.cold_starts) == (4, 3)
    never = dataclasses.replace(PARAMS, cold_every=0)
    state = ChainState()
    assert [compute_scene_flow(*_triple(seq, k), GEOMETRY, never, state).warm
            for k in range(4)] == [False, True, True, True]


@pytest.mark.parametrize("bad", [-1, 2.5, True, "3"])
def test_bad_cold_every_raises(bad: object) -> None:
    with pytest.raises(ValueError, match="cold_every"):
        ChainParameters(cold_every=bad)  # type: ignore[arg-type]


def test_bad_stride_raises() -> None:
    with pytest.raises(ValueError, match="stride"):
        ChainState(stride=3)


def test_each_frame_is_corrected_and_rectified_once_with_the_same_result() -> None:
    """Curves and rectification maps: the chain's per-frame cache gives exactly the
    differential images of pre-processing the raw triple directly."""
    from processing.calibration.radiometric import CharacteristicCurve
    from processing.preprocess.differential import preprocess_stereo

    seq = _sequence(4)
    h, w = SIZE
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    maps = (xx + 0.3, yy - 0.2)  # a small rectifying shift
    curves = (CharacteristicCurve(offset=900.0, gain=2.0e4, curvature=-300.0),
              CharacteristicCurve(offset=1100.0, gain=1.9e4))
    geo = dataclasses.replace(GEOMETRY, maps_left=maps, maps_right=maps,
                              curve_left=curves[0], curve_right=curves[1])
    params = dataclasses.replace(PARAMS, diff_scale=0.01)
    state = ChainState()
    for k in range(2):
        res = compute_scene_flow(*_triple(seq, k), geo, params, state)
        left, right, _ = _triple(seq, k)
        pl, pr = preprocess_stereo(left, right, scale=0.01, curves=curves, maps=(maps, maps),
                                   register=False)
        for got, want in ((res.diff_left, (pl.diff0, pl.diff1)),
                          (res.diff_right, (pr.diff0, pr.diff1))):
            np.testing.assert_array_equal(got[0], want[0])
            np.testing.assert_array_equal(got[1], want[1])
    assert state.frames_reused == 4  # t1, t2 of both cameras in the second triple


@pytest.mark.parametrize(("register", "max_jitter_px", "moving"),
                         [(False, 1.5, True), (True, 1e-6, True), (True, 1.5, False)])
def test_a_difference_left_on_its_grid_is_reused_with_the_same_result(
        register: bool, max_jitter_px: float, moving: bool) -> None:
    """D(t1) of a triple that left t1 unmoved (registration off, or every shift rejected:
    the moving plane) is D(t0) of the next: taken from the state, the differential images
    are exactly those of pre-processing each triple on its own with the same shifts;
    accepted jitter (the still plane) moves t1, and the difference is computed anew."""
    from processing.preprocess.differential import preprocess_stereo
    from processing.preprocess.translation import warp_translation

    left, right, times = _sequence(6)
    if not moving:
        left, right = [left[0]] * 6, [right[0]] * 6
    rng = np.random.default_rng(5)
    left = [np.rint(warp_translation(f.astype(np.float32), tuple(rng.uniform(-0.3, 0.3, 2))))
            .astype(np.uint16) for f in left]
    seq = (left, right, times)
    params = dataclasses.replace(PARAMS, register=register, max_jitter_px=max_jitter_px,
                                 diff_scale=500.0, depth_gate=False)  # the diffs as made
    state = ChainState()
    for k in range(4):
        res = compute_scene_flow(*_triple(seq, k), GEOMETRY, params, state)
        lk, rk, _ = _triple(seq, k)
        pl, pr = preprocess_stereo(lk, rk, scale=500.0, register=register,
                                   shift01=(res.shifts_left[0], res.shifts_right[0]),
                                   shift12=(res.shifts_left[1], res.shifts_right[1]))
        for got, want in ((res.diff_left, (pl.diff0, pl.diff1)),
                          (res.diff_right, (pr.diff0, pr.diff1))):
            np.testing.assert_array_equal(got[0], want[0])
            np.testing.assert_array_equal(got[1], want[1])
        assert (res.shifts_left[0] != (0.0, 0.0)) == (register and not moving)
    if moving:
        assert state.differences_reused == 6  # both cameras in triples 1-3
    else:  # the left camera's t1 moved in every triple: its D(t1) is not kept
        assert 0 not in state.differences


def test_shift_memo_answers_only_the_exact_frame_pair() -> None:
    from processing.chain.shifts import LocalShiftMemo

    memo = LocalShiftMemo(capacity=4)
    memo.put(0, 1.0, 2.0, (0.1, 0.0), False)
    memo.put(1, 1.0, 2.0, (0.0, 0.0), True)
    state = ChainState(shifts=memo)
    assert state.known_shifts((0.0, 1.0, 2.0)) == ((None, ((0.1, 0.0), False)),
                                                   (None, ((0.0, 0.0), True)))
    assert state.known_shifts((1.0, 2.0, 3.0)) == ((((0.1, 0.0), False), None),
                                                   (((0.0, 0.0), True), None))
    assert state.known_shifts((2.0, 3.0, 4.0)) == ((None, None), (None, None))
    assert state.shifts_reused == 4
    for k in range(8):  # bounded: the oldest entries go
        memo.put(0, 10.0 + k, 11.0 + k, (0.0, 0.0), False)
    assert memo.get(0, 1.0, 2.0) is None and memo.get(0, 17.0, 18.0) is not None


@pytest.mark.parametrize("shared", ["local", "multiprocessing"])
def test_two_workers_sharing_shifts_give_identical_results_with_half_the_estimates(
        shared: str) -> None:
    """Two states at stride 2 (the daemon's two workers) with one shift memo: every triple
    after the first takes one shift per camera from the other worker, and every result
    (fields, rejections) is bit-identical to workers that estimate all their shifts."""
    import multiprocessing

    from appliance.runtime.shiftshare import SharedShiftMemo, create_shift_table
    from processing.chain.shifts import LocalShiftMemo

    left, right, times = _sequence(8)
    rng = np.random.default_rng(3)
    # sub-pixel camera jitter on both cameras (what registration removes)
    from processing.preprocess.translation import warp_translation
    left = [np.rint(warp_translation(f.astype(np.float32), tuple(rng.uniform(-0.3, 0.3, 2))))
            .astype(np.uint16) for f in left]
    right = [np.rint(warp_translation(f.astype(np.float32), tuple(rng.uniform(-0.3, 0.3, 2))))
             .astype(np.uint16) for f in right]
    seq = (left, right, times)
    params = dataclasses.replace(PARAMS, register=True)
    memo = (LocalShiftMemo() if shared == "local"
            else SharedShiftMemo(create_shift_table(multiprocessing.get_context("spawn"))))
    together = [ChainState(stride=2, shifts=memo) for _ in range(2)]
    apart = [ChainState(stride=2) for _ in range(2)]
    for k in range(6):
        a = compute_scene_flow(*_triple(seq, k), GEOMETRY, params, together[k % 2])
        b = compute_scene_flow(*_triple(seq, k), GEOMETRY, params, apart[k % 2])
        assert a.shifts_left == b.shifts_left and a.shifts_right == b.shifts_right
        assert a.rejected_shifts == b.rejected_shifts
        for f in ("flow", "disparity", "disparity_change", "velocity"):
            np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    assert sum(s.shifts_reused for s in together) == 2 * 5  # one per camera, triples 1-5
    assert sum(s.shifts_reused for s in apart) == 0


def test_a_scene_change_starts_cold_and_is_not_carried_into_the_next_triples() -> None:
    """A jump of the whole picture (flat-field shutter, bumped camera, the simulated scene's
    loop): the triple is flagged ``scene_change`` and solved cold, and the triple after it
    starts cold as well; then warm starts resume."""
    left, right, times = _sequence(9)
    for frames in (left, right):  # frame 4: an offset jump of both cameras (a shutter)
        frames[4] = frames[4] + np.uint16(30000)
    seq = (left, right, times)
    state = ChainState()
    results = [compute_scene_flow(*_triple(seq, k), GEOMETRY, PARAMS, state) for k in range(7)]
    cut = ["scene_change" in r.summary.flags for r in results]
    assert cut[2] or cut[3] or cut[4]  # a triple containing frame 4
    assert not any(cut[:2]) and not any(cut[5:])
    first = cut.index(True)
    assert not results[first].warm and not results[first + 1].warm
    assert results[-1].warm
    assert (state.warm_starts + state.cold_starts) == 7


@pytest.mark.parametrize("register", [False, True])
def test_two_workers_sharing_differences_give_identical_results(register: bool) -> None:
    """Two states at stride 2 with one shared image table (the daemon's two workers, a
    spawn context's shared memory): where t1 stayed on its grid (registration off, or every
    shift of the moving plane rejected) each triple after the first takes D(t0) of both
    cameras from the other worker, and every result is bit-identical to workers that
    differentiate every pair themselves."""
    import multiprocessing

    from appliance.runtime.imageshare import SharedImages, create_image_table
    from processing.chain.shifts import LocalShiftMemo

    seq = _sequence(9)
    params = dataclasses.replace(PARAMS, register=register, max_jitter_px=1e-6)
    table = create_image_table(multiprocessing.get_context("spawn"), SIZE)
    memo = LocalShiftMemo()
    together = [ChainState(stride=2, shifts=memo, images=SharedImages(table))
                for _ in range(2)]
    apart = [ChainState(stride=2, shifts=memo) for _ in range(2)]
    for k in range(7):
        a = compute_scene_flow(*_triple(seq, k), GEOMETRY, params, together[k % 2])
        b = compute_scene_flow(*_triple(seq, k), GEOMETRY, params, apart[k % 2])
        for f in ("diff_left", "diff_right"):
            for x, y in zip(getattr(a, f), getattr(b, f), strict=True):
                np.testing.assert_array_equal(x, y)
        for f in ("flow", "disparity", "disparity_change", "velocity", "gas_mask"):
            np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    assert sum(s.differences_reused for s in together) == 6 * 2  # triples 1-6, both cameras
    assert sum(s.differences_reused for s in apart) == 0


def test_shared_images_answer_the_exact_key_and_keep_the_newest() -> None:
    """A shared table returns copies for the exact key and image count only, ignores
    images it cannot hold, and a new entry replaces the one written longest ago; a worker
    process reads what another wrote."""
    import multiprocessing

    from appliance.runtime.imageshare import SLOTS, SharedImages, create_image_table
    from processing.chain.images import difference_key

    def key(camera: int, t: float, settings: tuple = (1.0, None, 2.0)) -> tuple:
        return difference_key(camera, t, t + 1.0, (0.0, 0.0), settings)

    ctx = multiprocessing.get_context("spawn")
    table = create_image_table(ctx, (4, 5))
    share = SharedImages(table)
    a = np.arange(20, dtype=np.float32).reshape(4, 5)
    share.put(key(0, 1.0), (a, a + 1))
    got = share.get(key(0, 1.0), 2)
    assert got is not None
    np.testing.assert_array_equal(got[0], a)
    np.testing.assert_array_equal(got[1], a + 1)
    got[0][:] = -1  # a copy: the table keeps its entry
    np.testing.assert_array_equal(share.get(key(0, 1.0), 2)[0], a)
    assert share.get(key(1, 1.0), 2) is None  # other camera
    assert share.get(key(0, 1.0, (1.0, None, 3.0)), 2) is None  # other settings
    assert share.get(key(0, 1.0), 1) is None  # other count
    share.put(key(0, 3.0), (np.zeros((5, 4), np.float32),))  # another size
    share.put(key(0, 4.0), (a.astype(np.float64),))  # another type
    assert share.get(key(0, 3.0), 1) is None and share.get(key(0, 4.0), 1) is None
    share.put(key(0, 5.0), (a,))
    for t in range(SLOTS - 1):  # the first entry is now the one written longest ago
        share.put(key(1, 10.0 + t), (a,))
    assert share.get(key(0, 1.0), 2) is None and share.get(key(0, 5.0), 1) is not None
    child = ctx.Process(target=_put_in_child, args=(table,))
    child.start()
    child.join(timeout=60)
    assert child.exitcode == 0
    got = share.get(difference_key(1, 99.0, 100.0, (0.5, 0.0), "x"), 1)
    assert got is not None and float(got[0].sum()) == 7.0 * 20


def _put_in_child(table) -> None:
    from appliance.runtime.imageshare import SharedImages
    from processing.chain.images import difference_key

    SharedImages(table).put(difference_key(1, 99.0, 100.0, (0.5, 0.0), "x"),
                            (np.full((4, 5), 7.0, np.float32),))
