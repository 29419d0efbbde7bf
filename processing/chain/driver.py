"""The single entry point of the scene-flow chain (paper Sec. 4, Fig. 2).

:func:`compute_scene_flow` takes three consecutive stereo pairs of raw frames (t0, t1, t2)
with their capture times, the stereo geometry and the parameters, and returns one
:class:`SceneFlowResult` with every field, the gas mask, the per-frame summary and the
time spent in each stage. The daemon's workers, ``ogiflow replay``, the evaluations and
the benchmarks all call this function, so a number measured in one is the number the
others produce.

Stages (paper section / equation):

1. pre-processing (4.1): radiometric correction, rectification (then, with ``binning``,
   the means of k x k blocks: :mod:`processing.chain.binning`), jitter registration,
   differential images I_diff(t0) = I(t0) - I(t1) and I_diff(t1) = I(t1) - I(t2) (Eq. 2),
   Sobolev denoising, one normalisation to [0, 1] shared by both cameras;
2. optical flow w_L between the left differential images (4.2, Eq. 5);
3. initial disparity (SGM or the minimum disparity d0), then joint d_L, d'_L (4.3, Eq. 6);
4. 3D velocity V and the virtual gas surface (Eq. 4) with dt from the timestamps, and the
   quality U_SF (Eq. 7), in one compiled pass (:mod:`processing.velocity.pixelwise`);
5. gas segmentation (4.4, Eq. 9) of the left differential image with the flow;
6. per-frame summary over the gas region, with c_USF (Eq. 8).

The frame interval of Eq. 4 is the time between the centres of the two differential
images, dt = ((t1 + t2) - (t0 + t1)) / 2 = (t2 - t0) / 2, taken from the timestamps.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from processing.chain.binning import (
    binned_geometry,
    binned_parameters,
    upsampled_result,
)
from processing.chain.flags import UNTRUSTED_FOR_CONSTANT_MODE, preprocess_flags
from processing.chain.parameters import ChainParameters
from processing.chain.preprocessing import Pair, check_frames, preprocess_triple
from processing.chain.region import (
    Box,
    choose_region,
    crop_inputs,
    flow_blanked,
    measured_area,
    paste_fields,
)
from processing.chain.result import SceneFlowResult, frame_interval
from processing.chain.scale import initial_scale
from processing.chain.state import ChainState, Times, WarmStart, solver_options
from processing.chain.summary import GasSummary, summarize_frame
from processing.flow.brox import brox_optical_flow
from processing.preprocess.depth_gate import apply_gate, out_of_band_motion
from processing.preprocess.differential import PreprocessedTriple
from processing.preprocess.opaque_gate import remove_opaque_edges
from processing.preprocess.stereo_triple import rescale_differences, scale_samples
from processing.segmentation.segment import segment_gas
from processing.solvers.variational import PyramidCache
from processing.stereo.coherence import history_weight, smooth_disparity_change
from processing.stereo.joint import joint_disparity
from processing.stereo.sgm import sgbm_initial_disparity
from processing.stereo_geometry import StereoGeometry
from processing.velocity.pixelwise import velocity_and_quality
from processing.velocity.quality import c_usf


def compute_scene_flow(left: Sequence[np.ndarray], right: Sequence[np.ndarray],
                       times_s: Sequence[float], geometry: StereoGeometry,
                       params: ChainParameters | None = None,
                       state: ChainState | None = None, *,
                       at_camera_size: bool = True) -> SceneFlowResult:
    """Run the whole chain on three consecutive stereo pairs.

    Parameters
    ----------
    left, right : sequence of 3 ndarrays, shape (H, W), uint8/uint16/float
        Raw frames of the left and right camera at t0, t1, t2.
    times_s : sequence of 3 floats
        Capture times of the three pairs in s (any common origin).
    geometry : StereoGeometry
        From the calibration file (or ideal for simulated cameras).
    params : ChainParameters, optional
        Defaults to the paper's values.
    state : ChainState, optional
        Carried from the previous call of the same stream and updated in place
        (:mod:`processing.chain.state`); None: every triple on its own.
    at_camera_size : bool
        With ``params.binning`` k > 1: True returns the fields at the cameras' size (each
        block's value on its k x k pixels, motions and disparities in camera px); False
        returns them as the chain measured them, (H / k, W / k) in px of blocks, for a
        caller that grows only what it needs
        (:func:`processing.chain.binning.upsampled_result` makes the first from the second).

    Returns
    -------
    SceneFlowResult

    Raises
    ------
    ValueError
        Wrong number or size of frames, non-increasing times, bad parameters.
    """
    params = params or ChainParameters()
    check_frames(left, right, geometry)
    k = params.binning
    # From here on the chain works on k x k blocks: its settings and Eq. 4's geometry in
    # blocks; the raw frames keep theirs for the correction (processing.chain.binning).
    params = binned_parameters(params)
    frames_geometry, geometry = geometry, binned_geometry(geometry, k)
    dt = frame_interval(times_s)
    times: Times = (float(times_s[0]), float(times_s[1]), float(times_s[2]))
    stream = state if state is not None else ChainState()
    clock = _Laps()
    follows = stream.follows(times)  # before the warm start replaces the previous triple

    fixed = stream.scale_to_use(params.diff_scale)
    scale = fixed if fixed is not None else initial_scale(left, right, frames_geometry, params)
    pl, pr = preprocess_triple(left, right, times, frames_geometry, params, stream, scale, k)
    clock.lap("preprocess")
    flags: list[str] = []
    blanked = None
    if params.depth_gate:
        pl, pr, blanked = _depth_gate(pl, pr, params, flags)
    depth_blanked = blanked
    if params.opaque_gate_gas_k is not None:
        pl, pr, blanked = remove_opaque_edges(
            pl, pr, stream.frames_of(times), (geometry.curve_left, geometry.curve_right),
            params.opaque_gate_gas_k, params.min_contrast_k, blanked, flags)
    if params.depth_gate or params.opaque_gate_gas_k is not None:
        clock.lap("depth_gate")
    flags.extend(preprocess_flags(pl, pr))
    (pl, pr), scale, measured, target = _settle_scale(pl, pr, stream, scale, fixed is None)
    cut = stream.scene_change(target, measured)
    flags.extend(["scene_change"] if cut else [])
    warm = stream.warm_start(times, params.warm_start, params.cold_every, scene_change=cut)

    box = _region(pl, params, warm, stream)
    cl, cr, cwarm, cblank, history = crop_inputs(box, pl, pr, warm, blanked,
                                                 stream.change_history(follows))
    history_triples = stream.change_triples(follows)
    history_share = history_weight(params.temporal_weight, history_triples)
    pyramids = PyramidCache()  # the left images' pyramids, shared by both solvers
    restart = stream.restart_flow if params.restart_keeps_flow else None
    flow = _flow(cl, params, cwarm, pyramids, flow_blanked(blanked, depth_blanked, params, box),
                 restart, stream.stride)
    clock.lap("flow")
    init = _initial_disparity(cl, cr, params, cwarm)
    clock.lap("disparity_init")
    d, dd = _disparity(cl, cr, flow, init, params, warm is not None, flags, cblank, history,
                       history_share, pyramids)
    (flow, d, dd), start = paste_fields(box, flow, d, dd, warm)
    clock.lap("disparity")
    area = measured_area(d.shape, box, max(pl.border_px, pr.border_px))
    solved = None if box is None else box.mask(d.shape)
    mask, phi = _segment(area, solved, pl.diff0, flow, params)
    clock.lap("segmentation")
    velocity, position, valid, u_sf, u_sf_valid = _velocity(pl, pr, flow, d, dd, mask, area,
                                                            blanked, geometry, params, dt)
    clock.lap("velocity_quality")
    summary, implausible = _summary(velocity, valid, mask, u_sf, u_sf_valid, flags, params)
    clock.lap("summary")

    # An implausible triple must not seed the next (a warm d' of -69 px lived ten triples).
    stream.finish(times=times, scale=scale, fixed_scale=params.diff_scale,
                  forgetting=params.scale_forgetting, measured=measured, target=target,
                  scene_change=cut or implausible, flow=start[0], disparity=start[1],
                  change=start[2], mask=mask, change_triples=history_triples + 1)
    blocks = SceneFlowResult(
        times_s=times, dt_s=dt, diff_left=(pl.diff0, pl.diff1), diff_right=(pr.diff0, pr.diff1),
        flow=flow, disparity=d, disparity_change=dd, velocity=velocity, position=position,
        valid=valid, u_sf=u_sf, u_sf_valid=u_sf_valid, gas_mask=mask, phi=phi,
        summary=summary, diff_scale=scale, shifts_left=pl.shifts, shifts_right=pr.shifts,
        rejected_shifts=pl.rejected_shifts + pr.rejected_shifts, timings_ms=clock.total(),
        warm=warm is not None, region=None if box is None else box.bounds,
        offset_steps=(pl.offset_step1, pr.offset_step1))
    return upsampled_result(blocks, k) if at_camera_size else blocks


def _summary(velocity: np.ndarray, valid: np.ndarray, mask: np.ndarray, u_sf: np.ndarray,
             u_sf_valid: np.ndarray, flags: list[str], params: ChainParameters
             ) -> tuple[GasSummary, bool]:
    """The frame's summary (c_USF: Eq. 8) and whether its mean speed exceeds
    ``params.max_gas_speed_m_s`` (then invalid, flagged ``implausible_speed``)."""
    summary = summarize_frame(velocity, valid, mask, c_usf(u_sf, mask, valid & u_sf_valid),
                              tuple(flags))
    if summary.speed is None or summary.speed <= params.max_gas_speed_m_s:
        return summary, False
    return replace(summary, valid=False,
                               flags=(*summary.flags, "implausible_speed")), True


@dataclass
class _Laps:
    """Wall time per stage in ms, each lap from the end of the previous one."""

    timings: dict[str, float] = field(default_factory=dict)
    start: float = field(default_factory=time.perf_counter)
    last: float = 0.0

    def __post_init__(self) -> None:
        self.last = self.start

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.timings[name] = (now - self.last) * 1e3
        self.last = now

    def total(self) -> dict[str, float]:
        self.timings["total"] = (time.perf_counter() - self.start) * 1e3
        return self.timings


def _depth_gate(pl: PreprocessedTriple, pr: PreprocessedTriple, params: ChainParameters,
                flags: list[str]
                ) -> tuple[PreprocessedTriple, PreprocessedTriple,
                           tuple[np.ndarray, np.ndarray] | None]:
    """Blank what moves outside the gas's disparity band; the blanked masks, or None."""
    gate = out_of_band_motion(pl.diff0, pr.diff0, d_min=params.d0,
                              d_max=params.d0 + params.sgm_num_disparities,
                              tolerance_px=params.gate_tolerance_px,
                              dilate_px=params.max_motion_px, amplitude=pl.raw0,
                              grow_fraction=params.gate_grow_fraction)
    if gate.fraction <= 0:
        return pl, pr, None
    flags.append("object_motion_rejected")
    pl, pr = apply_gate(pl, pr, gate)
    return pl, pr, (gate.left, gate.right)


def _settle_scale(pl: PreprocessedTriple, pr: PreprocessedTriple, stream: ChainState,
                  scale: float, first: bool
                  ) -> tuple[Pair, float, list[np.ndarray], float | None]:
    """The triple's raw differences without the registration's border strips (on a textured
    background their mirrored values differ by far more than any gas), the target scale they
    ask for, and, for a ``first`` scale, the differences rescaled to it.

    A first scale comes from the unregistered first pair, with a textured background's
    jitter and any warm object in it (measured: 2.1x the gas's own under 0.3 px jitter, 15x
    with the object); it is taken again from what the solvers see: registered, gated,
    without the border strips, and is also the first target of the tracker.
    """
    measured = scale_samples(pl, pr)
    target = stream.scale_target(measured, first)
    if first and target is not None and 0 < target < scale:
        pl, pr = rescale_differences(pl, scale / target), rescale_differences(pr, scale / target)
        scale = target
    return (pl, pr), scale, measured, target


def _region(pl: PreprocessedTriple, params: ChainParameters, warm: WarmStart | None,
            stream: ChainState) -> Box | None:
    """The box the solvers work on (:mod:`processing.chain.region`), None for the whole
    frame: always on a cold start, where nothing says yet where the gas is."""
    if not params.active_region or warm is None:
        return None
    return choose_region((pl.diff0, pl.diff1), warm.flow, warm.disparity, stream.previous_mask,
                         margin_px=params.region_margin_px,
                         max_fraction=params.region_max_fraction)


def _segment(area: np.ndarray | None, solved: np.ndarray | None, diff: np.ndarray,
             flow: np.ndarray, params: ChainParameters) -> tuple[np.ndarray, np.ndarray]:
    """Stage 5 (Sec. 4.4, Eq. 9): the gas mask and phi, (H, W); the mask only in the
    measured ``area`` (:func:`processing.chain.region.measured_area`; None: everywhere).

    The level set runs on the whole frame: on the solvers' box alone it has too little
    background to split off (measured on the default robustness matrix: the mask shrank
    towards the plume's core, ideal RMVE 7.0 -> 9.8 %). Its motion features count only
    where the flow was ``solved`` (the box; None: everywhere): the zero flow left outside
    made the background's motion model a spike at zero, and the box's noise flow gas
    (measured: false gas 0.06 -> 0.25 of the frame with the box on).
    """
    seg = segment_gas(diff, flow, nu=params.nu, flow_known=solved,
                      **params.segmentation_options)
    if area is None:
        return seg.mask, seg.phi
    # phi > 0 means gas: outside the area it is turned negative with the mask.
    return seg.mask & area, np.where(area, seg.phi, -np.abs(seg.phi) - np.float32(1e-3))


def _flow(pl: PreprocessedTriple, params: ChainParameters, warm: WarmStart | None,
          pyramids: PyramidCache, blanked: np.ndarray | None = None,
          restart: np.ndarray | None = None, stride: int = 1) -> np.ndarray:
    """Stage 2 (Sec. 4.2, Eq. 5): w_L between the left differential images, (H, W, 2) px;
    no data term on ``blanked`` pixels (``params.flow_drop_blanked``). On a scheduled
    restart the flow goes on from ``restart``, the previous triple's (``stride`` frames
    back), as on a warm start (``params.restart_keeps_flow``)."""
    start, steps = (restart, stride) if warm is None else (warm.flow, warm.steps)
    return brox_optical_flow(
        pl.diff0, pl.diff1, alpha=params.alpha, beta=params.beta, pyramid_cache=pyramids,
        initial_flow=start, blanked=blanked,
        **solver_options(params.flow_options, params.warm_flow_for(steps), start is not None))


def _initial_disparity(pl: PreprocessedTriple, pr: PreprocessedTriple,
                       params: ChainParameters, warm: WarmStart | None
                       ) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The joint solver's start (d_L, d'_L): the previous triple's, an SGM estimate, or none
    (the constant d0)."""
    if warm is not None:
        # The fields of the same scene one triple earlier are far closer than any SGM
        # estimate on differential images, and cost nothing.
        return warm.disparity, warm.change
    if params.disparity_init == "sgm":
        # The search starts at d0: a range below the gas's disparity leaves SGM nothing to
        # find, and the joint solver, started far off, does not converge (d' bias).
        return sgbm_initial_disparity(pl.diff0, pr.diff0,
                                      min_disparity=int(np.floor(params.d0)),
                                      num_disparities=params.sgm_num_disparities,
                                      fallback=params.d0), None
    return None, None


def _disparity(pl: PreprocessedTriple, pr: PreprocessedTriple, flow: np.ndarray,
               init: tuple[np.ndarray | None, np.ndarray | None], params: ChainParameters,
               warm: bool, flags: Sequence[str],
               blanked: tuple[np.ndarray, np.ndarray] | None,
               history: tuple[np.ndarray | None, int], history_share: float,
               pyramids: PyramidCache) -> tuple[np.ndarray, np.ndarray]:
    """Stage 3 (Sec. 4.3, Eq. 6): d_L and d'_L given the flow, then d' made coherent with the
    previous triple's along the gas's paths (``history``: the previous d'_L and the frames
    back; ``history_share``: its share in this d'_L,
    :func:`processing.stereo.coherence.history_weight`)."""
    options = solver_options(params.disparity_options, params.warm_disparity_options, warm)
    if UNTRUSTED_FOR_CONSTANT_MODE.intersection(flags):
        # Left-over jitter differs between the cameras and noise without gas contrast has
        # its own minimum: both are a constant d' offset, which the constant-mode step
        # would fit (measured: V_Z 20-60 m/s with a rejected 0.5 px shift, 2-4 m/s on a
        # 3 K plume under 0.03 K noise). The plain solver keeps d' near its start there.
        options["constant_mode"] = False
    d, dd = joint_disparity(
        pl.diff0, pr.diff0, pl.diff1, pr.diff1, flow, gamma1=params.gamma1,
        gamma2=params.gamma2, d0=params.d0, initial_disparity=init[0],
        initial_change=init[1], blanked=blanked, pyramid_cache=pyramids, **options)
    if params.temporal_weight > 0:
        # At stride 2 the previous triple is two frames back, so the paths are twice the
        # flow.
        previous, steps = history
        assert steps in (1, 2)
        dd = smooth_disparity_change(dd, previous, flow * steps, history_share)
    return d, dd


def _velocity(pl: PreprocessedTriple, pr: PreprocessedTriple, flow: np.ndarray, d: np.ndarray,
              dd: np.ndarray, gas: np.ndarray, area: np.ndarray | None,
              blanked: tuple[np.ndarray, np.ndarray] | None, geometry: StereoGeometry,
              params: ChainParameters, dt: float) -> tuple[np.ndarray, ...]:
    """Stage 4: velocity (Eq. 4), surface position and U_SF (Eq. 7) in one compiled pass; U_SF
    only on the ``gas`` mask, the region c_USF (Eq. 8) averages it over; nothing valid
    outside the measured ``area`` nor where the depth gate ``blanked`` the left view."""
    out = velocity_and_quality(
        flow, d, dd, (pl.diff0, pr.diff0, pl.diff1, pr.diff1),
        principal_point=geometry.principal_point, camera_constant=geometry.camera_constant,
        baseline=geometry.baseline, dt=dt, gamma1=params.gamma1, gamma2=params.gamma2,
        quality_mask=gas)
    # A blanked pixel shows "no change", and the segmentation may keep it: ~0 m/s, no gas.
    drop = np.zeros(d.shape, bool) if blanked is None else blanked[0].copy()
    if area is not None:
        drop |= ~area
    out[2][drop] = out[4][drop] = False  # valid, u_sf_valid
    return out
