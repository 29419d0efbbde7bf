"""Pipeline worker processes: take the newest consecutive stereo pairs, run the chain.

Each worker is a separate process (both cores are used; numpy, numba and OpenCV release
the GIL only partly) that attaches to the shared-memory ring, repeatedly claims the
newest window of three consecutive pairs (t0, t1, t2), copies it out, and runs
:func:`processing.chain.driver.compute_scene_flow` - the same function replay, evaluation and
benchmarks call. When processing falls behind, older windows are skipped and counted;
acquisition and recording never wait for a worker. Results go back to the daemon through
a multiprocessing queue as :class:`WorkerResult` (fields reduced to what the recorder and
the live view need).

How the workers share the stream (measured, docs/performance.md): a warm start from the
previous triple makes a triple about twice as cheap as a cold one, but only a worker that
saw that triple can use it. With two workers each takes every other triple (ring stride 2,
phases 0 and 1) and starts from its own triple two frames earlier; "take the newest window"
alone would hand consecutive triples to alternating workers and keep every triple cold.
A worker also takes its windows in order while it lags at most half the ring behind
(``max_lag``), so that a short stall does not make it jump ahead and start cold; beyond
that it skips to the newest. More than two workers take the newest window of any phase.
"""

from __future__ import annotations

import os
import queue
import time
import traceback
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from appliance.live import MAX_ARROWS
from processing.calibration.radiometric import CharacteristicCurve
from processing.chain.driver import ChainParameters, ChainState, SceneFlowResult, StereoGeometry
from processing.emission.estimator import (
    DEFAULT_GAS_TEMPERATURE_K,
    EmissionEstimator,
    EmissionSettings,
)
from processing.emission.rate import FrameRate


@dataclass
class WorkerResult:
    """One processed window, as sent from a worker to the daemon (picklable).

    Times are host monotonic ns of the three pairs (mean of both cameras' capture times);
    fields are those of the left view at t0, (H, W) unless stated.
    """

    worker: int
    pair_indices: tuple[int, int, int]
    t_mono_ns: tuple[int, int, int]
    t_wall_ns: int
    skipped: int
    done_mono_ns: int
    error: str | None = None
    summary: dict[str, Any] = field(default_factory=dict)
    timings_ms: dict[str, float] = field(default_factory=dict)
    dt_s: float | None = None
    diff_scale: float | None = None
    rejected_shifts: int = 0
    diff_left: np.ndarray | None = None  # uint8, 0.5 = no change
    diff_right: np.ndarray | None = None
    flow: np.ndarray | None = None  # (H, W, 2) float32 px (with the fields only)
    gas_flow: np.ndarray | None = None  # (N, 2) float32 px at the gas pixels, row-major
    disparity: np.ndarray | None = None  # float32 px
    disparity_change: np.ndarray | None = None
    velocity: np.ndarray | None = None  # (H, W, 3) float32 m/s
    valid: np.ndarray | None = None  # bool
    gas_mask: np.ndarray | None = None  # bool
    points3d: np.ndarray | None = None  # (N, 3) m, gas pixels only
    velocity3d: np.ndarray | None = None  # (N, 3) m/s
    pixels: np.ndarray | None = None  # (N, 2) int32 (x, y) of those gas pixels
    raw_left: np.ndarray | None = None  # uint16 raw left frame at t0 (the operator's view)
    rate: FrameRate | None = None  # emission rate of the triple (None: not computed)
    warm: bool = False  # the solvers started from the worker's previous triple
    #: The camera of a single-camera result ("left"/"right"; its diff and raw frame travel
    #: as ``diff_left``/``raw_left``, the image the zones and the operator see); None: stereo.
    single_camera: str | None = None

    @property
    def has_fields(self) -> bool:
        """Whether the full fields came along (see :func:`pack_result`)."""
        return self.flow is not None if self.single_camera else self.velocity is not None


@dataclass(frozen=True)
class EmissionSetup:
    """What a worker needs for the emission rate (picklable).

    ``gas_temperature_k`` None: the anemometer's sonic temperature, shared by the daemon
    through a ``multiprocessing.Value`` (NaN until the first sample). ``curve_left``: the
    left camera's characteristic curve when the geometry has none (the simulated site's
    known counts model); without any, counts are not radiance and there is no rate.
    """

    settings: EmissionSettings
    gas_temperature_k: float | None = None
    curve_left: CharacteristicCurve | None = None
    every: int = 1  # a rate on every this many triples of a worker (config emission.every)

    def to_json(self) -> str:
        """The setup as JSON (the recording's ``emission`` metadata, so replay uses it)."""
        import dataclasses
        import json

        st = self.settings
        curve = self.curve_left
        return json.dumps({
            "gas": dataclasses.asdict(st.gas), "pressure_pa": st.pressure_pa,
            "background_frames": st.background_frames,
            "gas_temperature_k": self.gas_temperature_k,
            "curve_left": None if curve is None else {"offset": curve.offset,
                                                      "gain": curve.gain}})

    @classmethod
    def from_json(cls, text: str) -> EmissionSetup:
        """Inverse of :meth:`to_json` (ValueError on a malformed record)."""
        import json

        from processing.emission.gas import GasProperties

        try:
            d = json.loads(text)
            curve = d.get("curve_left")
            return cls(EmissionSettings(gas=GasProperties(**d["gas"]),
                                        pressure_pa=float(d["pressure_pa"]),
                                        background_frames=int(d["background_frames"])),
                       None if d["gas_temperature_k"] is None
                       else float(d["gas_temperature_k"]),
                       None if curve is None else CharacteristicCurve(
                           offset=float(curve["offset"]), gain=float(curve["gain"])))
        except (KeyError, TypeError, json.JSONDecodeError) as exc:
            raise ValueError(f"bad emission metadata: {exc}") from None

    def estimator(self, geometry: StereoGeometry) -> EmissionEstimator | None:
        """The estimator, or None without a radiometric calibration."""
        curve = geometry.curve_left or self.curve_left
        if curve is None:
            return None
        return EmissionEstimator(self.settings, geometry.principal_point,
                                 geometry.camera_constant, curve)

    def temperature_k(self, sonic_k: Any = None) -> float:
        """The gas temperature now: configured, else the sonic one, else 15 degC."""
        if self.gas_temperature_k is not None:
            return self.gas_temperature_k
        t = float("nan") if sonic_k is None else float(sonic_k.value)
        return t if np.isfinite(t) and 150.0 < t < 400.0 else DEFAULT_GAS_TEMPERATURE_K


#: The rate of a frame when the cameras have no radiometric calibration.
NO_RADIOMETRY = FrameRate(None, (), "no radiometric calibration (counts are not radiance)")


def emission_rate(estimator: EmissionEstimator, left_t1: np.ndarray, res: SceneFlowResult,
                  gas_temperature_k: float) -> FrameRate:
    """The stereo emission rate of one triple from the raw left frame at t1; a failure is a
    rate with its reason, never a lost result."""
    try:
        return estimator.frame_rate(left_t1, flow=res.flow, velocity=res.velocity,
                                    depth=res.position[..., 2], valid=res.valid,
                                    gas_mask=res.gas_mask, dt_s=res.dt_s,
                                    gas_temperature_k=gas_temperature_k)
    except (ValueError, FloatingPointError) as exc:
        return FrameRate(None, (), f"emission rate failed: {exc}")


def _to_u8(image: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(image * 255.0), 0, 255).astype(np.uint8)


def pack_result(res: SceneFlowResult, base: WorkerResult,
                raw_left: np.ndarray | None = None, *, fields: bool = True) -> WorkerResult:
    """Fill ``base`` with what the daemon needs from a chain result (and the raw left frame
    at t0, which the operator's view shows under the gas overlay).

    Without ``fields`` only what every result needs travels - summary, gas mask and the
    flow at the gas pixels (the leak events), the gas arrows - about 0.1-0.3 MB instead of
    2.6 MB at 320x240: the daemon records the full fields of every N-th result and shows
    pictures a few times a second, and pickling, piping and unpickling the rest cost both
    processes ~2-3 ms each.
    """
    base.summary = res.summary.to_dict()
    base.timings_ms = dict(res.timings_ms)
    base.dt_s = res.dt_s
    base.diff_scale = res.diff_scale
    base.rejected_shifts = res.rejected_shifts
    base.warm = bool(res.warm)
    base.gas_mask = res.gas_mask
    base.gas_flow = res.flow.reshape(-1, 2)[np.flatnonzero(res.gas_mask)]
    if fields:
        base.flow = res.flow
        base.diff_left = _to_u8(res.diff_left[0])
        base.diff_right = _to_u8(res.diff_right[0])
        base.disparity = res.disparity
        base.disparity_change = res.disparity_change
        base.velocity = res.velocity
        base.valid = res.valid
    sel = np.flatnonzero((res.gas_mask & res.valid).ravel())
    if sel.size > MAX_ARROWS:
        sel = sel[:: int(np.ceil(sel.size / MAX_ARROWS))]
    base.points3d = res.position.reshape(-1, 3)[sel].copy()
    base.velocity3d = res.velocity.reshape(-1, 3)[sel].copy()
    w = res.gas_mask.shape[1]
    base.pixels = np.column_stack([sel % w, sel // w]).astype(np.int32)
    if raw_left is not None and fields:
        base.raw_left = np.array(raw_left, copy=True)
    return base


def share_of_stream(worker_id: int, n_workers: int) -> tuple[int, int]:
    """(stride, phase) of a worker's triples: every other one for two workers, else all."""
    from processing.chain.state import STRIDES

    if n_workers > 1 and n_workers in STRIDES:
        return n_workers, worker_id % n_workers
    return 1, 0


def _single_threaded() -> None:
    """One thread per worker: the daemon runs one worker per core."""
    import cv2

    cv2.setNumThreads(1)
    try:
        import numba

        numba.set_num_threads(1)
    except (ImportError, ValueError):
        pass


def worker_main(
    worker_id: int,
    ring_handle: Any,
    results: Any,
    stop: Any,
    geometry: StereoGeometry | None,
    params: ChainParameters,
    n_workers: int = 1,
    emission: EmissionSetup | None = None,
    sonic_k: Any = None,
    shift_table: Any = None,
    fields_wanted: Any = None,
) -> None:
    """Body of one worker process; returns when ``stop`` (an Event) is set.

    Parameters
    ----------
    worker_id : int
        Index of this worker (for the health counters).
    ring_handle : appliance.runtime.ring.RingHandle
        Shared-memory ring to attach to.
    results : multiprocessing.Queue
        Where :class:`WorkerResult` objects go.
    stop : multiprocessing.Event
        Set by the daemon to end the worker.
    geometry, params
        Stereo geometry (None at a single-camera site without a calibration) and chain
        parameters (see :mod:`processing.chain.driver`).
    n_workers : int
        How many workers share the stream (see the module docstring).
    emission : EmissionSetup or None
        Compute the emission rate of every triple (None: not at all).
    sonic_k : multiprocessing.Value or None
        The anemometer's latest sonic temperature, K (NaN: none yet).
    shift_table : shared array or None
        Registration shifts shared by the workers (:mod:`appliance.runtime.shiftshare`).
    fields_wanted : multiprocessing.Value or None
        Set by the daemon when it wants the full fields (to record them, or a picture for
        the live view); the worker that packs the next result sends them and clears it.
        None: every result carries them.
    """
    from appliance.memory import PeriodicTrim, keep_freed_memory
    from appliance.runtime.ring import PairRing
    from appliance.runtime.shiftshare import SharedShiftMemo

    os.environ.setdefault("OMP_NUM_THREADS", "1")
    keep_freed_memory()
    _single_threaded()
    # Started by multiprocessing from the daemon: it shares the daemon's resource tracker.
    ring = PairRing.attach(ring_handle, shared_tracker=True)
    stride, phase = share_of_stream(worker_id, n_workers)
    state = (ChainState(stride=stride) if shift_table is None
             else ChainState(stride=stride, shifts=SharedShiftMemo(shift_table)))
    # In order (warm) while at most half the ring behind; more than two workers share one
    # phase and take the newest window.
    max_lag = ring.capacity // 2 if n_workers <= 2 else None
    torn = 0
    undelivered = 0  # results the daemon did not take within a second (counted as skipped)
    trim = PeriodicTrim()
    from appliance.runtime.single_camera import SingleCameraWorker, window_camera

    estimator = (None if emission is None or geometry is None
                 else emission.estimator(geometry))
    single = SingleCameraWorker(params)
    own = -1  # triples this worker processed (the emission rate on every n-th)
    try:
        while not stop.is_set():
            lease = ring.take_newest(3, stride=stride, phase=phase, max_lag=max_lag)
            if lease is None:
                time.sleep(0.002)
                continue
            meta = lease.meta
            skipped = lease.skipped
            images = lease.copy()
            lease.release()
            if images is None:
                torn += 1  # overwritten while copying: the worker is far behind
                continue
            left, right = images
            t_mono = tuple(int((m["t_left_mono_ns"] + m["t_right_mono_ns"]) // 2) for m in meta)
            base = WorkerResult(
                worker=worker_id,
                pair_indices=tuple(int(m["pair_index"]) for m in meta),  # type: ignore[arg-type]
                t_mono_ns=t_mono,  # type: ignore[arg-type]
                t_wall_ns=int(meta[1]["t_wall_ns"]),
                skipped=skipped + torn + undelivered,
                done_mono_ns=0,
            )
            torn = undelivered = 0
            camera = window_camera(meta)
            try:
                full = fields_wanted is None or bool(fields_wanted.value)
                if full and fields_wanted is not None:
                    fields_wanted.value = 0  # two workers may both send: harmless
                own += 1
                rate_due = emission is not None and own % emission.every == 0
                if camera is not None:
                    tr = single(camera, left if camera == "left" else right, t_mono, base)
                    pack_single(tr, base, camera, fields=full)
                    if emission is not None:
                        base.rate = single.rate(
                            estimator if camera == "left" else None, emission,
                            (left if camera == "left" else right)[1], tr, base.dt_s,
                            sonic_k, rate_due)
                else:
                    if geometry is None:
                        raise ValueError("a stereo pair at a site without stereo geometry")
                    res = compute_scene_flow_on(left, right, t_mono, geometry, params, state)
                    pack_result(res, base, raw_left=left[0], fields=full)
                    if estimator is not None and emission is not None and rate_due:
                        base.rate = emission_rate(estimator, left[1], res,
                                                  emission.temperature_k(sonic_k))
                    elif emission is not None:
                        base.rate = NO_RADIOMETRY
            except ValueError as exc:  # bad frames: reported, the worker goes on
                base.error = f"{type(exc).__name__}: {exc}"
            except Exception:
                base.error = traceback.format_exc(limit=5)
            base.done_mono_ns = time.monotonic_ns()
            try:
                results.put(base, timeout=1.0)
            except queue.Full:
                undelivered += 1
            trim.tick()
    finally:
        ring.close()


def pack_single(tr: Any, base: WorkerResult, camera: str, *, fields: bool = True) -> None:
    """Fill ``base`` with a single-camera triple (:class:`~appliance.runtime.single_camera.
    MonoTriple`): gas mask and the flow at its pixels always, the flow, I_diff and the raw
    frame with the fields; no disparity, no 3D velocity."""
    n = int(tr.mask.sum())
    flags = ["single_camera"] + ([] if camera == "left" else ["right_camera"])
    base.single_camera = camera
    base.summary = {"gas_pixel_count": n, "valid": False, "mean_velocity": None,
                    "speed": None, "angles_deg": None, "c_usf": None, "flags": flags}
    base.timings_ms = {**tr.timings_ms, "total": sum(tr.timings_ms.values())}
    base.rejected_shifts = tr.rejected_shifts
    base.gas_mask = tr.mask
    base.gas_flow = tr.flow.reshape(-1, 2)[np.flatnonzero(tr.mask)]
    if fields:
        base.flow = tr.flow
        base.diff_left = _to_u8(tr.diff)
        base.raw_left = np.array(tr.raw, copy=True)


def compute_scene_flow_on(left: np.ndarray, right: np.ndarray, t_mono_ns: tuple[int, ...],
                          geometry: StereoGeometry, params: ChainParameters,
                          state: ChainState) -> SceneFlowResult:
    """Run the chain on (3, H, W) left/right stacks with host monotonic ns times."""
    from processing.chain.driver import compute_scene_flow

    times = tuple(t / 1e9 for t in t_mono_ns)
    return compute_scene_flow(list(left), list(right), times, geometry, params, state)


def emission_setup(cfg: Any, truth: Any = None) -> EmissionSetup | None:
    """The workers' emission settings from the ``emission`` section (None: disabled);
    ValueError for a bad gas file (a configuration error). A simulated scene (``truth``, a
    :class:`SceneTruth`) lends its camera's counts model as the characteristic curve, its
    gas absorption as the gas-cell calibration, and its gas temperature."""
    from dataclasses import replace

    from processing.calibration.radiometric import CharacteristicCurve
    from processing.emission.estimator import EmissionSettings
    from processing.emission.gas import METHANE, load_gas

    em = cfg.emission
    if not em.enabled:
        return None
    gas = METHANE if em.gas_file is None else load_gas(em.gas_file)
    curve, t_gas = None, em.gas_temperature_k
    if truth is not None:
        counts = truth.meta["counts_model"]["left"]
        curve = CharacteristicCurve(offset=float(counts["offset"]), gain=float(counts["gain"]))
        rad = truth.meta["radiometry"]
        if em.gas_file is None:
            gas = replace(gas, alpha_per_ppm_m=float(rad["alpha_per_ppm_m"]),
                          source="the simulated scene's")
        if t_gas is None:
            # The simulated anemometer's sonic temperature is not the scene's gas
            # temperature (the renderer's plume is colder than the air around it).
            t_gas = float(rad["t_gas_k"])
    return EmissionSetup(EmissionSettings(gas=gas, pressure_pa=em.pressure_pa,
                                          background_frames=em.background_frames,
                                          typed_distance_m=em.single_camera_distance_m),
                         t_gas, curve, every=em.every)
