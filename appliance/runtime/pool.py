"""The worker pool: the shared-memory ring, the worker processes and the results thread.

The daemon owns one pool per run. Pairs enter through :attr:`WorkerPool.ring` (the pairing
thread writes, never waits); the workers take the newest consecutive windows; one thread takes
their results from a pipe per worker (:mod:`appliance.runtime.result_channel`) and hands each
to the daemon's handler. A worker that dies (OOM killer, a crash in native code) is replaced by
:meth:`WorkerPool.supervise`, with a new pipe and the shared locks it may have held given back.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing as mp
import threading
from collections.abc import Callable
from typing import Any

import numpy as np

from appliance.config import Config
from appliance.runtime.acquisition import Counters
from appliance.runtime.gas_temperature import GateTemperature
from appliance.runtime.imageshare import create_image_table
from appliance.runtime.keepup import peak_rss_mb
from appliance.runtime.result_channel import ResultReceiver
from appliance.runtime.ring import PairRing
from appliance.runtime.shiftshare import create_shift_table
from appliance.runtime.worker_result import WorkerResult
from appliance.runtime.workers import worker_main
from processing.chain.driver import ChainParameters, StereoGeometry

log = logging.getLogger("ogiflow")

#: Results in flight from the workers to the daemon, all workers together (see
#: :meth:`WorkerPool._start_worker`).
RESULTS_QUEUE_SIZE = 8
#: How long a lock a worker shares stays taken after that worker died before it is taken to be
#: the dead worker's (its critical sections last microseconds).
ORPHANED_LOCK_WAIT_S = 2.0


class WorkerPool:
    """Ring, worker processes and results thread of one run.

    Parameters
    ----------
    cfg : Config
        Validated configuration (``ring.capacity``, ``processing.workers``/``enabled``).
    geometry : StereoGeometry or None
        Camera geometry (None at a single-camera site without a calibration).
    image_size : (int, int)
        (W, H) of the images: the ring's slots.
    params : ChainParameters
        Parameters of the scene-flow chain, the same for every worker.
    emission : Any
        Emission set-up for the workers (``emission_setup.emission_setup``), or None.
    handle : callable
        Called in the results thread with every :class:`WorkerResult`; an exception it raises
        is logged and the next result taken.
    counters : Counters
        The run's counters (``worker_restarts``).
    gate : GateTemperature or None
        The opaque-edge gate at the site's gas temperature, set anew every triple
        (``processing.opaque_gate``); None: ``params`` as they are.
    """

    def __init__(self, cfg: Config, geometry: StereoGeometry | None,
                 image_size: tuple[int, int], params: ChainParameters, emission: Any,
                 handle: Callable[[WorkerResult], None],
                 counters: Counters, gate: GateTemperature | None = None) -> None:
        self.cfg = cfg
        self.geometry = geometry
        self.image_size = image_size
        self.params = params
        self.emission = emission
        self.gate = gate
        self._handle = handle
        self.ring: Any = None
        #: The anemometer's sonic temperature (K), shared with the workers for the gas
        #: temperature of the emission rate and the opaque-edge gate.
        self.sonic_k: Any = None
        #: Set when the daemon wants the next result's full fields (``workers.worker_main``).
        self.fields_wanted: Any = None
        self.counters = counters
        self._workers: list[Any] = []
        self._done = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self, stack: contextlib.ExitStack,
              spawn: Callable[..., threading.Thread]) -> WorkerPool:
        """Create the ring, start the workers and the results thread; teardown on ``stack``.

        ``spawn(target, name, *args)`` starts a guarded daemon thread (the daemon's, so that
        an exception escaping the results loop ends the run with exit code 1).
        """
        w, h = self.image_size
        self.ring = PairRing.create(self.cfg.ring.capacity, (h, w), np.uint16)
        stack.callback(self._release_ring)
        self._mp = mp.get_context("spawn")
        self._results = ResultReceiver(self._mp)
        self._stop = self._mp.Event()
        self._shift_table = create_shift_table(self._mp)
        # Only workers that alternate share frames and differences (one worker keeps its own).
        self._image_table = (create_image_table(self._mp, self.image_size, self.params.binning)
                             if self.cfg.processing.workers > 1 else None)
        self.sonic_k = self._mp.Value("d", float("nan"), lock=False)
        self.fields_wanted = self._mp.Value("b", 1, lock=False)
        stack.callback(self.stop)
        if self.cfg.processing.enabled:
            self._workers = [self._start_worker(i) for i in range(self.cfg.processing.workers)]
        else:
            self._done.set()
        self._thread = spawn(self._results_loop, "results")
        return self

    def supervise(self, stopping: bool) -> None:
        """Start a new worker in place of one that died: processing resumes with the next
        window of the ring."""
        for i, p in enumerate(self._workers):
            if p.is_alive() or stopping:
                continue
            log.error("worker %d exited (code %s); starting a new one", i, p.exitcode)
            self.counters.worker_restarts += 1
            # It may have died inside a critical section: the others would wait for ever.
            locks = [self.ring.reader_lock, self._shift_table.get_lock()]
            if self._image_table is not None:
                locks.append(self._image_table.lock)
            for lock in locks:
                free_if_orphaned(lock, ORPHANED_LOCK_WAIT_S)
            self._workers[i] = self._start_worker(i)

    @property
    def workers(self) -> list[Any]:
        """The worker processes now running (``multiprocessing.Process``)."""
        return list(self._workers)

    def worker_peak_rss_mb(self) -> list[float | None]:
        """Peak resident memory of each worker, MB (None: unknown); while they run."""
        return [peak_rss_mb(p.pid) for p in self._workers]

    def stop(self) -> None:
        """Stop the workers (terminate those that do not stop within 2 s), then the results
        thread once it has taken what the pipes hold."""
        self._stop.set()
        for p in self._workers:
            p.join(timeout=2.0)
            if p.is_alive():
                p.terminate()
        self._done.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        if self._thread is None or not self._thread.is_alive():
            self._results.close()  # else the thread still reads them; they go with the process

    def _start_worker(self, i: int) -> Any:
        n = self.cfg.processing.workers
        # About half a second of results: each carries 0.1-0.3 MB (2.6 MB with the full
        # fields the daemon asked for), and what the daemon has not read is held in the
        # workers' memory (64 made 130-160 MB steps when the daemon was starved of CPU). A
        # result not taken within 1 s is counted as a skipped triple.
        buffered = max(1, RESULTS_QUEUE_SIZE // n)
        with self._results.pipe() as pipe:
            p = self._mp.Process(target=worker_main, name=f"ogiflow-worker-{i}",
                                 args=(i, self.ring.handle(), (pipe, buffered), self._stop,
                                       self.geometry, self.params, n, self.emission,
                                       self.sonic_k, self._shift_table, self.fields_wanted,
                                       self._image_table, self.gate),
                                 daemon=True)
            p.start()
        return p

    def _results_loop(self) -> None:
        while True:
            batch: list[WorkerResult] = self._results.get(timeout=0.1)
            if not batch and self._done.is_set():
                break
            for res in batch:
                try:
                    self._handle(res)
                except Exception:
                    log.exception("result of pair %s could not be handled", res.pair_indices)

    def _release_ring(self) -> None:
        self.ring.close()
        self.ring.unlink()


def free_if_orphaned(lock: Any, wait_s: float) -> bool:
    """Give back ``lock`` (a ``multiprocessing.Lock``) if a dead process may hold it.

    A worker's critical sections last microseconds, so a lock that stays taken for
    ``wait_s`` after a worker died was held by that worker: it is released here, or every
    other worker would wait on it for ever. Returns True if it was released so.
    """
    if lock.acquire(timeout=wait_s):
        lock.release()
        return False
    log.error("a lock held by the dead worker released")
    lock.release()
    return True
