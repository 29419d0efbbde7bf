"""Anemometers on a serial line, opened by URL with ``serial.serial_for_url``.

``SerialTransport`` opens the port (a device path, a pty, ``loop://``, ``spy://...``), reads
whatever arrived with a short timeout and stamps each chunk with ``time.monotonic_ns()`` when
its first byte was returned. ``SerialAnemometer`` feeds the chunks to a protocol decoder and
keeps the line alive on its own:

- a read error (device unplugged, pty closed) closes the port and reopens it with exponential
  backoff (``backoff_initial_s`` doubling up to ``backoff_max_s``) until it comes back;
- when no valid message arrived for ``reopen_after_s`` seconds on an open port, the port is
  closed and reopened (a wedged USB adapter often recovers this way);
- optionally, after each open, Gill sensors are configured (``gill_setup``): ``*`` enters
  set-up mode (the sensor answers ``CONFIGURATION MODE``), each command is sent with CR LF and
  must be echoed, ``Q`` leaves set-up mode and a valid frame must follow. A sensor that does
  not answer this way is closed and retried like an unplugged one; the error stays in
  :attr:`SerialAnemometer.last_error`.
"""

from __future__ import annotations

import collections
import contextlib
import time
from collections.abc import Mapping, Sequence
from typing import Any

import serial

from drivers.anemometer.base import (
    Anemometer,
    AnemometerConfigError,
    AnemometerConnectionError,
    AnemometerSetupError,
    DecoderCounts,
    WindSample,
)
from drivers.anemometer.registry import make_decoder

_PARITIES = {
    "N": serial.PARITY_NONE,
    "E": serial.PARITY_EVEN,
    "O": serial.PARITY_ODD,
    "M": serial.PARITY_MARK,
    "S": serial.PARITY_SPACE,
}


class SerialTransport:
    """One serial port opened by URL; chunks out, stamped on arrival.

    Parameters
    ----------
    url : str
        ``/dev/ttyUSB0``, a pty path or symlink, ``loop://``, ``spy:///dev/ttyUSB0``, ...
    baudrate : int
    parity : {"N", "E", "O", "M", "S"}
    bytesize : {5, 6, 7, 8}
    stopbits : {1, 1.5, 2}
    read_timeout_s : float
        Longest a read waits for the first byte.
    """

    def __init__(
        self,
        url: str,
        *,
        baudrate: int = 9600,
        parity: str = "N",
        bytesize: int = 8,
        stopbits: float = 1,
        read_timeout_s: float = 0.1,
    ) -> None:
        if not isinstance(url, str) or not url:
            raise AnemometerConfigError(f"serial url must be a non-empty string, got {url!r}")
        if not isinstance(baudrate, int) or baudrate <= 0:
            raise AnemometerConfigError(f"baudrate must be a positive integer, got {baudrate!r}")
        if parity not in _PARITIES:
            raise AnemometerConfigError(
                f"parity must be one of {sorted(_PARITIES)}, got {parity!r}"
            )
        if bytesize not in (5, 6, 7, 8):
            raise AnemometerConfigError(f"bytesize must be 5, 6, 7 or 8, got {bytesize!r}")
        if stopbits not in (1, 1.5, 2):
            raise AnemometerConfigError(f"stopbits must be 1, 1.5 or 2, got {stopbits!r}")
        if not read_timeout_s > 0:
            raise AnemometerConfigError(f"read_timeout_s must be > 0, got {read_timeout_s!r}")
        self.url = url
        self.baudrate = baudrate
        self.parity = parity
        self.bytesize = bytesize
        self.stopbits = stopbits
        self.read_timeout_s = read_timeout_s
        self._port: serial.SerialBase | None = None

    @property
    def is_open(self) -> bool:
        return self._port is not None

    def open(self) -> None:
        """Open the port; raise :class:`AnemometerConnectionError` naming it on failure."""
        self.close()
        try:
            self._port = serial.serial_for_url(
                self.url,
                baudrate=self.baudrate,
                parity=_PARITIES[self.parity],
                bytesize=self.bytesize,
                stopbits=self.stopbits,
                timeout=self.read_timeout_s,
                write_timeout=1.0,
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            raise AnemometerConnectionError(f"cannot open {self.url}: {exc}") from exc

    def close(self) -> None:
        port, self._port = self._port, None
        if port is not None:
            try:
                port.close()
            except (serial.SerialException, OSError):
                pass  # already gone; nothing left to release

    def read(self) -> tuple[bytes, int]:
        """Wait up to ``read_timeout_s`` for data; return (bytes, host_ns of the first byte).

        Returns ``(b"", now)`` on timeout; raises :class:`AnemometerConnectionError` when the
        device vanished.
        """
        port = self._port
        if port is None:
            raise AnemometerConnectionError(f"{self.url} is not open")
        try:
            waiting = port.in_waiting
            data = port.read(waiting or 1)
            host_ns = time.monotonic_ns()
            if data and not waiting:
                # The first byte just arrived; take what came with it under the same stamp.
                more = port.in_waiting
                if more:
                    data += port.read(more)
        except (serial.SerialException, OSError) as exc:
            self.close()
            raise AnemometerConnectionError(f"{self.url}: {exc}") from exc
        return data, host_ns

    def write(self, data: bytes) -> None:
        port = self._port
        if port is None:
            raise AnemometerConnectionError(f"{self.url} is not open")
        try:
            port.write(data)
            port.flush()
        except (serial.SerialException, OSError) as exc:
            self.close()
            raise AnemometerConnectionError(f"{self.url}: {exc}") from exc


class SerialAnemometer(Anemometer):
    """An anemometer speaking ``protocol`` on a serial port (see the module docstring).

    Parameters
    ----------
    protocol : str
        Registry name of the protocol (``gill``, ``campbell_csat3b``, ...).
    url, baudrate, parity, bytesize, stopbits, read_timeout_s
        Passed to :class:`SerialTransport`.
    reopen_after_s : float
        Reopen the port when no valid message arrived for this long.
    backoff_initial_s, backoff_max_s : float
        Delay before the first reconnect attempt and its ceiling (doubling in between).
    decoder_options : mapping, optional
        Keyword options of the decoder (e.g. ``{"counter_modulus": 64}``).
    gill_setup : mapping, optional
        ``{"commands": ["M2", "P20"], "reply_timeout_s": 2.0}``: Gill set-up commands as in
        the sensor's manual, sent after each open (see the module docstring).
    """

    backend = "serial"

    def __init__(
        self,
        protocol: str = "gill",
        url: str = "",
        *,
        baudrate: int = 9600,
        parity: str = "N",
        bytesize: int = 8,
        stopbits: float = 1,
        read_timeout_s: float = 0.1,
        reopen_after_s: float = 5.0,
        backoff_initial_s: float = 0.1,
        backoff_max_s: float = 5.0,
        decoder_options: Mapping[str, Any] | None = None,
        gill_setup: Mapping[str, Any] | None = None,
    ) -> None:
        super().__init__()
        self.transport = SerialTransport(
            url, baudrate=baudrate, parity=parity, bytesize=bytesize, stopbits=stopbits,
            read_timeout_s=read_timeout_s,
        )
        if not reopen_after_s > 0:
            raise AnemometerConfigError(f"reopen_after_s must be > 0, got {reopen_after_s!r}")
        if not 0 < backoff_initial_s <= backoff_max_s:
            raise AnemometerConfigError(
                f"need 0 < backoff_initial_s <= backoff_max_s, got {backoff_initial_s!r}, "
                f"{backoff_max_s!r}"
            )
        self.protocol = protocol
        self.decoder = make_decoder(protocol, **dict(decoder_options or {}))
        self.reopen_after_ns = int(reopen_after_s * 1e9)
        self.backoff_initial_s = backoff_initial_s
        self.backoff_max_s = backoff_max_s
        self._setup_commands: Sequence[str] = ()
        self._setup_timeout_s = 2.0
        if gill_setup is not None:
            if not protocol.startswith("gill"):
                raise AnemometerConfigError(f"gill_setup given for protocol {protocol!r}")
            unknown = set(gill_setup) - {"commands", "reply_timeout_s"}
            if unknown:
                raise AnemometerConfigError(f"unknown gill_setup key(s): {sorted(unknown)}")
            commands = gill_setup.get("commands", [])
            if isinstance(commands, str) or not all(isinstance(c, str) and c for c in commands):
                raise AnemometerConfigError(
                    f"gill_setup.commands must be a list of command strings, got {commands!r}"
                )
            self._setup_commands = list(commands)
            self._setup_timeout_s = float(gill_setup.get("reply_timeout_s", 2.0))
            self._gill_setup = True
        else:
            self._gill_setup = False
        self._pending: collections.deque[WindSample] = collections.deque()
        self._backoff_s = backoff_initial_s
        self._next_attempt = 0.0
        self._last_valid_ns = 0
        #: Monotonic ns of the last successful open (None before the first).
        self.connected_ns: int | None = None
        #: The last connection or set-up error, for health reporting.
        self.last_error: str = ""
        self._stats = dict.fromkeys(
            ("connects", "disconnects", "reopens", "open_failures", "setup_failures"), 0
        )

    @property
    def counts(self) -> DecoderCounts:
        return self.decoder.counts

    @property
    def stats(self) -> dict[str, int]:
        return dict(self._stats)

    @property
    def connected(self) -> bool:
        return self.transport.is_open

    def _connect(self) -> bool:
        now = time.monotonic()
        if now < self._next_attempt:
            return False
        try:
            self.transport.open()
            if self._gill_setup:
                self._run_gill_setup()
        except (AnemometerConnectionError, AnemometerSetupError) as exc:
            if isinstance(exc, AnemometerSetupError):
                # Leave set-up mode so that a refused command does not keep the sensor silent.
                with contextlib.suppress(AnemometerConnectionError):
                    self.transport.write(b"Q\r\n")
            self.transport.close()
            self.last_error = str(exc)
            key = "setup_failures" if isinstance(exc, AnemometerSetupError) else "open_failures"
            self._stats[key] += 1
            self._next_attempt = time.monotonic() + self._backoff_s
            self._backoff_s = min(2 * self._backoff_s, self.backoff_max_s)
            return False
        self._backoff_s = self.backoff_initial_s
        # The stamp before the count: whoever sees a new connection counted (another
        # thread: health, a test) must read its stamp, not the previous connection's.
        self.connected_ns = self._last_valid_ns = time.monotonic_ns()
        self._stats["connects"] += 1
        return True

    def _drop(self, reason: str) -> None:
        self.transport.close()
        self.decoder.reset_stream()
        self.last_error = reason
        self._next_attempt = time.monotonic() + self._backoff_s
        self._backoff_s = min(2 * self._backoff_s, self.backoff_max_s)

    def _recv_internal(self, timeout: float) -> WindSample | None:
        deadline = time.monotonic() + timeout
        while True:
            if self._pending:
                return self._pending.popleft()
            if self._closed:
                return None
            if not self.transport.is_open and not self._connect():
                wait = min(deadline, self._next_attempt) - time.monotonic()
                if time.monotonic() >= deadline:
                    return None
                time.sleep(max(0.0, min(wait, 0.05)))
                continue
            try:
                chunk, host_ns = self.transport.read()
            except AnemometerConnectionError as exc:
                self._stats["disconnects"] += 1
                self._drop(str(exc))
                continue
            if chunk:
                for sample in self.decoder.feed(chunk, host_ns):
                    if sample.valid:
                        self._last_valid_ns = sample.host_ns
                    self._pending.append(sample)
            if time.monotonic_ns() - self._last_valid_ns > self.reopen_after_ns:
                # Open but silent (or only garbage): reopen right away.
                self._stats["reopens"] += 1
                self.transport.close()
                self.decoder.reset_stream()
                self.last_error = (
                    f"{self.transport.url}: no valid message for "
                    f"{self.reopen_after_ns / 1e9:g} s; reopened"
                )
                self._next_attempt = 0.0
            if not self._pending and time.monotonic() >= deadline:
                return None

    def _run_gill_setup(self) -> None:
        t = self.transport
        t.write(b"*")
        self._expect(b"CONFIGURATION MODE", "'*'")
        for cmd in self._setup_commands:
            t.write(cmd.encode("ascii") + b"\r\n")
            self._expect(cmd.encode("ascii"), repr(cmd))
        t.write(b"Q\r\n")
        # Back in measurement mode: a valid frame must follow.
        deadline = time.monotonic() + self._setup_timeout_s
        probe = make_decoder(self.protocol)
        while time.monotonic() < deadline:
            chunk, ns = t.read()
            samples = probe.feed(chunk, ns)
            if samples:
                return
        raise AnemometerSetupError(
            f"{t.url}: no valid frame within {self._setup_timeout_s:g} s after leaving set-up "
            f"mode ('Q')"
        )

    def _expect(self, needle: bytes, sent: str) -> None:
        deadline = time.monotonic() + self._setup_timeout_s
        got = b""
        while time.monotonic() < deadline:
            chunk, _ = self.transport.read()
            got += chunk
            if needle in got:
                return
            if b"INVALID" in got.upper() or b"ERROR" in got.upper():
                break
        raise AnemometerSetupError(
            f"{self.transport.url}: Gill set-up: expected {needle.decode(errors='replace')!r} "
            f"after sending {sent}, got {got[-80:]!r}"
        )

    def close(self) -> None:
        super().close()
        self.transport.close()
