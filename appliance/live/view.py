"""Rerun live view in its own thread, fed through slots that keep only the newest item.

A stalled viewer makes ``rr.log`` block for tens of seconds (docs/design.md), so nothing but this
module's thread ever calls Rerun: producers call :meth:`LiveView.push` with plain dataclasses
(:class:`LiveFrame`, :class:`OperatorStatus`, :class:`LiveScalars`), which returns at once. A
live view shows the present: the newest frame and the newest status each wait in a slot of
their own and replace an older one not yet shown (counted as dropped), so a slow viewer sees
fewer frames, never older ones, and the 1 Hz status is never crowded out by frames; health
samples (for plots) wait in a short queue of ``live.queue_size``. Images are encoded to JPEG
in the live thread (not raw uint16: 9.4 MB/s at 2 x 30 Hz); what is drawn for each item is in
:mod:`appliance.live.draw`.

Modes (``live.mode``):

- ``serve``: starts the Rerun gRPC server and web viewer (:mod:`appliance.live.server`, on
  ``live.bind``), then streams to it.
- ``connect``: streams to a viewer at ``live.url`` (``rr.connect_grpc``).
- ``save``: writes an ``.rrd`` file (``rerun rrd verify`` checks it).
- ``off``: nothing; :meth:`LiveView.push` is a no-op.

Entity paths: ``cam/left/diff``, ``cam/right/diff``, ``flow``, ``disparity``, ``gas/mask``,
``gas/velocity3d`` (Arrows3D at the virtual gas surface points), ``plots/speed/{gas,wind}``,
``plots/angle/{x,y,z}/{gas,wind}`` (paper Fig. 8), ``health/<name>``. Timelines: ``frame``
(pair index) and ``capture_time`` (wall clock).
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np

from appliance.config import LiveConfig
from appliance.live import draw
from appliance.live.blueprint import blueprint
from appliance.live.items import LiveFrame, LiveScalars, LiveStats, health_scalars
from appliance.live.server import LiveViewError, ViewerServer, start_viewer_server
from appliance.live.status import OperatorStatus
from appliance.memory import with_mimalloc_purge
from appliance.threads import NamedThread

__all__ = [
    "LiveFrame",
    "LiveScalars",
    "LiveStats",
    "LiveView",
    "LiveViewError",
    "health_scalars",
]

log = logging.getLogger("ogiflow.live")

APP_ID = "ogiflow"
#: After each frame the live thread waits at most this long for Rerun to send what it logged.
DRAIN_TIMEOUT_S = 2.0


# --------------------------------------------------------------------------- the view


class LiveView:
    """The live view thread. ``start()``, ``push()`` from anywhere, ``close()``.

    Parameters
    ----------
    cfg
        The ``live`` section of the configuration.
    server_memory_limit
        Serve mode: how much the gRPC server buffers for late viewers.
    max_image_hz
        Images (the heavy part) are sent at most this often; scalars, text and plots with
        every result. A browser on the appliance's own two cores decodes a few JPEGs per
        second; more piles up in its queue as display latency.
    """

    def __init__(self, cfg: LiveConfig, *, server_memory_limit: str = "512MB",
                 max_image_hz: float = 5.0) -> None:
        self.cfg = cfg
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        # The newest unsent frame and status, and the health samples (see the module doc).
        self._frame: LiveFrame | None = None
        self._status: OperatorStatus | None = None
        self._scalars: deque[LiveScalars] = deque()
        self._stats = LiveStats()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._rec: Any = None
        self._server: ViewerServer | None = None
        self._memory_limit = server_memory_limit
        self._image_period_ns = int(1e9 / max_image_hz) if max_image_hz > 0 else 0
        self._pending_blueprint: Any = None
        self._last_image_ns = 0

    # ------------------------------------------------------------------ producer side

    def push(self, item: LiveFrame | LiveScalars | OperatorStatus) -> bool:
        """Hand an item to the live thread; never waits on Rerun.

        A frame or status replaces the one of its kind not yet shown (that one is counted
        as dropped), except that a frame without pictures never replaces one with them (it
        is refused instead); a health sample is refused (False, counted) when
        ``live.queue_size`` wait already. False as well when the view is not running.
        """
        if self._thread is None:
            return False
        with self._wake:
            if isinstance(item, LiveScalars):
                if len(self._scalars) >= self.cfg.queue_size:
                    self._stats.dropped += 1
                    return False
                self._scalars.append(item)
            elif isinstance(item, OperatorStatus):
                self._stats.dropped += self._status is not None
                self._status = item
            else:
                if (not item.has_pictures and self._frame is not None
                        and self._frame.has_pictures):
                    self._stats.dropped += 1  # keep the pictures waiting to be shown
                    return False
                self._stats.dropped += self._frame is not None
                self._frame = item
            self._stats.pushed += 1
            self._wake.notify()
        return True

    def wants_pictures(self) -> bool:
        """Whether a frame with pictures would be shown now (``max_image_hz``) and none
        waits: the daemon then asks the workers for the full fields of their next result."""
        if self._thread is None:
            return False
        with self._wake:
            if self._frame is not None and self._frame.has_pictures:
                return False
        return time.monotonic_ns() - self._last_image_ns >= self._image_period_ns

    def stats(self) -> LiveStats:
        """A copy of the counters."""
        with self._lock:
            return LiveStats(**self._stats.__dict__)

    @property
    def url(self) -> str:
        """Where to watch (serve), where it streams (connect) or the file (save)."""
        return self._stats.url

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> LiveView:
        """Open the sink (and, in serve mode, the server) and start the thread.

        Call it from the main thread: in serve mode the viewer server is tied to the thread
        that started it (PR_SET_PDEATHSIG) so that it never outlives a crashed appliance.

        Raises
        ------
        LiveViewError
            A port is busy or the server did not start.
        """
        mode = self.cfg.mode
        if mode == "off":
            return self
        # Before the first import of rerun: its allocator reads the setting when it loads.
        os.environ.update(with_mimalloc_purge(os.environ))
        # rerun is imported only when a live view starts (it costs ~1-2 s and memory).
        import rerun as rr

        self._rec = rr.RecordingStream(application_id=APP_ID)
        bp = blueprint()
        if mode == "save":
            path = Path(self.cfg.file)
            path.parent.mkdir(parents=True, exist_ok=True)
            self._rec.save(str(path), default_blueprint=bp)
            self._stats.url = str(path)
        elif mode == "connect":
            # No blueprint here: connect_grpc flushes it synchronously, and a viewer that
            # accepts but never reads would hang the caller (the daemon's start-up) once
            # the blueprint exceeds the transport's window. The live thread sends it.
            self._rec.connect_grpc(self.cfg.url)
            self._stats.url = self.cfg.url
            self._pending_blueprint = bp
        elif mode == "serve":
            grpc_url = self._start_server()
            self._rec.connect_grpc(grpc_url)
            self._pending_blueprint = bp
        else:
            raise ValueError(f"live.mode: unknown mode {mode!r}")
        self._thread = NamedThread(target=self._run, name="live-view", daemon=True)
        self._thread.start()
        return self

    def _start_server(self) -> str:
        cfg = self.cfg
        self._server = start_viewer_server(cfg.bind, cfg.grpc_port, cfg.web_port,
                                           self._memory_limit)
        self._stats.url = self._server.view_url
        return self._server.grpc_url

    def _stop_server(self) -> None:
        srv, self._server = self._server, None
        if srv is not None:
            srv.stop()

    def close(self, timeout: float = 3.0) -> bool:
        """Stop the thread and the sink. Returns False when the thread was stuck in Rerun
        (a stalled viewer): it is then abandoned (a daemon thread) rather than waited for."""
        ok = True
        if self._thread is not None:
            with self._wake:
                self._stop.set()
                self._wake.notify()
            self._thread.join(timeout)
            if self._thread.is_alive():
                log.warning("live view: Rerun did not return within %.1f s; abandoning it",
                            timeout)
                ok = False
            elif self._rec is not None:
                try:
                    self._rec.flush(timeout_sec=timeout)
                    self._rec.disconnect()
                except Exception as exc:  # a viewer problem must not fail the shutdown
                    log.warning("live view: closing the stream failed: %s", exc)
            self._thread = None
        self._stop_server()
        return ok

    def __enter__(self) -> LiveView:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ live thread

    def _run(self) -> None:
        if self._pending_blueprint is not None:  # may block on a stalled viewer: only here
            self._rec.send_blueprint(self._pending_blueprint, make_active=True,
                                     make_default=True)
            self._pending_blueprint = None
        draw.log_styles(self._log)
        while True:
            with self._wake:
                while not (self._stop.is_set() or self._frame is not None
                           or self._status is not None or self._scalars):
                    self._wake.wait()
                # What is pending at a stop is still shown (a save-mode file ends complete).
                stopping = self._stop.is_set()
                status, self._status = self._status, None
                scalars = list(self._scalars)
                self._scalars.clear()
                frame, self._frame = self._frame, None
            # The status first: it is what the operator reads, and it is small.
            for item in (status, *scalars, frame):
                if item is not None:
                    self._show(item)
            if frame is not None:
                self._drain()
            if stopping:
                break

    def _show(self, item: LiveFrame | LiveScalars | OperatorStatus) -> None:
        try:
            if isinstance(item, LiveFrame):
                self._log_frame(item)
            elif isinstance(item, OperatorStatus):
                self._log_status(item)
            else:
                self._log_scalars(item)
            with self._lock:
                self._stats.logged += 1
        except Exception as exc:  # bad item or viewer error: count it, keep the view alive
            with self._lock:
                self._stats.errors += 1
                self._stats.last_error = f"{type(exc).__name__}: {exc}"
            if self._stats.errors in (1, 10, 100) or self._stats.errors % 1000 == 0:
                log.warning("live view: %s (%d errors)", exc, self._stats.errors)

    def _drain(self) -> None:
        """Wait until Rerun has sent everything logged so far (at most DRAIN_TIMEOUT_S).

        ``rr.log`` only queues: when the server cannot take the stream as fast as it comes
        (a browser on the appliance's two cores starves it), Rerun's queue inside this
        process grew without bound - measured +220 MB in the daemon and a displayed frame
        that fell further behind every second (25 -> 48 s in 30 s). Waiting here holds
        the backlog to about one frame; the frames that arrive meanwhile replace each other
        in the frame slot (counted as ``live_drops``), so the view shows fewer but current
        frames.
        """
        try:
            self._rec.flush(timeout_sec=DRAIN_TIMEOUT_S)
        except RuntimeError:  # "Flush timed out": the data stays queued, counted here
            with self._lock:
                self._stats.slow_sends += 1

    def _log(self, path: str, *args: Any, **kwargs: Any) -> None:
        self._rec.log(path, *args, **kwargs)

    def _set_time(self, frame: int | None, t_ns: int) -> None:
        if frame is not None:
            self._rec.set_time("frame", sequence=int(frame))
        self._rec.set_time("capture_time", timestamp=np.datetime64(int(t_ns), "ns"))

    def _log_frame(self, f: LiveFrame) -> None:
        self._set_time(f.frame, f.t_capture_ns)
        draw.log_plots(self._log, f)
        if not f.has_pictures:
            return
        now = time.monotonic_ns()
        if now - self._last_image_ns < self._image_period_ns:
            return  # images at most max_image_hz: the browser must keep up (latency)
        self._last_image_ns = now
        draw.log_pictures(self._log, f, self.cfg.jpeg_quality)

    def _log_status(self, s: OperatorStatus) -> None:
        self._set_time(None, s.t_capture_ns)
        draw.log_status(self._log, s)

    def _log_scalars(self, s: LiveScalars) -> None:
        self._set_time(s.frame, s.t_capture_ns)
        draw.log_scalars(self._log, s)
