"""Results from the worker processes to the daemon, safe against a worker killed at any time.

A worker can die between any two instructions (the OOM killer, SIGKILL, a crash in native
code). ``multiprocessing.Queue`` is not safe against that: its writers share one pipe and one
lock, and a writer killed while its feeder thread holds the lock or has written part of a
result leaves the lock taken and a torn message in the pipe. The reader then blocks for ever
inside that message, past any timeout (seen: the daemon's results thread hung when a worker was
killed while a 2.6 MB result with full fields was in the pipe, and no result came after the
worker was replaced).

Here each worker writes to a pipe of its own (:class:`ResultSender`), and the daemon closes
its copy of the write end once the worker holds it, so a dead worker's pipe - torn message or
not - reads as end of file and is dropped (:class:`ResultReceiver`); its replacement gets a new
pipe.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing.connection as mpc
import queue
import threading
import time
from collections.abc import Iterator
from multiprocessing.reduction import ForkingPickler
from typing import Any

log = logging.getLogger("ogiflow")

_STOP = object()


class ResultSender:
    """The worker's end: a bounded buffer and a thread that writes it to the daemon's pipe.

    Like ``multiprocessing.Queue.put``, :meth:`put` returns as soon as the result is buffered;
    the thread pickles and writes it, so the worker computes the next triple meanwhile.

    Parameters
    ----------
    conn : multiprocessing.connection.Connection
        Write end from :meth:`ResultReceiver.open`.
    maxsize : int
        Results buffered in the worker while the daemon does not read.
    """

    def __init__(self, conn: Any, maxsize: int) -> None:
        self._conn = conn
        self._buffer: queue.Queue[Any] = queue.Queue(maxsize=maxsize)
        self._thread = threading.Thread(target=self._run, name="results-sender", daemon=True)
        self._thread.start()

    def put(self, item: Any, timeout: float) -> bool:
        """Buffer ``item`` for the daemon; False if the buffer stayed full for ``timeout`` s."""
        try:
            self._buffer.put(item, timeout=timeout)
        except queue.Full:
            return False
        return True

    def close(self, timeout: float) -> None:
        """Write what is buffered (for at most ``timeout`` s), then close the pipe."""
        deadline = time.monotonic() + timeout
        # A full buffer with the daemon not reading: what is buffered is lost with the worker.
        while self._thread.is_alive() and time.monotonic() < deadline:
            try:
                self._buffer.put(_STOP, timeout=0.05)
                break
            except queue.Full:
                continue
        self._thread.join(max(0.0, deadline - time.monotonic()))
        if not self._thread.is_alive():
            self._conn.close()

    def _run(self) -> None:
        while (item := self._buffer.get()) is not _STOP:
            try:
                data = ForkingPickler.dumps(item)
            except Exception:  # this result only; the pipe is untouched
                log.exception("a result could not be pickled; dropped")
                continue
            try:
                self._conn.send_bytes(data)
            except (OSError, ValueError):  # the daemon closed its end: it is stopping
                return


class ResultReceiver:
    """The daemon's end: one pipe per worker, read by one thread.

    Parameters
    ----------
    ctx : multiprocessing context
        The context the workers are started with.
    """

    def __init__(self, ctx: Any) -> None:
        self._ctx = ctx
        self._lock = threading.Lock()
        self._readers: list[Any] = []  # read ends, one per worker not known to have ended

    @contextlib.contextmanager
    def pipe(self) -> Iterator[Any]:
        """A new pipe: yields its write end, to start one worker process with inside the
        block; on leaving it the daemon's copy is closed, so that the pipe reads as end of
        file once the worker is gone."""
        reader, writer = self._ctx.Pipe(duplex=False)
        with self._lock:
            self._readers.append(reader)
        try:
            yield writer
        finally:
            writer.close()

    @property
    def open_pipes(self) -> int:
        """Pipes still open (one per worker that has not ended)."""
        with self._lock:
            return len(self._readers)

    def get(self, timeout: float) -> list[Any]:
        """The results ready within ``timeout`` s, from any worker (empty: none)."""
        with self._lock:
            readers = list(self._readers)
        if not readers:
            time.sleep(timeout)
            return []
        items = []
        for reader in mpc.wait(readers, timeout):
            try:
                data = reader.recv_bytes()  # type: ignore[union-attr]
            except (EOFError, OSError):
                # The worker ended (a torn last result reads as end of file, too).
                self._drop(reader)
                continue
            try:
                items.append(ForkingPickler.loads(data))
            except Exception:  # this result only: the next one starts at a message boundary
                log.exception("a result could not be unpickled; dropped")
        return items

    def close(self) -> None:
        """Close every pipe (after the workers have ended)."""
        with self._lock:
            readers, self._readers = self._readers, []
        for conn in readers:
            conn.close()

    def _drop(self, reader: Any) -> None:
        with self._lock:
            self._readers = [r for r in self._readers if r is not reader]
        reader.close()

