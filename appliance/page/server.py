"""The operator's page over HTTP (aiohttp), in a thread of its own with its own event loop.

Routes (all read-only; nothing here writes or controls the appliance):

- ``GET /``, ``/page.js``, ``/page.css``: the page (``static/``);
- ``GET /events``: server-sent events, ``status`` (the leak monitor's snapshot, on every
  change of leak state and once per health report) and ``frame`` (the newest picture's
  number, capture time and URL, up to ``live.page.max_image_hz``);
- ``GET /frame/<seq>.jpg``: one of the last pictures (404 once it is gone);
- ``GET /status.json``: the same snapshot as the page, with the newest picture's notice;
- ``GET /metrics``: the Prometheus text format (:mod:`appliance.runtime.metrics`).

Every client of ``/events`` has its own :class:`ClientFeed`: one slot per message kind
holding the newest message not yet sent, so a slow or stalled browser gets fewer, newer
messages (the replaced ones are counted as its drops) and never holds up the hub, another
client, acquisition, recording or processing. Unknown paths get 404, other methods 405,
request lines or header fields over 4 kB and more than 32 header fields 400 (aiohttp's
parser), a body over 1 kB 413, malformed requests 400.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import socket
import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass
from importlib import resources
from typing import Any

from appliance.config.schema import ConfigError
from appliance.page.hub import PageHub, json_text
from appliance.threads import NamedThread

__all__ = ["ClientFeed", "PageServer", "ServerStats"]

log = logging.getLogger("ogiflow.page")

#: Request line / header field / header count limits (a browser sends far less).
MAX_LINE = 4096
MAX_HEADERS = 32
#: Largest request body accepted (the page sends none), bytes.
MAX_BODY = 1024
#: A keep-alive comment on an idle event stream this often, s (finds dead connections).
KEEPALIVE_S = 15.0
#: A client whose socket takes no data for this long is disconnected, s (its browser
#: reconnects by itself; one that stops reading for a minute is still served).
STALL_S = 120.0
#: How long the shutdown waits for open requests before it cancels them, s.
SHUTDOWN_S = 1.0
STATIC = {"/": ("index.html", "text/html"), "/page.js": ("page.js", "text/javascript"),
          "/page.css": ("page.css", "text/css")}
HEADERS = {
    "Content-Security-Policy": "default-src 'self'; img-src 'self'; style-src 'self'; "
                               "script-src 'self'; connect-src 'self'; frame-ancestors 'none'",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
}


class ClientFeed:
    """One event-stream client's queue: the newest message of each kind (event loop only)."""

    KINDS = ("status", "frame")

    def __init__(self) -> None:
        self.pending: dict[str, str] = {}
        self.sent = 0
        self.dropped = 0
        self.closing = False
        self.wake = asyncio.Event()

    def offer(self, kind: str, text: str) -> None:
        self.dropped += kind in self.pending
        self.pending[kind] = text
        self.wake.set()

    def take(self) -> list[tuple[str, str]]:
        """What waits, status first; empties the slots."""
        out = [(k, self.pending.pop(k)) for k in self.KINDS if k in self.pending]
        self.wake.clear()
        return out

    def close(self) -> None:
        self.closing = True
        self.wake.set()


@dataclass
class ServerStats:
    """Counters of the server (for /metrics and the health report)."""

    clients: int = 0
    clients_total: int = 0
    refused: int = 0
    messages_sent: int = 0
    #: Messages replaced in a client's queue before they were sent (that client only).
    client_drops: int = 0
    #: Most messages waiting in any one client's queue now (at most one per kind).
    queue_depth: int = 0
    frames_served: int = 0
    frames_gone: int = 0
    #: Malformed or oversized requests aiohttp's parser rejected with 400.
    bad_requests: int = 0


class _HttpLog(logging.LoggerAdapter):
    """aiohttp's server log: the parser's rejections of bad requests are counted instead of
    logged each with a traceback (a client must not be able to fill the journal);
    everything else is logged as aiohttp would."""

    def __init__(self, stats: ServerStats, lock: threading.Lock) -> None:
        super().__init__(logging.getLogger("ogiflow.page.http"), {})
        self.stats, self.lock = stats, lock

    def log(self, level: int, msg: object, *args: Any, **kwargs: Any) -> None:
        # aiohttp (~0.8 s to import) only when the operator's page is served.
        from aiohttp.http_exceptions import HttpProcessingError

        exc = kwargs.get("exc_info")
        if not isinstance(exc, BaseException):
            exc = sys.exc_info()[1]
        if isinstance(exc, HttpProcessingError):
            with self.lock:
                self.stats.bad_requests += 1
                n = self.stats.bad_requests
            if n in (1, 10, 100) or n % 1000 == 0:
                log.warning("operator page: rejected a bad request (%s; %d so far)",
                            type(exc).__name__, n)
            return
        super().log(level, msg, *args, **kwargs)


class PageServer:
    """The HTTP server thread. ``start()`` (binds, or raises ConfigError), ``close()``.

    Parameters
    ----------
    cfg
        The ``live.page`` section.
    hub
        Where the pictures and the status come from.
    metrics
        Returns the ``/metrics`` body (Prometheus text format) and its content type.
    """

    def __init__(self, cfg: Any, hub: PageHub,
                 metrics: Callable[[], tuple[bytes, str]] | None = None) -> None:
        self.cfg = cfg
        self.hub = hub
        self.metrics = metrics
        self._feeds: set[ClientFeed] = set()
        self._stats = ServerStats()
        self._lock = threading.Lock()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._runner: Any = None
        self._thread: threading.Thread | None = None
        self._static = {path: (resources.files("appliance.page").joinpath(
            "static", name).read_bytes(), ctype) for path, (name, ctype) in STATIC.items()}
        self.port = 0
        self._http_log = _HttpLog(self._stats, self._lock)

    @property
    def url(self) -> str:
        host = {"0.0.0.0": "127.0.0.1", "::": "::1"}.get(self.cfg.bind, self.cfg.bind)
        return f"http://{f'[{host}]' if ':' in host else host}:{self.port}/"

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> PageServer:
        """Bind ``live.page.bind:port`` and serve from a daemon thread.

        Raises
        ------
        ConfigError
            The address cannot be bound (port in use, address not of this machine): a
            configuration problem, found before any device opens (exit code 2).
        """
        sock = self._bind()
        self.port = int(sock.getsockname()[1])
        started: concurrent.futures.Future[None] = concurrent.futures.Future()
        self._thread = NamedThread(target=self._serve, args=(sock, started),
                                   name="page-http", daemon=True)
        self._thread.start()
        started.result(timeout=30)
        self.hub.broadcast = self._broadcast_threadsafe
        return self

    def _bind(self) -> socket.socket:
        host, port = self.cfg.bind, int(self.cfg.port)
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        try:
            return socket.create_server((host, port), family=family, backlog=128)
        except OSError as exc:
            raise ConfigError([
                f"live.page.port: {port} on {host} is not available ({exc.strerror}); another "
                f"program (or another ogiflow) uses it - stop it, or choose another port with "
                f"--set live.page.port=PORT (or live.page.enabled=false)"]) from None

    def _serve(self, sock: socket.socket, started: concurrent.futures.Future[None]) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._setup(sock))
        except BaseException as exc:
            started.set_exception(exc)
            loop.close()
            return
        started.set_result(None)
        try:
            loop.run_forever()
        finally:
            loop.close()

    async def _setup(self, sock: socket.socket) -> None:
        # aiohttp (~0.8 s to import) only when the operator's page is served.
        from aiohttp import web

        @web.middleware
        async def guard(request: Any, handler: Any) -> Any:
            return await self._guard(request, handler)

        app = web.Application(client_max_size=MAX_BODY, middlewares=[guard])
        app.router.add_get("/", self._static_route)
        app.router.add_get("/page.js", self._static_route)
        app.router.add_get("/page.css", self._static_route)
        app.router.add_get("/events", self._events)
        app.router.add_get(r"/frame/{seq:\d{1,12}}.jpg", self._frame)
        app.router.add_get("/status.json", self._status)
        app.router.add_get("/metrics", self._metrics)
        self._runner = web.AppRunner(app, handle_signals=False, access_log=None,
                                     logger=self._http_log,
                                     shutdown_timeout=SHUTDOWN_S, max_line_size=MAX_LINE,
                                     max_field_size=MAX_LINE, max_headers=MAX_HEADERS)
        await self._runner.setup()
        await web.SockSite(self._runner, sock).start()

    def close(self, timeout: float = 5.0) -> None:
        """Stop serving: end the event streams, close connections, stop the thread."""
        self.hub.broadcast = None
        loop, thread = self._loop, self._thread
        if loop is None or thread is None or not thread.is_alive():
            return
        fut = asyncio.run_coroutine_threadsafe(self._shutdown(), loop)
        try:
            fut.result(timeout)
        except (concurrent.futures.TimeoutError, RuntimeError) as exc:
            log.warning("operator page: shutdown incomplete: %s", exc)
        loop.call_soon_threadsafe(loop.stop)
        thread.join(timeout)
        self._thread = None

    async def _shutdown(self) -> None:
        for feed in list(self._feeds):
            feed.close()
        if self._runner is not None:
            await self._runner.cleanup()
        # connections aiohttp let go of but whose tasks still wait (a stalled socket)
        rest = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
        for t in rest:
            t.cancel()
        await asyncio.gather(*rest, return_exceptions=True)

    # ------------------------------------------------------------------ broadcasting

    def _broadcast_threadsafe(self, kind: str, text: str) -> None:
        loop = self._loop
        if loop is not None and not loop.is_closed():
            try:
                loop.call_soon_threadsafe(self._broadcast, kind, text)
            except RuntimeError:  # the loop closed meanwhile (shutdown)
                pass

    def _broadcast(self, kind: str, text: str) -> None:
        for feed in self._feeds:
            feed.offer(kind, text)

    def stats(self) -> ServerStats:
        """A copy of the counters (drops of connected clients included)."""
        with self._lock:
            s = ServerStats(**self._stats.__dict__)
        feeds = list(self._feeds)
        s.client_drops += sum(f.dropped for f in feeds)
        s.queue_depth = max((len(f.pending) for f in feeds), default=0)
        return s

    # ------------------------------------------------------------------ handlers

    @staticmethod
    def _headers(extra: dict[str, str] | None = None) -> dict[str, str]:
        return {**HEADERS, "Cache-Control": "no-store", **(extra or {})}

    async def _guard(self, request: Any, handler: Any) -> Any:
        """Security headers on everything; a request body the page never sends: 413."""
        # aiohttp (~0.8 s to import) only when the operator's page is served.
        from aiohttp import web

        if request.content_length is not None and request.content_length > MAX_BODY:
            raise web.HTTPRequestEntityTooLarge(MAX_BODY, request.content_length)
        try:
            resp = await handler(request)
        except web.HTTPException as exc:
            exc.headers.update(HEADERS)
            raise
        if not resp.prepared:
            resp.headers.update({k: v for k, v in HEADERS.items() if k not in resp.headers})
        return resp

    async def _static_route(self, request: Any) -> Any:
        # aiohttp (~0.8 s to import) only when the operator's page is served.
        from aiohttp import web

        body, ctype = self._static[request.path]
        return web.Response(body=body, content_type=ctype, charset="utf-8",
                            headers=self._headers())

    async def _status(self, request: Any) -> Any:
        # aiohttp (~0.8 s to import) only when the operator's page is served.
        from aiohttp import web

        return web.Response(text=json_text(self.hub.status()), content_type="application/json",
                            headers=self._headers())

    async def _frame(self, request: Any) -> Any:
        # aiohttp (~0.8 s to import) only when the operator's page is served.
        from aiohttp import web

        enc = self.hub.frame(int(request.match_info["seq"]))
        with self._lock:
            if enc is None:
                self._stats.frames_gone += 1
            else:
                self._stats.frames_served += 1
        if enc is None:
            raise web.HTTPNotFound(text="picture no longer kept; the page shows the newest")
        return web.Response(body=enc.jpeg, content_type="image/jpeg", headers=self._headers({
            "X-Capture-Time-Ns": str(enc.t_capture_ns), "X-Frame": str(enc.frame)}))

    async def _metrics(self, request: Any) -> Any:
        # aiohttp (~0.8 s to import) only when the operator's page is served.
        from aiohttp import web

        if self.metrics is None:
            raise web.HTTPNotFound(text="no metrics")
        body, ctype = self.metrics()
        return web.Response(body=body, headers=self._headers({"Content-Type": ctype}))

    async def _events(self, request: Any) -> Any:
        # aiohttp (~0.8 s to import) only when the operator's page is served.
        from aiohttp import web

        with self._lock:
            if self._stats.clients >= self.cfg.max_clients:
                self._stats.refused += 1
                raise web.HTTPServiceUnavailable(text="too many browsers on this page")
            self._stats.clients += 1
            self._stats.clients_total += 1
        feed = ClientFeed()
        # What a new browser shows at once: the current status and the newest picture.
        feed.offer("status", json_text(self.hub.status()))
        newest = self.hub.newest_frame()
        if newest is not None:
            feed.offer("frame", json_text({**newest.notice(), "sent_ns": self.hub.clock()}))
        feed.dropped = 0
        self._feeds.add(feed)
        resp = web.StreamResponse(headers=self._headers({
            "Content-Type": "text/event-stream", "X-Accel-Buffering": "no"}))
        try:
            await resp.prepare(request)
            await resp.write(b"retry: 2000\n\n")
            while not feed.closing:
                try:
                    await asyncio.wait_for(feed.wake.wait(), KEEPALIVE_S)
                except asyncio.TimeoutError:
                    await asyncio.wait_for(resp.write(b": keepalive\n\n"), STALL_S)
                    continue
                for kind, text in feed.take():
                    await asyncio.wait_for(
                        resp.write(f"event: {kind}\ndata: {text}\n\n".encode()), STALL_S)
                    feed.sent += 1
        except (ConnectionError, asyncio.TimeoutError):
            pass  # the browser went away or stopped reading for STALL_S
        finally:
            self._feeds.discard(feed)
            with self._lock:
                self._stats.clients -= 1
                self._stats.messages_sent += feed.sent
                self._stats.client_drops += feed.dropped
        return resp
