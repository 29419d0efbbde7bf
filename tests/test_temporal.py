"""Temporal reuse in the chain: warm starts agree with cold starts, and only follow on."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from processing.chain import ChainParameters, ChainState, compute_scene_flow
from tests.plane_sequence import GEOMETRY, PARAMS, REGION, sequence, triple
from tests.scene_flow_plane import SIZE


def _mean_velocity(result) -> np.ndarray:
    valid = result.valid[REGION]
    return result.velocity[REGION][valid].astype(np.float64).mean(axis=0)


@pytest.mark.parametrize("stride", [1, 2])
def test_warm_started_results_agree_with_cold_ones(stride: int) -> None:
    """Bounds: flow within 0.05 px, d within 0.05 px, d' within 0.02 px (median over the
    region), mean velocity within 2 % and 1 deg of the cold start of the same triple."""
    seq = sequence(3 + 2 * stride)
    state = ChainState(stride=stride)
    results = [compute_scene_flow(*triple(seq, k), GEOMETRY, PARAMS, state)
               for k in range(0, 2 * stride + 1, stride)]
    assert [r.warm for r in results] == [False, True, True]
    assert (state.warm_starts, state.cold_starts) == (2, 1)
    for k, warm in zip(range(0, 2 * stride + 1, stride), results, strict=True):
        cold = compute_scene_flow(*triple(seq, k), GEOMETRY, PARAMS)
        assert not cold.warm
        for a, b, bound in ((warm.flow, cold.flow, 0.05), (warm.disparity, cold.disparity, 0.05),
                            (warm.disparity_change, cold.disparity_change, 0.02)):
            assert np.median(np.abs(a[REGION] - b[REGION])) < bound
        vw, vc = _mean_velocity(warm), _mean_velocity(cold)
        assert abs(np.linalg.norm(vw) / np.linalg.norm(vc) - 1) < 0.02
        cos = vw @ vc / np.linalg.norm(vw) / np.linalg.norm(vc)
        assert np.degrees(np.arccos(min(cos, 1.0))) < 1.0


def test_non_consecutive_triple_never_uses_a_warm_start() -> None:
    seq = sequence(8)
    state = ChainState()
    assert not compute_scene_flow(*triple(seq, 0), GEOMETRY, PARAMS, state).warm
    assert compute_scene_flow(*triple(seq, 1), GEOMETRY, PARAMS, state).warm
    # A dropped frame (triple 3 after triple 1), a repeated and an earlier triple: cold.
    for k in (3, 3, 1):
        res = compute_scene_flow(*triple(seq, k), GEOMETRY, PARAMS, state)
        assert not res.warm, k
    # A stride-1 state does not take a triple two frames on as consecutive.
    assert not compute_scene_flow(*triple(seq, 3), GEOMETRY, PARAMS, state).warm
    assert compute_scene_flow(*triple(seq, 4), GEOMETRY, PARAMS, state).warm
    # A stride-2 state takes exactly the triple two frames on.
    s2 = ChainState(stride=2)
    compute_scene_flow(*triple(seq, 0), GEOMETRY, PARAMS, s2)
    assert not compute_scene_flow(*triple(seq, 1), GEOMETRY, PARAMS, s2).warm
    assert compute_scene_flow(*triple(seq, 3), GEOMETRY, PARAMS, s2).warm


def test_warm_start_can_be_switched_off_and_the_state_reset() -> None:
    seq = sequence(5)
    off = dataclasses.replace(PARAMS, warm_start=False)
    state = ChainState()
    for k in range(3):
        assert not compute_scene_flow(*triple(seq, k), GEOMETRY, off, state).warm
    state = ChainState()
    compute_scene_flow(*triple(seq, 0), GEOMETRY, PARAMS, state)
    state.reset()
    assert not compute_scene_flow(*triple(seq, 1), GEOMETRY, PARAMS, state).warm


def test_cold_every_bounds_a_warm_run() -> None:
    """Every cold_every-th triple of an unbroken warm run starts cold (so a wrong state
    cannot live longer), and the run counts again from there."""
    seq = sequence(9)
    params = dataclasses.replace(PARAMS, cold_every=3)
    state = ChainState()
    warm = [compute_scene_flow(*triple(seq, k), GEOMETRY, params, state).warm
            for k in range(7)]
    assert warm == [False, True, True, False, True, True, False]
    assert (state.warm_starts, state.cold_starts) == (4, 3)
    never = dataclasses.replace(PARAMS, cold_every=0)
    state = ChainState()
    assert [compute_scene_flow(*triple(seq, k), GEOMETRY, never, state).warm
            for k in range(4)] == [False, True, True, True]


@pytest.mark.parametrize("keep", [True, False])
def test_a_scheduled_restart_goes_on_from_the_previous_flow(
        keep: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    """At a scheduled restart the disparity starts cold; the flow starts from the previous
    triple's whole-frame flow with the warm options (``restart_keeps_flow``), or from zero
    with the cold ones. A triple that does not follow on starts all cold either way."""
    import processing.chain.driver as driver

    starts: list[tuple[np.ndarray | None, dict]] = []
    solve = driver.brox_optical_flow

    def spy(*args, initial_flow=None, **kwargs):
        starts.append((initial_flow, kwargs))
        return solve(*args, initial_flow=initial_flow, **kwargs)

    monkeypatch.setattr(driver, "brox_optical_flow", spy)
    seq = sequence(9)
    params = dataclasses.replace(PARAMS, cold_every=3, restart_keeps_flow=keep)
    state = ChainState()
    results = [compute_scene_flow(*triple(seq, k), GEOMETRY, params, state) for k in range(4)]
    assert [r.warm for r in results] == [False, True, True, False]
    restart, options = starts[3]
    if keep:
        assert restart is not None and restart.shape == (*SIZE, 2)
        np.testing.assert_array_equal(restart, results[2].flow)
        assert options["n_levels"] == params.warm_flow_options["n_levels"]
    else:
        assert restart is None and "n_levels" not in options
    compute_scene_flow(*triple(seq, 6), GEOMETRY, params, state)  # a gap: all cold
    assert starts[4][0] is None and state.restart_flow is None


def test_bad_restart_keeps_flow_raises() -> None:
    with pytest.raises(ValueError, match="restart_keeps_flow must be true or false"):
        ChainParameters(restart_keeps_flow=1)  # type: ignore[arg-type]


@pytest.mark.parametrize("bad", [-1, 2.5, True, "3"])
def test_bad_cold_every_raises(bad: object) -> None:
    with pytest.raises(ValueError, match="cold_every"):
        ChainParameters(cold_every=bad)  # type: ignore[arg-type]


@pytest.mark.parametrize("bad", [-1, 2.5, True, "3"])
def test_bad_registration_pause_after_raises(bad: object) -> None:
    with pytest.raises(ValueError, match="registration_pause_after"):
        ChainParameters(registration_pause_after=bad)  # type: ignore[arg-type]


def test_bad_stride_raises() -> None:
    with pytest.raises(ValueError, match="stride"):
        ChainState(stride=3)


def test_each_frame_is_corrected_and_rectified_once_with_the_same_result() -> None:
    """Curves and rectification maps: the chain's per-frame cache gives exactly the
    differential images of pre-processing the raw triple directly."""
    from processing.calibration.radiometric import CharacteristicCurve
    from processing.preprocess.stereo_triple import preprocess_stereo

    seq = sequence(4)
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
        res = compute_scene_flow(*triple(seq, k), geo, params, state)
        left, right, _ = triple(seq, k)
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
    from processing.preprocess.stereo_triple import preprocess_stereo
    from processing.preprocess.translation import warp_translation

    left, right, times = sequence(6)
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
        res = compute_scene_flow(*triple(seq, k), GEOMETRY, params, state)
        lk, rk, _ = triple(seq, k)
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


def test_a_scene_change_starts_cold_and_is_not_carried_into_the_next_triples() -> None:
    """A jump of the whole picture (a bumped camera, the simulated scene's loop, a garbled
    frame): the triple is flagged ``scene_change`` and solved cold, and the triple after it
    starts cold as well; then warm starts resume."""
    left, right, times = sequence(9)
    rng = np.random.default_rng(5)
    for frames in (left, right):  # frame 4: garbled, random counts all over the picture
        frames[4] = rng.integers(0, 60000, frames[4].shape).astype(np.uint16)
    seq = (left, right, times)
    state = ChainState()
    results = [compute_scene_flow(*triple(seq, k), GEOMETRY, PARAMS, state) for k in range(7)]
    cut = ["scene_change" in r.summary.flags for r in results]
    assert cut[2] or cut[3] or cut[4]  # a triple containing frame 4
    assert not any(cut[:2]) and not any(cut[5:])
    first = cut.index(True)
    assert not results[first].warm and not results[first + 1].warm
    assert results[-1].warm
    assert (state.warm_starts + state.cold_starts) == 7


@pytest.mark.parametrize("cameras", [(0,), (0, 1)])
def test_a_flat_field_shutter_is_levelled_out(cameras: tuple[int, ...]) -> None:
    """From frame 4 on, one camera (or both) reads 5000 counts more everywhere, as after a
    flat-field shutter: the differential images lose that step (the median of the
    difference), so every triple reads as without the shutter (within 1 %: the plane moves
    everywhere, so its difference's median of 20 counts is left as it is without the
    shutter), warm, no scene change. Without the levelling the triple across the step reads
    the plane's mean velocity 3 % (one camera) and 26 % (both) off. The triple whose D(t1)
    spans the step (frames 2-4) reports it, flagged, for the stepped cameras alone; no
    other triple does, so a health count counts each step once."""
    seq = sequence(9)
    left, right, times = sequence(9)
    for cam in cameras:
        frames = (left, right)[cam]
        for k in range(4, 9):
            frames[k] = frames[k] + np.uint16(5000)
    stepped = (left, right, times)
    plain, shut = ChainState(), ChainState()
    for k in range(7):
        a = compute_scene_flow(*triple(seq, k), GEOMETRY, PARAMS, plain)
        b = compute_scene_flow(*triple(stepped, k), GEOMETRY, PARAMS, shut)
        assert b.warm == a.warm and "scene_change" not in b.summary.flags
        va, vb = _mean_velocity(a), _mean_velocity(b)
        assert np.linalg.norm(vb - va) < 0.01 * np.linalg.norm(va), k
        stepped_cams = [cam for cam in (0, 1) if b.offset_steps[cam]]
        assert stepped_cams == (list(cameras) if k == 2 else []), (k, b.offset_steps)
        assert ("offset_levelled" in b.summary.flags) == (k == 2), k
        assert a.offset_steps == (0.0, 0.0) and "offset_levelled" not in a.summary.flags


def test_a_warm_object_walking_in_is_not_a_scene_change() -> None:
    """A hot square (0.4 % of the picture, far stronger than the plane's changes) walks
    into both views from frame 4 on: it is not a jump of the whole picture, so the warm
    starts go on."""
    left, right, times = sequence(9)
    for frames in (left, right):
        for k in range(4, 9):
            x = 20 + 3 * (k - 4)
            frames[k][100:116, x:x + 16] = 60000
    seq = (left, right, times)
    state = ChainState()
    results = [compute_scene_flow(*triple(seq, k), GEOMETRY, PARAMS, state) for k in range(7)]
    assert not any("scene_change" in r.summary.flags for r in results)
    assert all(r.warm for r in results[1:])


def test_a_scene_change_is_strong_and_spread_over_the_picture() -> None:
    """More than SCENE_CHANGE_FACTOR times the tracked scale, on more than
    SCENE_CHANGE_SHARE of one differential image: a scene change; strong on a small part
    (an object) or spread but weak (a shift the registration rejected): not; no tracked
    scale, no test."""
    from processing.chain.scene_change import SCENE_CHANGE_SHARE
    from processing.preprocess.normalisation import DiffScaleTracker

    rng = np.random.default_rng(3)
    quiet = [rng.normal(0.0, 0.3, (128, 160)).astype(np.float32) for _ in range(4)]

    def cut(images: list[np.ndarray]) -> bool:
        return state.scene_change(state.scale_target(images, first=False), images)

    state = ChainState()
    assert not state.scene_change(None, quiet)
    state.scale = DiffScaleTracker(1.0)
    assert not cut(quiet)
    spot = [q.copy() for q in quiet]
    spot[3][40:50, 40:60] = 12.0  # 1 % of the picture at 12x the scale: an object
    assert not cut(spot)
    weak = [q.copy() for q in quiet]
    weak[1] += 1.5  # one camera's whole picture 1.5x the scale brighter
    assert not cut(weak)
    shutter = [q.copy() for q in quiet]
    shutter[1] += 4.0
    assert cut(shutter)
    edge = [q.copy() for q in quiet]
    rows = int(np.ceil(2 * SCENE_CHANGE_SHARE * 128)) + 2  # every 2nd row is sampled
    edge[0][:rows] = 4.0
    assert cut(edge)
    edge[0][:rows - 6] = 0.0  # now just under the share
    assert not cut(edge)


def test_a_registration_that_keeps_failing_pauses_with_the_same_results() -> None:
    """Every shift of the moving plane is rejected (it is all the texture there is): after
    ``registration_pause_after`` of them in a row a camera's shifts are taken as rejected
    without an estimate, every PROBE_EVERY-th is estimated all the same, and every result
    and flag is what estimating each shift gives."""
    from processing.chain.state import PROBE_EVERY

    seq = sequence(16)
    runs = {}
    for pause in (0, 2):
        params = dataclasses.replace(PARAMS, register=True, max_jitter_px=1e-6,
                                     registration_pause_after=pause)
        state = ChainState()
        runs[pause] = [compute_scene_flow(*triple(seq, k), GEOMETRY, params, state)
                       for k in range(14)], state
    (estimated, s0), (paused, s2) = runs[0], runs[2]
    for a, b in zip(estimated, paused, strict=True):
        assert a.summary.flags == b.summary.flags and "registration_rejected" in a.summary.flags
        assert a.rejected_shifts == b.rejected_shifts
        for f in ("flow", "disparity", "disparity_change", "velocity", "gas_mask"):
            np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    assert s0.shifts_paused == 0
    # 15 new shifts per camera: the first 2 estimated, then 1 probe per PROBE_EVERY
    assert s2.shifts_paused == 2 * (15 - 2 - (15 - 2) // PROBE_EVERY)
    assert s2.rejected_run == {0: 15, 1: 15}


def test_an_applied_shift_ends_the_pause() -> None:
    """The state's side of the pause: a paused camera's shifts come back as rejected
    (and go to the memo for the other worker), a probe is left to estimate, and one applied
    shift makes the camera estimate every shift again; the other camera is not affected."""
    from processing.chain.state import PROBE_EVERY
    from processing.preprocess.differential import PreprocessedTriple

    img = np.zeros((4, 4), np.float32)

    def triple(shift: tuple[float, float], rejected: bool) -> PreprocessedTriple:
        return PreprocessedTriple(img, img, img, img, ((0.0, 0.0), shift), int(rejected),
                                  (False, rejected))

    state = ChainState()
    # rejected: 2 to start the pause, PROBE_EVERY - 1 paused, a probe that is applied, then
    # every shift estimated again
    left_rejects = [True] * (1 + PROBE_EVERY) + [False, True, True]
    asked = []
    for k, reject in enumerate(left_rejects):
        times = (float(k), float(k + 1), float(k + 2))
        known = state.known_shifts(times, pause_after=2)
        asked.append(known[0][1] is None)
        est = [triple((0.0, 0.0) if reject else (0.3, 0.0), reject), triple((0.1, 0.0), False)]
        est = [e if known[c][1] is None else dataclasses.replace(e, rejected=(False, False))
               for c, e in enumerate(est)]
        state.remember_shifts(times, known, est)
        assert known[1][1] is None  # the right camera's shifts are applied: never paused
    assert asked == [True] * 2 + [False] * (PROBE_EVERY - 1) + [True] * 3
    assert state.shifts_paused == PROBE_EVERY - 1 and state.rejected_run == {0: 2, 1: 0}
    assert state.shifts.get(0, 11.0, 12.0) == ((0.0, 0.0), True)  # the last paused one
