"""sd_notify datagrams to a socket bound by the test, and the watchdog policy."""

from __future__ import annotations

import os
import socket
from collections.abc import Iterator
from pathlib import Path

import pytest

from appliance.runtime.sdnotify import SdNotifier, Watchdog, watchdog_period_s


@pytest.fixture(params=["path", "abstract"])
def notify_socket(request: pytest.FixtureRequest, tmp_path: Path
                  ) -> Iterator[tuple[str, socket.socket]]:
    """A datagram socket like systemd's; yields ($NOTIFY_SOCKET value, socket)."""
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    if request.param == "path":
        addr = str(tmp_path / "notify.sock")
        sock.bind(addr)
    else:
        name = f"ogiflow-test-{os.getpid()}-{id(sock)}"
        sock.bind("\0" + name)
        addr = "@" + name
    sock.settimeout(5)
    yield addr, sock
    sock.close()


def _recv(sock: socket.socket) -> str:
    return sock.recv(4096).decode()


def test_messages_reach_the_socket(notify_socket: tuple[str, socket.socket],
                                   monkeypatch: pytest.MonkeyPatch) -> None:
    addr, sock = notify_socket
    monkeypatch.setenv("NOTIFY_SOCKET", addr)
    n = SdNotifier()
    assert n.enabled
    assert n.ready("recording to /var/lib/ogiflow")
    assert _recv(sock) == "READY=1\nSTATUS=recording to /var/lib/ogiflow"
    assert n.status("pairs 30.0/s\nsecond line")
    assert _recv(sock) == "STATUS=pairs 30.0/s second line"  # one line only
    assert n.watchdog()
    assert _recv(sock) == "WATCHDOG=1"
    assert n.stopping()
    assert _recv(sock) == "STOPPING=1"
    n.close()


def test_disabled_without_notify_socket(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
    n = SdNotifier()
    assert not n.enabled
    assert not n.ready() and not n.watchdog()


def test_send_failure_is_counted_not_raised(tmp_path: Path) -> None:
    n = SdNotifier(str(tmp_path / "nobody-listens.sock"))
    assert not n.watchdog()
    assert n.errors == 1


def test_watchdog_period_is_half_of_watchdog_usec() -> None:
    assert watchdog_period_s({"WATCHDOG_USEC": "20000000"}) == 10.0
    assert watchdog_period_s({}) is None
    assert watchdog_period_s({"WATCHDOG_USEC": "0"}) is None
    assert watchdog_period_s({"WATCHDOG_USEC": "20000000", "WATCHDOG_PID": "1"}, pid=2) is None
    assert watchdog_period_s({"WATCHDOG_USEC": "20000000", "WATCHDOG_PID": "2"}, pid=2) == 10.0


def test_watchdog_pings_only_while_frames_arrive(notify_socket: tuple[str, socket.socket]
                                                 ) -> None:
    addr, sock = notify_socket
    wd = Watchdog(SdNotifier(addr), period_s=1.0, stall_s=5.0)
    wd.frame_arrived(now=100.0)
    assert wd.tick(now=100.5)
    assert _recv(sock) == "WATCHDOG=1"
    assert not wd.tick(now=101.0)  # not due yet (period 1 s)
    wd.frame_arrived(now=101.4)
    assert wd.tick(now=101.6)
    assert _recv(sock) == "WATCHDOG=1"
    # acquisition stalls: last frame at 101.4, pings stop once it is older than 5 s
    assert wd.tick(now=106.3)
    assert _recv(sock) == "WATCHDOG=1"
    assert wd.stalled(now=106.5)
    assert not wd.tick(now=106.5)
    assert not wd.tick(now=120.0)
    sock.settimeout(0.2)
    with pytest.raises(TimeoutError):
        sock.recv(4096)
    wd.frame_arrived(now=121.0)  # frames again: pings resume
    assert wd.tick(now=121.1)
    assert wd.pings == 4


def test_watchdog_disabled_without_period(notify_socket: tuple[str, socket.socket]) -> None:
    addr, _ = notify_socket
    wd = Watchdog(SdNotifier(addr), period_s=None, stall_s=5.0)
    assert not wd.tick()
