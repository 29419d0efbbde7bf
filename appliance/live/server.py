"""The Rerun viewer server process of ``live.mode: serve``.

The ``rerun`` CLI runs as a child process (``--serve-web --bind ADDRESS``) after both ports
were checked free on the bind address. ``rr.serve_grpc`` / ``rr.serve_web_viewer`` cannot be
used: they always listen on every interface and do not report a busy port, while the viewer
must stay on 127.0.0.1 unless the site decides otherwise.
"""

from __future__ import annotations

import ctypes
import importlib.util
import os
import shutil
import signal
import socket
import subprocess
import time
import urllib.parse
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from appliance.memory import with_mimalloc_purge

__all__ = ["LiveViewError", "ViewerServer", "check_port_free", "start_viewer_server"]

#: How long the server may take to listen before start-up fails.
START_TIMEOUT_S = 30.0


class LiveViewError(RuntimeError):
    """The live view could not start (port busy, server did not come up)."""


def check_port_free(host: str, port: int, what: str) -> None:
    """Raise :class:`LiveViewError` naming the setting when ``host:port`` cannot be bound."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as s:
        # Like the servers themselves: TIME_WAIT leftovers do not count as busy.
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError as exc:
            raise LiveViewError(
                f"live.{what} {port} on {host} is not available ({exc.strerror}); another "
                f"program (or another ogiflow) uses it - stop it or choose another port with "
                f"--set live.{what}=PORT") from None


def _pdeathsig_hook() -> Callable[[], None] | None:
    """A ``preexec_fn`` making the viewer server die with us (a leftover server would keep
    the ports busy), or None where prctl is unavailable.

    libc is loaded here, in the parent: the child, forked from a threaded process, only makes
    the one system call before exec.
    """
    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None

    def hook() -> None:  # pragma: no cover - runs in the child between fork and exec
        prctl(1, int(signal.SIGTERM))  # PR_SET_PDEATHSIG

    return hook


def _rerun_binary() -> str:
    """The Rerun CLI binary shipped in rerun-sdk (run directly, not through ``python -m
    rerun``, whose wrapper process would survive as the only one we can stop)."""
    override = os.environ.get("RERUN_CLI_PATH")
    if override:
        return override
    spec = importlib.util.find_spec("rerun_cli")
    if spec is not None and spec.origin is not None:
        path = Path(spec.origin).parent / "rerun"
        if path.is_file():
            return str(path)
    found = shutil.which("rerun")
    if found is None:
        raise LiveViewError("the Rerun viewer binary (package rerun-sdk) was not found")
    return found


def _client_host(bind: str) -> str:
    return {"0.0.0.0": "127.0.0.1", "::": "::1"}.get(bind, bind)


def _url_host(host: str) -> str:
    return f"[{host}]" if ":" in host else host


@dataclass
class ViewerServer:
    """A running viewer server: where to stream to and where to watch.

    Attributes
    ----------
    process
        The ``rerun`` child process.
    grpc_url
        What the recording stream connects to (``rerun+http://HOST:PORT/proxy``).
    view_url
        What a browser opens (web viewer page with the gRPC URL as its ``url`` parameter).
    """

    process: subprocess.Popen[bytes]
    grpc_url: str
    view_url: str

    def stop(self) -> None:
        """Terminate the server (kill it after 5 s) and reap it."""
        self.process.terminate()
        try:
            self.process.wait(5)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait(5)


def start_viewer_server(bind: str, grpc_port: int, web_port: int,
                        memory_limit: str) -> ViewerServer:
    """Start the Rerun gRPC server and web viewer on ``bind`` and wait until it listens.

    Call it from the main thread: the server is tied to the thread that started it
    (PR_SET_PDEATHSIG) so that it never outlives a crashed appliance.

    Parameters
    ----------
    bind
        Address to listen on (``live.bind``).
    grpc_port, web_port
        ``live.grpc_port`` (data) and ``live.web_port`` (web viewer).
    memory_limit
        How much the server buffers for late viewers (``--server-memory-limit``, e.g. 512MB).

    Raises
    ------
    LiveViewError
        A port is busy, or the server exited or did not listen within 30 s.
    """
    check_port_free(bind, grpc_port, "grpc_port")
    check_port_free(bind, web_port, "web_port")
    cmd = [_rerun_binary(), "--serve-web", "--bind", bind,
           "--port", str(grpc_port), "--web-viewer-port", str(web_port),
           "--server-memory-limit", memory_limit]
    proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, preexec_fn=_pdeathsig_hook(),
                            env=with_mimalloc_purge(os.environ))
    host = _client_host(bind)
    shown = _url_host(socket.gethostname() if bind in ("0.0.0.0", "::") else host)
    view = f"rerun+http://{shown}:{grpc_port}/proxy"
    server = ViewerServer(proc, f"rerun+http://{_url_host(host)}:{grpc_port}/proxy",
                          f"http://{shown}:{web_port}/?url={urllib.parse.quote(view, safe='')}")
    deadline = time.monotonic() + START_TIMEOUT_S
    while True:
        if proc.poll() is not None:
            raise LiveViewError(f"the Rerun viewer server exited at start "
                                f"(code {proc.returncode}): {' '.join(cmd)}")
        try:
            socket.create_connection((host, grpc_port), timeout=0.5).close()
            return server
        except OSError:
            if time.monotonic() > deadline:
                server.stop()
                raise LiveViewError(f"the Rerun viewer server did not listen on "
                                    f"{host}:{grpc_port} within {START_TIMEOUT_S:.0f} s") from None
            time.sleep(0.1)
