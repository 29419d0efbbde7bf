"""A simulated anemometer (Gill WindMaster by default) on a pseudo terminal, and its back end.

:class:`SimulatedSensor` is the device side: it creates a pty (``os.openpty``), points a
symlink you choose (or a temporary one) at its slave end and writes real Gill UVW frames with
correct checksums (or CSAT3B, R.M. Young UVW or METEK lines: ``protocol``) at a set rate,
with a constant, gusty or turbulent wind (seeded, so runs repeat). It records every frame it
sent with the true wind, answers Gill set-up mode (``*``, commands echoed, ``Q``) like a
sensor would, and can be "unplugged" (pty closed) and "replugged" (a new pty behind the same
symlink) to exercise reconnects.

:class:`SimulatedAnemometer` (registry name ``simulated``) runs such a sensor and reads it
through :class:`~drivers.anemometer.serial_transport.SerialAnemometer`, so the default
configuration and the tests drive the real serial and decoding code.
"""

from __future__ import annotations

import bisect
import contextlib
import errno
import math
import os
import select
import tempfile
import threading
import time
import tty
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.anemometer.base import Anemometer, AnemometerConfigError, DecoderCounts, WindSample
from drivers.anemometer.campbell import format_csat3b
from drivers.anemometer.gill import format_gill_uvw
from drivers.anemometer.metek import format_metek
from drivers.anemometer.registry import make_decoder
from drivers.anemometer.serial_transport import SerialAnemometer
from drivers.anemometer.wind_model import WIND_KINDS, WindModel
from drivers.anemometer.young import format_young

__all__ = ["ENCODERS", "WIND_KINDS", "SentFrame", "SimulatedAnemometer", "SimulatedSensor",
           "WindModel"]

#: Protocols the simulator can speak -> encoder of (index, u, v, w, sos, ts, node) in the
#: protocol's own axes and units.
ENCODERS = {
    "gill": lambda k, u, v, w, c, t, node: format_gill_uvw(u, v, w, c, t, 0, node=node),
    "campbell_csat3b": lambda k, u, v, w, c, t, node: format_csat3b(u, v, w, t, 0, k % 256),
    "young_81000_uvw": lambda k, u, v, w, c, t, node: format_young(u, v, w, c, t, uvw=True),
    "metek_usonic3": lambda k, u, v, w, c, t, node: format_metek(
        round(100 * u), round(100 * v), round(100 * w), round(100 * t)
    ),
}

@dataclass(frozen=True)
class SentFrame:
    """One frame the simulator wrote: when, the wind it carries (as encoded), delivered?"""

    index: int
    host_ns: int
    u: float
    v: float
    w: float
    delivered: bool


class SimulatedSensor:
    """A Gill WindMaster speaking UVW on a pty (see the module docstring).

    Parameters
    ----------
    rate_hz : float
        Frames per second.
    wind : WindModel
        The true wind, in the protocol's own axes.
    protocol : str
        One of :data:`ENCODERS` (default Gill WindMaster UVW). Set-up mode is answered for
        Gill only.
    link_path : str, optional
        Where to put the symlink to the pty slave (the port the driver opens). Default: a
        temporary directory of its own.
    node : str
        Gill node letter in each frame.
    temperature_c : float
        Sonic temperature sent; the speed of sound follows from it (c = sqrt(403 T)).
    """

    def __init__(
        self,
        rate_hz: float = 20.0,
        wind: WindModel | None = None,
        *,
        protocol: str = "gill",
        link_path: str | None = None,
        node: str = "Q",
        temperature_c: float = 20.0,
        history: int = 100_000,
    ) -> None:
        if not 0 < rate_hz <= 1000:
            raise AnemometerConfigError(f"rate_hz must be in (0, 1000], got {rate_hz!r}")
        if protocol not in ENCODERS:
            raise AnemometerConfigError(
                f"the simulator speaks {sorted(ENCODERS)}, not {protocol!r}"
            )
        self.rate_hz = rate_hz
        self.protocol = protocol
        self.wind = wind or WindModel()
        self.node = node
        self.temperature_c = temperature_c
        self._own_dir: str | None = None
        if link_path is None:
            self._own_dir = tempfile.mkdtemp(prefix="ogiflow-anemometer-")
            link_path = os.path.join(self._own_dir, "ttyGILL")
        self.link_path = link_path
        self._history = history
        self._lock = threading.Lock()
        self._sent: list[SentFrame] = []
        self._sent_ns: list[int] = []
        self._master: int | None = None
        self._slave: int | None = None
        self._stop = threading.Event()
        self._paused = threading.Event()
        self._thread: threading.Thread | None = None
        self._config_mode = False
        self._inbuf = b""
        self.frames_dropped = 0

    # -- device side -----------------------------------------------------------------
    def start(self) -> SimulatedSensor:
        self._plug()
        self._thread = threading.Thread(target=self._run, name="sim-anemometer", daemon=True)
        self._thread.start()
        return self

    def _plug(self) -> None:
        master, slave = os.openpty()
        # Raw, no echo: the line discipline must pass the bytes through untouched.
        tty.setraw(slave)
        os.set_blocking(master, False)
        tmp = self.link_path + ".new"
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        os.symlink(os.ttyname(slave), tmp)
        os.replace(tmp, self.link_path)
        with self._lock:
            self._master, self._slave = master, slave
            self._config_mode = False
            self._inbuf = b""

    def unplug(self) -> None:
        """Close the pty, as if the cable were pulled (the driver's reads fail)."""
        with self._lock:
            fds = (self._master, self._slave)
            self._master = self._slave = None
        for fd in fds:
            if fd is not None:
                os.close(fd)

    def replug(self) -> None:
        """A new pty behind the same symlink, as if the sensor came back."""
        if self._master is not None:
            self.unplug()
        self._plug()

    def pause(self) -> None:
        """Stop sending frames (the pty stays open, so what was sent can still be read)."""
        with self._lock:
            self._paused.set()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        self.unplug()
        with contextlib.suppress(FileNotFoundError):
            os.unlink(self.link_path)
        if self._own_dir is not None:
            with contextlib.suppress(OSError):
                os.rmdir(self._own_dir)

    def _run(self) -> None:
        period = 1.0 / self.rate_hz
        t0 = time.monotonic()
        k = 0
        while not self._stop.is_set():
            due = t0 + k * period
            self._serve_input(max(0.0, due - time.monotonic()))
            if time.monotonic() < due:
                continue
            if not self._config_mode and not self._paused.is_set():
                self._send(k, due - t0)
            k += 1
            if time.monotonic() - due > 1.0:
                # Fell far behind (machine stalled): resynchronise the clock, don't burst.
                t0 = time.monotonic() - k * period

    def _send(self, index: int, t_s: float) -> None:
        u, v, w = self.wind.at(t_s)
        temp = self.temperature_c
        sos = math.sqrt(403.0 * (temp + 273.15))
        frame = ENCODERS[self.protocol](index, u, v, w, sos, temp, self.node)
        # The wind as it goes out, exactly as a decoder will read it back (rounded by the
        # format): decoded from the frame itself.
        (echo,) = make_decoder(self.protocol).decode_all(frame)
        with self._lock:
            if self._paused.is_set():
                return
            # Stamp before the first byte leaves and record under the same lock as the
            # write, so a reader can never hold a sample older than its frame's record.
            sent_ns = time.monotonic_ns()
            delivered = self._write_locked(frame)
            sent = SentFrame(index, sent_ns, echo.u, echo.v, echo.w, delivered)
            self._sent.append(sent)
            self._sent_ns.append(sent.host_ns)
            if len(self._sent) > 2 * self._history:
                del self._sent[: self._history], self._sent_ns[: self._history]

    def _write(self, data: bytes) -> bool:
        with self._lock:
            return self._write_locked(data)

    def _write_locked(self, data: bytes) -> bool:
        fd = self._master
        if fd is None:
            return False
        try:
            return os.write(fd, data) == len(data)
        except BlockingIOError:
            # Nobody reads the port and its buffer is full: the frame is lost, as on a real
            # line.
            self.frames_dropped += 1
            return False
        except OSError as exc:
            if exc.errno in (errno.EIO, errno.EBADF):
                return False
            raise

    def _serve_input(self, timeout: float) -> None:
        # The fd is used only under the lock: unplug() cannot close it (and a new pty or the
        # driver's port reuse its number) between select and read.
        with self._lock:
            fd = self._master
            if fd is not None:
                try:
                    ready, _, _ = select.select([fd], [], [], min(timeout, 0.005))
                    data = os.read(fd, 1024) if ready else b""
                except OSError:
                    data = b""
        if fd is None:
            time.sleep(timeout)
            return
        if data:
            self._inbuf += data
            self._handle_commands()
        elif timeout > 0.005:
            time.sleep(min(timeout, 0.005))

    def _handle_commands(self) -> None:
        if self.protocol != "gill":
            self._inbuf = b""
            return
        # Gill set-up mode as the sensor presents it: '*' enters, each CR LF terminated
        # command is echoed, 'Q' leaves; anything else is refused.
        if not self._config_mode:
            if b"*" in self._inbuf:
                self._inbuf = self._inbuf.split(b"*", 1)[1]
                self._config_mode = True
                self._write(b"\r\nCONFIGURATION MODE\r\n")
            else:
                self._inbuf = b""
                return
        while b"\r" in self._inbuf or b"\n" in self._inbuf:
            line, _, rest = self._inbuf.replace(b"\n", b"\r").partition(b"\r")
            self._inbuf = rest.lstrip(b"\r")
            cmd = line.strip()
            if not cmd:
                continue
            if cmd == b"Q":
                self._write(b"Q\r\n")
                self._config_mode = False
                self._inbuf = b""
                return
            if len(cmd) >= 2 and cmd[:1].isalpha() and cmd[1:].isdigit():
                self._write(cmd + b"\r\n")
            else:
                self._write(b"INVALID SETTING\r\n")

    # -- ground truth ----------------------------------------------------------------
    def sent(self) -> list[SentFrame]:
        """Every frame sent so far (the most recent ``history`` at least)."""
        with self._lock:
            return list(self._sent)

    def true_wind(self, host_ns: int) -> np.ndarray | None:
        """The wind (u, v, w) of the last frame sent at or before ``host_ns``; None if none."""
        with self._lock:
            i = bisect.bisect_right(self._sent_ns, host_ns) - 1
            if i < 0:
                return None
            f = self._sent[i]
        return np.array([f.u, f.v, f.w])

    def __enter__(self) -> SimulatedSensor:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


class SimulatedAnemometer(Anemometer):
    """Back end ``simulated``: a :class:`SimulatedSensor` read through the serial back end.

    Parameters
    ----------
    rate_hz : float
    wind : {"constant", "gusty", "turbulent"}
    mean_wind : sequence of 3 float
        Mean (u, v, w) in the protocol's own axes, m/s.
    seed : int
    link_path : str, optional
        Symlink to the pty (default: a temporary path).
    protocol : str
        What the simulated sensor speaks (:data:`ENCODERS`; default Gill UVW).
    history : int
        Sent frames the sensor remembers for :meth:`SimulatedSensor.sent` (tests).
    **serial_options
        Passed to :class:`~drivers.anemometer.serial_transport.SerialAnemometer`
        (``reopen_after_s``, ``gill_setup``, ...).
    """

    backend = "simulated"

    def __init__(
        self,
        rate_hz: float = 20.0,
        wind: str = "turbulent",
        mean_wind: Sequence[float] = (3.0, 0.0, 0.0),
        seed: int = 0,
        link_path: str | None = None,
        protocol: str = "gill",
        history: int = 100_000,
        **serial_options: Any,
    ) -> None:

        super().__init__()
        self.sensor = SimulatedSensor(
            rate_hz,
            WindModel(wind, mean_wind, seed=seed),
            protocol=protocol,
            link_path=link_path,
            history=history,
        ).start()
        try:
            self.serial = SerialAnemometer(protocol, self.sensor.link_path, **serial_options)
        except Exception:
            self.sensor.stop()
            raise

    @property
    def counts(self) -> DecoderCounts:
        return self.serial.counts

    @property
    def stats(self) -> dict[str, int]:
        return self.serial.stats

    @property
    def connected(self) -> bool:
        return self.serial.connected

    def _recv_internal(self, timeout: float) -> WindSample | None:
        return self.serial.recv(timeout)

    def close(self) -> None:
        super().close()
        self.serial.close()
        self.sensor.stop()
