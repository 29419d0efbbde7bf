"""Pipeline worker processes: take the newest consecutive stereo pairs, run the chain.

Each worker is a separate process (both cores are used; numpy, numba and OpenCV release
the GIL only partly) that attaches to the shared-memory ring, repeatedly claims the
newest window of three consecutive pairs (t0, t1, t2), copies it out, and runs
:func:`processing.chain.driver.compute_scene_flow` - the same function replay, evaluation and
benchmarks call. When processing falls behind, older windows are skipped and counted;
acquisition and recording never wait for a worker. Results go back to the daemon through
a pipe per worker (:mod:`appliance.runtime.result_channel`) as :class:`WorkerResult`
(fields reduced to what the recorder and the live view need).

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
import time
import traceback
from typing import Any

import cv2
import numba
import numpy as np

from appliance.memory import PeriodicTrim, keep_freed_memory
from appliance.runtime.emission_setup import NO_RADIOMETRY, EmissionSetup, emission_rate
from appliance.runtime.gas_temperature import GateTemperature
from appliance.runtime.imageshare import SharedImages
from appliance.runtime.result_channel import ResultSender
from appliance.runtime.ring import PairRing
from appliance.runtime.shiftshare import SharedShiftMemo
from appliance.runtime.single_camera import SingleCameraWorker, window_camera
from appliance.runtime.worker_result import WorkerResult, pack_result, pack_single
from appliance.threads import set_os_thread_name
from processing.chain.driver import (
    ChainParameters,
    ChainState,
    SceneFlowResult,
    StereoGeometry,
    compute_scene_flow,
)
from processing.chain.state import STRIDES


def share_of_stream(worker_id: int, n_workers: int) -> tuple[int, int]:
    """(stride, phase) of a worker's triples: every other one for two workers, else all."""
    if n_workers > 1 and n_workers in STRIDES:
        return n_workers, worker_id % n_workers
    return 1, 0


def single_threaded() -> None:
    """One thread per worker: the daemon runs one worker per core."""
    cv2.setNumThreads(1)
    try:
        numba.set_num_threads(1)
    except ValueError:
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
    image_table: Any = None,
    gate: GateTemperature | None = None,
) -> None:
    """Body of one worker process; returns when ``stop`` (an Event) is set.

    Parameters
    ----------
    worker_id : int
        Index of this worker (for the health counters).
    ring_handle : appliance.runtime.ring.RingHandle
        Shared-memory ring to attach to.
    results : (multiprocessing.connection.Connection, int)
        Where :class:`WorkerResult` objects go: the write end of this worker's pipe
        (:class:`appliance.runtime.result_channel.ResultReceiver`) and how many results to
        buffer while the daemon does not read.
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
    image_table : ImageTable or None
        Differential images shared by the workers
        (:mod:`appliance.runtime.imageshare`); None: each worker computes its own.
    gate : GateTemperature or None
        Run the opaque-edge gate of every stereo triple at the site's gas temperature of
        that moment (``sonic_k``); None: ``params`` as they are.
    """
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    set_os_thread_name(f"ogiflow-worker{worker_id}")  # what top and ps show for the process
    keep_freed_memory()
    single_threaded()
    # Started by multiprocessing from the daemon: it shares the daemon's resource tracker.
    ring = PairRing.attach(ring_handle, shared_tracker=True)
    worker = _Worker(worker_id, ring, n_workers, geometry, params, emission, sonic_k,
                     shift_table, fields_wanted, image_table, gate)
    trim = PeriodicTrim()
    sender = ResultSender(*results)
    try:
        while not stop.is_set():
            window = worker.take()
            if window is None:
                continue
            base, camera, left, right = window
            worker.process(base, camera, left, right)
            worker.deliver(sender, base)
            trim.tick()
    finally:
        sender.close(timeout=1.0)
        ring.close()


class _Worker:
    """The state of one worker process between windows (see :func:`worker_main`)."""

    def __init__(self, worker_id: int, ring: PairRing, n_workers: int,
                 geometry: StereoGeometry | None, params: ChainParameters,
                 emission: EmissionSetup | None, sonic_k: Any, shift_table: Any,
                 fields_wanted: Any, image_table: Any = None,
                 gate: GateTemperature | None = None) -> None:
        self.worker_id, self.ring = worker_id, ring
        self.geometry, self.params, self.gate = geometry, params, gate
        self.emission, self.sonic_k, self.fields_wanted = emission, sonic_k, fields_wanted
        self.stride, self.phase = share_of_stream(worker_id, n_workers)
        self.state = ChainState(
            stride=self.stride,
            **({} if shift_table is None else {"shifts": SharedShiftMemo(shift_table)}),
            images=None if image_table is None else SharedImages(image_table))
        # In order (warm) while at most half the ring behind; more than two workers share
        # one phase and take the newest window.
        self.max_lag = ring.capacity // 2 if n_workers <= 2 else None
        self.torn = 0
        self.undelivered = 0  # results the daemon did not take within a second (skipped)
        self.estimator = (None if emission is None or geometry is None
                          else emission.estimator(geometry, params.binning))
        # a single camera's window runs on every pixel (no binning): its own estimator
        self.single_estimator = (self.estimator if params.binning == 1 or self.estimator is None
                                 else emission.estimator(geometry))  # type: ignore[union-attr]
        self.single = SingleCameraWorker(params)
        self.own = -1  # triples this worker processed (the emission rate on every n-th)

    def take(self) -> tuple[WorkerResult, str | None, np.ndarray, np.ndarray] | None:
        """The next window copied out of the ring: its result to fill, its single camera
        (None: stereo) and the (3, H, W) left and right frames (None: no window yet, or it
        was overwritten while copying)."""
        lease = self.ring.take_newest(3, stride=self.stride, phase=self.phase,
                                      max_lag=self.max_lag)
        if lease is None:
            time.sleep(0.002)
            return None
        meta = lease.meta
        skipped = lease.skipped
        images = lease.copy()
        lease.release()
        if images is None:
            self.torn += 1  # overwritten while copying: the worker is far behind
            return None
        left, right = images
        t_mono = tuple(int((m["t_left_mono_ns"] + m["t_right_mono_ns"]) // 2) for m in meta)
        base = WorkerResult(
            worker=self.worker_id,
            pair_indices=tuple(int(m["pair_index"]) for m in meta),  # type: ignore[arg-type]
            t_mono_ns=t_mono,  # type: ignore[arg-type]
            t_wall_ns=int(meta[1]["t_wall_ns"]),
            skipped=skipped + self.torn + self.undelivered,
            done_mono_ns=0,
        )
        self.torn = self.undelivered = 0
        return base, window_camera(meta), left, right

    def process(self, base: WorkerResult, camera: str | None, left: np.ndarray,
                right: np.ndarray) -> None:
        """Run the chain of the window's cameras into ``base``; bad frames become its
        ``error``, never an ended worker."""
        try:
            full = self.fields_wanted is None or bool(self.fields_wanted.value)
            if full and self.fields_wanted is not None:
                self.fields_wanted.value = 0  # two workers may both send: harmless
            self.own += 1
            rate_due = self.emission is not None and self.own % self.emission.every == 0
            if camera is not None:
                self._single(camera, left if camera == "left" else right, base, full,
                             rate_due)
            else:
                self._stereo(left, right, base, full, rate_due)
        except ValueError as exc:  # bad frames: reported, the worker goes on
            base.error = f"{type(exc).__name__}: {exc}"
        except Exception:
            base.error = traceback.format_exc(limit=5)
        base.done_mono_ns = time.monotonic_ns()

    def _single(self, camera: str, frames: np.ndarray, base: WorkerResult, full: bool,
                rate_due: bool) -> None:
        tr = self.single(camera, frames, base.t_mono_ns, base)
        pack_single(tr, base, camera, fields=full)
        if self.emission is not None:
            base.rate = self.single.rate(
                self.single_estimator if camera == "left" else None, self.emission, frames[1], tr,
                base.dt_s, self.sonic_k, rate_due)

    def _stereo(self, left: np.ndarray, right: np.ndarray, base: WorkerResult, full: bool,
                rate_due: bool) -> None:
        if self.geometry is None:
            raise ValueError("a stereo pair at a site without stereo geometry")
        if self.gate is not None:  # the gas temperature of this moment
            self.params = self.gate.parameters(self.params, self.sonic_k)
        res = compute_scene_flow_on(left, right, base.t_mono_ns, self.geometry, self.params,
                                    self.state)
        pack_result(res, base, raw_left=left[0], fields=full, binning=self.params.binning)
        if self.estimator is not None and self.emission is not None and rate_due:
            base.rate = emission_rate(self.estimator, left[1], res,
                                      self.emission.temperature_k(self.sonic_k))
        elif self.emission is not None:
            base.rate = NO_RADIOMETRY

    def deliver(self, sender: ResultSender, base: WorkerResult) -> None:
        """Send ``base`` to the daemon; one it does not take within a second is counted
        with the next result's skipped windows."""
        if not sender.put(base, timeout=1.0):
            self.undelivered += 1


def compute_scene_flow_on(left: np.ndarray, right: np.ndarray, t_mono_ns: tuple[int, ...],
                          geometry: StereoGeometry, params: ChainParameters,
                          state: ChainState) -> SceneFlowResult:
    """Run the chain on (3, H, W) left/right stacks with host monotonic ns times; with
    ``params.binning`` > 1 the result is on the chain's blocks (:func:`pack_result` and
    :func:`emission_rate` take it so and grow only what they send)."""
    times = tuple(t / 1e9 for t in t_mono_ns)
    return compute_scene_flow(list(left), list(right), times, geometry, params, state,
                              at_camera_size=False)
