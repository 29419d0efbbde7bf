"""A thread that reads an anemometer back end and hands samples on without ever waiting.

The daemon's acquisition must not stall on a slow consumer: samples go into a bounded queue;
when it is full the oldest sample is dropped (and counted) to make room. Optionally each
sample is also put into a :class:`~drivers.anemometer.history.WindHistory` in the camera frame
(lock held for microseconds) and passed to ``on_sample``, a callback that must return quickly
(it runs in the reader thread; its exceptions are counted, the last one kept).
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable

from drivers.anemometer.base import Anemometer, AnemometerError, WindSample
from drivers.anemometer.history import WindHistory
from drivers.anemometer.mounting import Mounting


class AnemometerReader:
    """Owns an :class:`Anemometer` (transport + decoder) and runs it in a daemon thread.

    Parameters
    ----------
    anemometer : Anemometer
        Any back end; closed by :meth:`stop`.
    queue_size : int
        Capacity of :attr:`samples`; when full the oldest sample is dropped.
    on_sample : callable, optional
        Called with each sample in the reader thread; must not block.
    history, mounting : optional
        When both are given, every sample is added to ``history`` in the camera frame.
    """

    def __init__(
        self,
        anemometer: Anemometer,
        *,
        queue_size: int = 4096,
        on_sample: Callable[[WindSample], None] | None = None,
        history: WindHistory | None = None,
        mounting: Mounting | None = None,
        poll_s: float = 0.2,
    ) -> None:
        if queue_size < 1:
            raise ValueError(f"queue_size must be >= 1, got {queue_size!r}")
        if (history is None) != (mounting is None):
            raise ValueError("history and mounting go together: give both or neither")
        self.anemometer = anemometer
        self.samples: queue.Queue[WindSample] = queue.Queue(maxsize=queue_size)
        self.on_sample = on_sample
        self.history = history
        self.mounting = mounting
        self.poll_s = poll_s
        self.received = 0
        self.dropped = 0
        self.callback_errors = 0
        self.last_callback_error: BaseException | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="anemometer-reader", daemon=True)

    def start(self) -> AnemometerReader:
        self._thread.start()
        return self

    def stop(self, timeout: float = 2.0) -> None:
        """Stop the thread and close the anemometer."""
        self._stop.set()
        self._thread.join(timeout)
        self.anemometer.close()

    def get(self, timeout: float | None = None) -> WindSample | None:
        """Next sample from the queue, or None after ``timeout`` seconds."""
        try:
            return self.samples.get(timeout=timeout)
        except queue.Empty:
            return None

    def _deliver(self, sample: WindSample) -> None:
        self.received += 1
        while True:
            try:
                self.samples.put_nowait(sample)
                break
            except queue.Full:
                try:
                    self.samples.get_nowait()
                    self.dropped += 1
                except queue.Empty:
                    pass
        if self.history is not None and self.mounting is not None:
            self.history.add(self.mounting.to_camera(sample))
        if self.on_sample is not None:
            try:
                self.on_sample(sample)
            except Exception as exc:  # a consumer bug must not stop acquisition
                self.callback_errors += 1
                self.last_callback_error = exc

    def _run(self) -> None:
        recv = self.anemometer.recv
        while not self._stop.is_set():
            try:
                sample = recv(self.poll_s)
            except AnemometerError:
                # The anemometer was closed under us: nothing more will come.
                return
            if sample is not None:
                self._deliver(sample)

    def __enter__(self) -> AnemometerReader:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
