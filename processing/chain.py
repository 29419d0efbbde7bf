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
4. 3D velocity V and the virtual gas surface (Eq. 4) with dt from the timestamps;
5. quality U_SF (Eq. 7);
6. gas segmentation (4.4, Eq. 9) of the left differential image with the flow;
7. per-frame summary over the gas region, with c_USF (Eq. 8).

The frame interval of Eq. 4 is the time between the centres of the two differential
images, dt = ((t1 + t2) - (t0 + t1)) / 2 = (t2 - t0) / 2, taken from the timestamps.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from processing.baselines import sgbm_initial_disparity
from processing.calibration import StereoCalibration, rectification_maps
from processing.calibration.radiometric import CharacteristicCurve, band_radiance
from processing.depth_gate import apply_gate, out_of_band_motion
from processing.disparity import joint_disparity
from processing.disturbances import preprocess_flags
from processing.optical_flow import brox_optical_flow
from processing.preprocess import (
    DiffScaleTracker,
    PreprocessedTriple,
    differential_image,
    preprocess_stereo,
    radiometric_correction,
)
from processing.quality import c_usf, scene_flow_energy
from processing.segmentation import segment_gas
from processing.summary import GasSummary, summarize_frame
from processing.temporal import smooth_disparity_change
from processing.velocity import scene_flow_velocity, surface_position

Maps = tuple[np.ndarray, np.ndarray]



@dataclass(frozen=True)
class StereoGeometry:
    """What the chain needs from a stereo calibration.

    Attributes
    ----------
    camera_constant : float
        Rectified camera constant s in px (Eq. 4).
    principal_point : (float, float)
        Rectified principal point (x0, y0) of the left image in px.
    baseline : float
        Stereo baseline b in m.
    image_size : (int, int)
        (W, H) of the raw frames.
    maps_left, maps_right : (map_x, map_y) or None
        Rectification maps (float32, (H, W) each); None when the raw frames are already
        rectified (ideal or simulated cameras).
    curve_left, curve_right : CharacteristicCurve or None
        Radiometric characteristic curves; None means counts are used as they are.
    """

    camera_constant: float
    principal_point: tuple[float, float]
    baseline: float
    image_size: tuple[int, int]
    maps_left: Maps | None = None
    maps_right: Maps | None = None
    curve_left: CharacteristicCurve | None = None
    curve_right: CharacteristicCurve | None = None

    @classmethod
    def from_calibration(cls, calib: StereoCalibration, *, rectify: bool = True) -> StereoGeometry:
        """Geometry, rectification maps and curves of a loaded calibration file."""
        maps_l = maps_r = None
        if rectify:
            maps = rectification_maps(calib)
            maps_l, maps_r = (maps.left_x, maps.left_y), (maps.right_x, maps.right_y)
        radio = calib.radiometric
        return cls(
            camera_constant=float(calib.s_px),
            principal_point=(float(calib.cx_px), float(calib.cy_px)),
            baseline=float(calib.b_m),
            image_size=(int(calib.image_size[0]), int(calib.image_size[1])),
            maps_left=maps_l,
            maps_right=maps_r,
            curve_left=radio.left if radio is not None else None,
            curve_right=radio.right if radio is not None else None,
        )

    @classmethod
    def from_synthetic_camera(cls, cam: Mapping[str, Any]) -> StereoGeometry:
        """Geometry of a synthetic sequence's ideal, rectified camera pair.

        ``cam`` is the ``camera`` entry of a sequence's ``meta.json`` (``s_px``, ``cx_px``,
        ``cy_px``, ``b_m``, ``width``, ``height``, optional ``k1``/``k2``).

        Raises
        ------
        ValueError
            When the cameras have lens distortion: the frames then need the calibration
            file the simulator writes, not this ideal geometry.
        """
        if cam.get("k1", 0.0) or cam.get("k2", 0.0):
            raise ValueError(
                f"the synthetic cameras have lens distortion (k1={cam.get('k1')}, "
                f"k2={cam.get('k2')}); use the matching calibration file instead")
        return cls(camera_constant=float(cam["s_px"]),
                   principal_point=(float(cam["cx_px"]), float(cam["cy_px"])),
                   baseline=float(cam["b_m"]),
                   image_size=(int(cam["width"]), int(cam["height"])))


@dataclass(frozen=True)
class ChainParameters:
    """Parameters of the chain; defaults are the paper's values (Sec. 5).

    Attributes
    ----------
    alpha, beta : float
        Flow smoothness and gradient-constancy weights (Eq. 5; 0.05, 0.1).
    gamma1, gamma2 : float
        Smoothness weights of d and d' (Eq. 6; 0.05, 0.5).
    nu : float
        Length weight of the segmentation (Eq. 9; 0.5).
    d0 : float
        Minimum disparity in px (Sec. 4.3): the initial disparity for ``disparity_init =
        "d0"``; for ``"sgm"`` the lower end of the SGM search range and the fill value of
        its holes.
    disparity_init : str
        "sgm" (StereoSGBM on the differential images, holes filled with d0) or "d0".
    sgm_num_disparities : int
        Width of the SGM search range [floor(d0), floor(d0) + N) in px (multiple of 16).
    denoise_lambda : float
        Sobolev prior weight in px^2 (0 disables).
    register : bool
        Remove camera jitter by registering consecutive frames on the static background.
    max_jitter_px : float
        Registration estimates larger than this are taken for gas motion (featureless
        background) and not applied; the result counts them in ``rejected_shifts``. The
        shift between two frames is the difference of two independent jitters: with 0.3
        px per axis it exceeds 1 px in about 6 % of the pairs, hence 1.5.
    diff_scale : float or None
        Normalisation scale of the differential images in radiance (or count) units. None
        tracks it online: the 0.999 quantile of |I_diff| over both cameras, with
        exponential forgetting ``scale_forgetting`` per triple (kept in the state).
    scale_forgetting : float
        Forgetting factor of the tracked scale (0.02 at 30 Hz ~ 1.7 s memory).
    warm_start : bool
        Start the flow and the disparity from the previous triple's results (needs a
        state; only when this triple directly follows it). The SGM or d0 initialisation
        is then used only on a cold start.
    gas_temperature_k : float or None
        Gas temperature in K (about the ambient air temperature). With radiometric curves
        in the geometry, the differential images become differential optical depth, free of
        the background's texture (:func:`processing.preprocess.differential_image`); None
        (or no curves) keeps plain differences.
    min_contrast_k : float
        Floor of the gas-background contrast for that division, in K.
    depth_gate : bool
        Remove moving image regions whose stereo disparity lies outside the gas band
        [d0, d0 + sgm_num_disparities] before the solvers (:mod:`processing.depth_gate`).
    max_motion_px : int
        Largest image motion within a triple, px: how far the gate's masks grow.
    temporal_weight : float
        Share a in [0, 1) of the previous triple's d', carried along the flow, in this
        triple's d' (:mod:`processing.temporal`); 0 uses each triple alone (the paper).
        The default 0.7 (memory ~3 frames) halved the triple-to-triple scatter of V_Z on
        the robustness matrix.
    flow_options, disparity_options, segmentation_options : mapping
        Further keyword arguments of the three solvers (iteration counts, pyramid ...).
    """

    alpha: float = 0.05
    beta: float = 0.1
    gamma1: float = 0.05
    gamma2: float = 0.5
    nu: float = 0.5
    d0: float = 0.0
    disparity_init: str = "sgm"
    sgm_num_disparities: int = 64
    denoise_lambda: float = 2.0
    register: bool = True
    max_jitter_px: float = 1.5
    diff_scale: float | None = None
    scale_forgetting: float = 0.02
    warm_start: bool = True
    gas_temperature_k: float | None = None
    min_contrast_k: float = 1.0
    depth_gate: bool = True
    max_motion_px: int = 8
    temporal_weight: float = 0.7
    flow_options: Mapping[str, Any] = field(default_factory=dict)
    disparity_options: Mapping[str, Any] = field(default_factory=dict)
    segmentation_options: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.disparity_init not in ("sgm", "d0"):
            raise ValueError(
                f"disparity_init must be 'sgm' or 'd0', got {self.disparity_init!r}"
            )
        if self.sgm_num_disparities < 16 or self.sgm_num_disparities % 16:
            raise ValueError(
                f"sgm_num_disparities must be a positive multiple of 16, "
                f"got {self.sgm_num_disparities!r}"
            )
        if self.diff_scale is not None and not self.diff_scale > 0:
            raise ValueError(f"diff_scale must be positive or null, got {self.diff_scale!r}")
        if not 0 < self.scale_forgetting <= 1:
            raise ValueError(f"scale_forgetting must be in (0, 1], got {self.scale_forgetting!r}")

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any]) -> ChainParameters:
        """Build from a config mapping; an unknown key raises ValueError naming it."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - names)
        if unknown:
            raise ValueError(
                f"unknown processing parameter(s) {', '.join(unknown)}; "
                f"known: {', '.join(sorted(names))}"
            )
        return cls(**dict(values))


@dataclass
class ChainState:
    """What one call leaves for the next call on the following triple (warm start).

    The daemon keeps one per worker; offline evaluation may pass None (cold start).
    """

    scale: DiffScaleTracker | None = None
    previous_flow: np.ndarray | None = None
    previous_disparity: np.ndarray | None = None
    previous_times: tuple[float, float, float] | None = None
    previous_disparity_change: np.ndarray | None = None
    shift01: tuple[tuple[float, float] | None, tuple[float, float] | None] = (None, None)


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
        Quality U_SF (Eq. 7); ``u_sf_valid`` marks pixels whose warps stayed inside.
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
    """A first normalisation scale: 0.999 quantile of |D(t0)| over both cameras."""
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
        Carried from the previous call on the preceding triple (warm start of the flow,
        registration shift reuse, tracked normalisation scale); updated in place. The
        warm start is used only when this triple directly follows the previous one.

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

    consecutive = (
        state is not None
        and state.previous_times is not None
        and state.previous_times[1:] == times[:2]
    )
    if params.diff_scale is not None:
        scale = params.diff_scale
    elif state is not None and state.scale is not None:
        scale = state.scale.scale
    else:
        scale = initial_scale(left, right, geometry, params)
    shift01 = state.shift01 if (state is not None and consecutive) else (None, None)

    lg, contrast_floor = gas_radiance(params, geometry)
    t = time.perf_counter()
    pl, pr = preprocess_stereo(
        left, right, scale=scale,
        curves=(geometry.curve_left, geometry.curve_right),
        maps=(geometry.maps_left, geometry.maps_right),
        register=params.register, denoise_lambda=params.denoise_lambda, shift01=shift01,
        max_shift_px=params.max_jitter_px, gas_radiance=lg, min_contrast=contrast_floor,
    )
    t = lap("preprocess", t)

    flags: list[str] = []
    if params.depth_gate:
        gate = out_of_band_motion(pl.diff0, pr.diff0, d_min=params.d0,
                                  d_max=params.d0 + params.sgm_num_disparities,
                                  dilate_px=params.max_motion_px)
        if gate.fraction > 0:
            flags.append("object_motion_rejected")
            pl, pr, scale = apply_gate(pl, pr, gate, scale)
        t = lap("depth_gate", t)
    flags.extend(preprocess_flags(pl, pr))

    init_flow = None
    if params.warm_start and consecutive and state is not None:
        init_flow = state.previous_flow
    flow = brox_optical_flow(pl.diff0, pl.diff1, alpha=params.alpha, beta=params.beta,
                             initial_flow=init_flow, **params.flow_options)
    t = lap("flow", t)

    init_d = None
    if params.warm_start and consecutive and state is not None:
        # The disparity of the same scene one frame earlier is far closer than any SGM
        # estimate on differential images, and costs nothing.
        init_d = state.previous_disparity
    if init_d is None and params.disparity_init == "sgm":
        # The search starts at d0: a range below the gas's disparity leaves SGM nothing to
        # find, and the joint solver, started far off, does not converge (d' bias).
        init_d = sgbm_initial_disparity(pl.diff0, pr.diff0,
                                        min_disparity=int(np.floor(params.d0)),
                                        num_disparities=params.sgm_num_disparities,
                                        fallback=params.d0)
    t = lap("disparity_init", t)
    d, dd = joint_disparity(pl.diff0, pr.diff0, pl.diff1, pr.diff1, flow,
                            gamma1=params.gamma1, gamma2=params.gamma2, d0=params.d0,
                            initial_disparity=init_d, **params.disparity_options)
    if params.temporal_weight > 0:
        history = state.previous_disparity_change if (state is not None and consecutive) \
            else None
        dd = smooth_disparity_change(dd, history, flow, params.temporal_weight)
    t = lap("disparity", t)

    pp, s, b = geometry.principal_point, geometry.camera_constant, geometry.baseline
    velocity, valid = scene_flow_velocity(flow, d, dd, principal_point=pp, camera_constant=s,
                                          baseline=b, dt=dt)
    position, pos_valid = surface_position(d, principal_point=pp, camera_constant=s,
                                           baseline=b)
    valid &= pos_valid
    t = lap("velocity", t)

    u_sf, u_sf_valid = scene_flow_energy(pl.diff0, pr.diff0, pl.diff1, pr.diff1, flow, d, dd,
                                         gamma1=params.gamma1, gamma2=params.gamma2)
    t = lap("quality", t)

    seg = segment_gas(pl.diff0, flow, nu=params.nu, **params.segmentation_options)
    t = lap("segmentation", t)

    quality = c_usf(u_sf, seg.mask, valid & u_sf_valid)
    summary = summarize_frame(velocity, valid, seg.mask, quality, tuple(flags))
    lap("summary", t)
    timings["total"] = (time.perf_counter() - t_start) * 1e3

    if state is not None:
        _update_state(state, params, scale, pl, pr, flow, d, times)
        state.previous_disparity_change = dd
    return SceneFlowResult(
        times_s=times, dt_s=dt, diff_left=(pl.diff0, pl.diff1), diff_right=(pr.diff0, pr.diff1),
        flow=flow, disparity=d, disparity_change=dd, velocity=velocity, position=position,
        valid=valid, u_sf=u_sf, u_sf_valid=u_sf_valid, gas_mask=seg.mask, phi=seg.phi,
        summary=summary, diff_scale=scale, shifts_left=pl.shifts, shifts_right=pr.shifts,
        rejected_shifts=pl.rejected_shifts + pr.rejected_shifts, timings_ms=timings,
    )


def _update_state(state: ChainState, params: ChainParameters, scale: float,
                  pl: PreprocessedTriple, pr: PreprocessedTriple, flow: np.ndarray,
                  d: np.ndarray, times: tuple[float, float, float]) -> None:
    if params.diff_scale is None:
        if state.scale is None:
            state.scale = DiffScaleTracker(scale, forgetting=params.scale_forgetting)
        state.scale.update(pl.raw0, pl.raw1, pr.raw0, pr.raw1)
    state.previous_flow = flow
    state.previous_disparity = d
    state.previous_times = times
    # The t1 -> t2 shift of this triple is the t0 -> t1 shift of the next one.
    state.shift01 = (pl.shifts[1], pr.shifts[1])
