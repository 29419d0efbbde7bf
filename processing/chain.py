"""The single entry point of the scene-flow chain (paper Sec. 4, Fig. 2).

:func:`compute_scene_flow` takes three consecutive stereo pairs of raw frames (t0, t1, t2)
with their capture times, the stereo geometry and the parameters, and returns one
:class:`SceneFlowResult` with every field, the gas mask, the per-frame summary and the
time spent in each stage. The daemon's workers, ``ogiflow replay``, the evaluations and
the benchmarks all call this function, so a number measured in one is the number the
others produce.

Stages (paper section / equation):

1. pre-processing (4.1): radiometric correction, rectification, jitter registration,
   differential images I_diff(t0) = I(t0) - I(t1) and I_diff(t1) = I(t1) - I(t2) (Eq. 2),
   Sobolev denoising, one normalisation to [0, 1] shared by both cameras;
2. optical flow w_L between the left differential images (4.2, Eq. 5);
3. initial disparity (SGM or the minimum disparity d0), then joint d_L, d'_L (4.3, Eq. 6);
4. 3D velocity V and the virtual gas surface (Eq. 4) with dt from the timestamps, and the
   quality U_SF (Eq. 7), in one compiled pass (:mod:`processing.pixelwise`);
5. gas segmentation (4.4, Eq. 9) of the left differential image with the flow;
6. per-frame summary over the gas region, with c_USF (Eq. 8).

The frame interval of Eq. 4 is the time between the centres of the two differential
images, dt = ((t1 + t2) - (t0 + t1)) / 2 = (t2 - t0) / 2, taken from the timestamps.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from processing.baselines import sgbm_initial_disparity
from processing.calibration.radiometric import CharacteristicCurve, band_radiance
from processing.chain_parameters import (
    ChainParameters,
)
from processing.coherence import smooth_disparity_change
from processing.depth_gate import apply_gate, out_of_band_motion
from processing.disparity import joint_disparity
from processing.disturbances import preprocess_flags
from processing.normalisation import DiffScaleTracker, pooled_quantile
from processing.optical_flow import brox_optical_flow
from processing.pixelwise import velocity_and_quality
from processing.preprocess import (
    apply_rectification,
    differential_image,
    preprocess_stereo,
    radiometric_correction,
    rescale_differences,
    scale_samples,
)
from processing.quality import c_usf
from processing.segmentation import segment_gas
from processing.stereo_geometry import Maps, StereoGeometry
from processing.summary import GasSummary, summarize_frame
from processing.temporal import (
    ChainState,
    corrected_frames,
    known_shifts,
    remember,
    remember_shifts,
    solver_options,
    warm_start,
)

__all__ = ["ChainParameters", "ChainState", "SceneFlowResult", "StereoGeometry",
           "compute_scene_flow", "frame_interval", "initial_scale"]

@dataclass(frozen=True)
class SceneFlowResult:
    """Everything the chain computed for one triple; fields of the left view, (H, W).

    Attributes
    ----------
    times_s : (float, float, float)
        Capture times of the three pairs in s (any common origin).
    dt_s : float
        Frame interval used in Eq. 4, (t2 - t0) / 2.
    diff_left, diff_right : (ndarray, ndarray)
        Normalised differential images at t0 and t1, float32 in [0, 1].
    flow : ndarray, shape (H, W, 2), float32
        w_L in px (Eq. 5).
    disparity, disparity_change : ndarray, float32
        d_L and d'_L in px (Eq. 6; x_R = x_L - d).
    velocity : ndarray, shape (H, W, 3), float32
        V in m/s, left camera frame (X right, Y down, Z forward) (Eq. 4); 0 where invalid.
    position : ndarray, shape (H, W, 3), float32
        Virtual gas surface (X, Y, Z) in m; 0 where invalid.
    valid : ndarray of bool
        Pixels where V is defined (d > 0, d + d' > 0, finite).
    u_sf : ndarray, float32
        Quality U_SF (Eq. 7) at the gas pixels (NaN elsewhere); ``u_sf_valid`` marks gas
        pixels whose warps stayed inside.
    gas_mask : ndarray of bool
        Segmented gas region Omega_g (Eq. 9); ``phi`` is its embedding function.
    summary : GasSummary
        Mean velocity, speed, directional angles, pixel counts, c_USF (Eq. 8).
    diff_scale : float
        Normalisation scale used for this triple.
    shifts_left, shifts_right : ((dx, dy), (dx, dy))
        Jitter removed (t0->t1, t1->t2) in px.
    rejected_shifts : int
        Registration estimates (of 4) not applied because they exceeded max_jitter_px:
        non-zero means the background offers no static texture to register on.
    timings_ms : dict
        Wall time per stage in ms, and "total".
    warm : bool
        True when the solvers started from the previous triple (:mod:`processing.temporal`).
    """

    times_s: tuple[float, float, float]
    dt_s: float
    diff_left: tuple[np.ndarray, np.ndarray]
    diff_right: tuple[np.ndarray, np.ndarray]
    flow: np.ndarray
    disparity: np.ndarray
    disparity_change: np.ndarray
    velocity: np.ndarray
    position: np.ndarray
    valid: np.ndarray
    u_sf: np.ndarray
    u_sf_valid: np.ndarray
    gas_mask: np.ndarray
    phi: np.ndarray
    summary: GasSummary
    diff_scale: float
    shifts_left: tuple[tuple[float, float], tuple[float, float]]
    shifts_right: tuple[tuple[float, float], tuple[float, float]]
    rejected_shifts: int
    timings_ms: dict[str, float]
    warm: bool = False


def frame_interval(times_s: Sequence[float]) -> float:
    """dt of Eq. 4 from three capture times: (t2 - t0) / 2, checked to be increasing."""
    if len(times_s) != 3:
        raise ValueError(f"need 3 capture times (t0, t1, t2), got {len(times_s)}")
    t0, t1, t2 = (float(t) for t in times_s)
    if not (np.isfinite([t0, t1, t2]).all() and t0 < t1 < t2):
        raise ValueError(f"capture times must be finite and increasing, got {(t0, t1, t2)}")
    return (t2 - t0) / 2.0


def gas_radiance(params: ChainParameters,
                 geometry: StereoGeometry) -> tuple[float | None, float]:
    """(L_g, contrast floor) in radiance units for the optical-depth differential images,
    or (None, 0) when the gas temperature or the radiometric curves are not known."""
    curve = geometry.curve_left
    if params.gas_temperature_k is None or curve is None or geometry.curve_right is None:
        return None, 0.0
    t = float(params.gas_temperature_k)
    lg = float(band_radiance(t, curve.band_m))
    per_k = float(band_radiance(t + 0.5, curve.band_m) - band_radiance(t - 0.5, curve.band_m))
    return lg, per_k * float(params.min_contrast_k)


def initial_scale(left: Sequence[np.ndarray], right: Sequence[np.ndarray],
                  geometry: StereoGeometry, params: ChainParameters | None = None) -> float:
    """A provisional first normalisation scale: 0.999 quantile of |D(t0)| over both
    cameras, before registration (the chain takes it again from the registered, gated
    differences when that is smaller)."""
    lg, floor = gas_radiance(params or ChainParameters(), geometry)
    diffs = []
    for frames, curve in ((left, geometry.curve_left), (right, geometry.curve_right)):
        a = radiometric_correction(frames[0], curve)
        b = radiometric_correction(frames[1], curve)
        diffs.append(np.abs(differential_image(a, b, lg, floor))[::2, ::2].ravel())
    q = float(np.quantile(np.concatenate(diffs), 0.999))
    # A static scene has no difference at all; any positive scale then gives flat 0.5.
    return q if q > 0 else 1.0


def _check_frames(left: Sequence[np.ndarray], right: Sequence[np.ndarray],
                  geometry: StereoGeometry) -> None:
    if len(left) != 3 or len(right) != 3:
        raise ValueError(f"need 3 left and 3 right frames, got {len(left)} and {len(right)}")
    w, h = geometry.image_size
    for side, frames in (("left", left), ("right", right)):
        for i, f in enumerate(frames):
            shape = getattr(f, "shape", None)
            if shape != (h, w):
                raise ValueError(
                    f"{side} frame t{i} has shape {shape}, the calibration expects {(h, w)}"
                )


def compute_scene_flow(
    left: Sequence[np.ndarray],
    right: Sequence[np.ndarray],
    times_s: Sequence[float],
    geometry: StereoGeometry,
    params: ChainParameters | None = None,
    state: ChainState | None = None,
) -> SceneFlowResult:
    """Run the whole chain on three consecutive stereo pairs.

    Parameters
    ----------
    left, right : sequence of 3 ndarrays, shape (H, W), uint8/uint16/float
        Raw frames of the left and right camera at t0, t1, t2.
    times_s : sequence of 3 floats
        Capture times of the three pairs in s (e.g. corrected monotonic time / 1e9).
    geometry : StereoGeometry
        From the calibration file (or ideal for simulated cameras).
    params : ChainParameters, optional
        Defaults to the paper's values.
    state : ChainState, optional
        Carried from the previous call of the same stream (:mod:`processing.temporal`):
        warm start of w, d and d', frames corrected once, registration shift reuse,
        tracked normalisation scale; updated in place. The warm start and the shift are
        used only when this triple follows the previous one by the state's stride.

    Returns
    -------
    SceneFlowResult

    Raises
    ------
    ValueError
        Wrong number or size of frames, non-increasing times, bad parameters.
    """
    params = params or ChainParameters()
    _check_frames(left, right, geometry)
    dt = frame_interval(times_s)
    times = (float(times_s[0]), float(times_s[1]), float(times_s[2]))
    timings: dict[str, float] = {}
    t_start = time.perf_counter()

    def lap(name: str, t: float) -> float:
        now = time.perf_counter()
        timings[name] = (now - t) * 1e3
        return now

    # Whether the scale is a first one from this triple's own differences (provisional:
    # taken again after registration and the depth gate, below) or is set / tracked.
    own_scale = False
    if params.diff_scale is not None:
        scale = params.diff_scale
    elif state is not None and state.scale is not None:
        scale = state.scale.scale
    else:
        scale = initial_scale(left, right, geometry, params)
        own_scale = True
    known = known_shifts(state, times)
    # Checked before the warm start: the state then still holds the previous triple.
    follows = state is not None and state.follows(times)
    lg, contrast_floor = gas_radiance(params, geometry)

    t = time.perf_counter()
    # Radiometric correction and rectification once per frame (processing.temporal); the
    # corrected frames then go through pre-processing as they are (no curve, no maps).
    corrected = [
        corrected_frames(state, cam, frames, times,
                         lambda f, curve=curve, maps=maps: _correct(f, curve, maps))
        for cam, (frames, curve, maps) in enumerate((
            (left, geometry.curve_left, geometry.maps_left),
            (right, geometry.curve_right, geometry.maps_right)))
    ]
    pl, pr = preprocess_stereo(
        corrected[0], corrected[1], scale=scale, register=params.register,
        denoise_lambda=params.denoise_lambda,
        shift01=tuple(k[0][0] if k[0] else None for k in known),  # type: ignore[arg-type]
        shift12=tuple(k[1][0] if k[1] else None for k in known),  # type: ignore[arg-type]
        max_shift_px=params.max_jitter_px, gas_radiance=lg, min_contrast=contrast_floor,
    )
    pl, pr = remember_shifts(state, times, known, (pl, pr))
    t = lap("preprocess", t)

    flags: list[str] = []
    blanked = None
    if params.depth_gate:
        gate = out_of_band_motion(pl.diff0, pr.diff0, d_min=params.d0,
                                  d_max=params.d0 + params.sgm_num_disparities,
                                  dilate_px=params.max_motion_px)
        if gate.fraction > 0:
            flags.append("object_motion_rejected")
            pl, pr = apply_gate(pl, pr, gate)
            blanked = (gate.left, gate.right)
        t = lap("depth_gate", t)
    flags.extend(preprocess_flags(pl, pr))
    # The scale this triple asks for: once, for the scene-change test and the tracker.
    # Without the registration's border strips: on a textured background their mirrored
    # values differ by far more than any gas (processing.normalisation's quantile).
    measured = scale_samples(pl, pr)
    target = None
    if own_scale:
        # A first scale (no tracked one yet) came from the unregistered first pair, with a
        # textured background's jitter and any warm object in it (measured: 2.1x the gas's
        # own under 0.3 px jitter, 15x with the object). Taken again from what the solvers
        # see: registered, gated, without the border strips.
        # It is also the first target of the tracker that starts from it.
        q = target = pooled_quantile(measured)
        if 0 < q < scale:
            pl, pr = rescale_differences(pl, scale / q), rescale_differences(pr, scale / q)
            scale = q
    elif state is not None and state.scale is not None:
        target = state.scale.target(*measured)
    cut = scene_change(state, target)
    if cut:
        flags.append("scene_change")
    # Decided after pre-processing: a scene change starts cold and leaves nothing to warm.
    warm = None if cut else warm_start(state, times, params.warm_start, params.cold_every)
    if cut and state is not None:
        state.cold_starts += 1

    flow = brox_optical_flow(
        pl.diff0, pl.diff1, alpha=params.alpha, beta=params.beta,
        initial_flow=None if warm is None else warm.flow,
        **solver_options(params.flow_options, params.warm_flow_options, warm is not None))
    t = lap("flow", t)

    if warm is not None:
        # The fields of the same scene one triple earlier are far closer than any SGM
        # estimate on differential images, and cost nothing.
        init_d, init_dd = warm.disparity, warm.change
    elif params.disparity_init == "sgm":
        # The search starts at d0: a range below the gas's disparity leaves SGM nothing to
        # find, and the joint solver, started far off, does not converge (d' bias).
        init_d = sgbm_initial_disparity(pl.diff0, pr.diff0,
                                        min_disparity=int(np.floor(params.d0)),
                                        num_disparities=params.sgm_num_disparities,
                                        fallback=params.d0)
        init_dd = None
    else:
        init_d = init_dd = None
    t = lap("disparity_init", t)
    options = solver_options(params.disparity_options, params.warm_disparity_options,
                             warm is not None)
    if UNTRUSTED_FOR_CONSTANT_MODE.intersection(flags):
        # Left-over jitter differs between the cameras and noise without gas contrast has
        # its own minimum: both are a constant d' offset, which the constant-mode step
        # would fit (measured: V_Z 20-60 m/s with a rejected 0.5 px shift, 2-4 m/s on a
        # 3 K plume under 0.03 K noise). The plain solver keeps d' near its start there.
        options["constant_mode"] = False
    d, dd = joint_disparity(
        pl.diff0, pr.diff0, pl.diff1, pr.diff1, flow, gamma1=params.gamma1,
        gamma2=params.gamma2, d0=params.d0, initial_disparity=init_d, initial_change=init_dd,
        blanked=blanked, **options)
    if params.temporal_weight > 0:
        # The previous triple's (smoothed) d' carried along the gas's paths; at stride 2
        # the previous triple is two frames back, so the paths are twice the flow.
        assert state is None or state.stride in (1, 2)
        history = state.previous_change if (state is not None and follows) else None
        steps = 1 if state is None else state.stride
        dd = smooth_disparity_change(dd, history, flow * steps, params.temporal_weight)
    t = lap("disparity", t)

    seg = segment_gas(pl.diff0, flow, nu=params.nu, **params.segmentation_options)
    t = lap("segmentation", t)

    # Velocity (Eq. 4), surface position and U_SF (Eq. 7) in one compiled pass; U_SF only
    # on the gas, the region c_USF (Eq. 8) averages it over.
    velocity, position, valid, u_sf, u_sf_valid = velocity_and_quality(
        flow, d, dd, (pl.diff0, pr.diff0, pl.diff1, pr.diff1),
        principal_point=geometry.principal_point, camera_constant=geometry.camera_constant,
        baseline=geometry.baseline, dt=dt, gamma1=params.gamma1, gamma2=params.gamma2,
        quality_mask=seg.mask)
    t = lap("velocity_quality", t)

    quality = c_usf(u_sf, seg.mask, valid & u_sf_valid)
    summary = summarize_frame(velocity, valid, seg.mask, quality, tuple(flags))
    lap("summary", t)
    timings["total"] = (time.perf_counter() - t_start) * 1e3

    if state is not None:
        _update_state(state, params, scale, measured, target)
        if cut:
            state.reset()  # the next triple starts cold too: these fields are not gas
        else:
            remember(state, times=times, flow=flow, disparity=d, change=dd)
    return SceneFlowResult(
        times_s=times, dt_s=dt, diff_left=(pl.diff0, pl.diff1), diff_right=(pr.diff0, pr.diff1),
        flow=flow, disparity=d, disparity_change=dd, velocity=velocity, position=position,
        valid=valid, u_sf=u_sf, u_sf_valid=u_sf_valid, gas_mask=seg.mask, phi=seg.phi,
        summary=summary, diff_scale=scale, shifts_left=pl.shifts, shifts_right=pr.shifts,
        rejected_shifts=pl.rejected_shifts + pr.rejected_shifts, timings_ms=timings,
        warm=warm is not None,
    )


#: Flags of a triple whose data do not fix the constant part of d and d' (see
#: :func:`processing.disparity.constant_mode_step`).
UNTRUSTED_FOR_CONSTANT_MODE = frozenset({"registration_rejected", "low_contrast"})

#: A triple whose differential images ask for this many times the tracked normalisation
#: scale is a scene change, not gas motion (measured: the simulated scene's loop jump asked
#: for 4-9x, consecutive gas frames for 0.6-1.5x).
SCENE_CHANGE_FACTOR = 3.0


def scene_change(state: ChainState | None, target: float | None) -> bool:
    """Whether the whole picture changed at once in this triple.

    A flat-field shutter, a bumped camera or a jump of the scene makes both differential
    images of a triple far stronger than gas ever does. A warm start would carry that
    triple's fields into the next ones (measured: four triples after the simulated scene's
    loop jump at 4-19 m/s against 1.3 m/s true), so it starts cold and leaves nothing to
    warm from. Needs a tracked scale (a state after its first triple); ``target`` is the
    scale this triple's raw differential images ask for (:meth:`DiffScaleTracker.target`).
    """
    if state is None or state.scale is None or target is None:
        return False
    return target > SCENE_CHANGE_FACTOR * state.scale.scale


def _correct(frame: np.ndarray, curve: CharacteristicCurve | None, maps: Maps | None
             ) -> np.ndarray:
    """Steps 1-2 of :mod:`processing.preprocess` for one raw frame."""
    img = radiometric_correction(frame, curve)
    return img if maps is None else apply_rectification(img, maps[0], maps[1])


def _update_state(state: ChainState, params: ChainParameters, scale: float,
                  measured: Sequence[np.ndarray], target: float | None) -> None:
    if params.diff_scale is None:
        if state.scale is None:
            state.scale = DiffScaleTracker(scale, forgetting=params.scale_forgetting)
        state.scale.update(*measured, target=target)
