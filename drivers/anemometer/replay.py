"""Back end ``replay``: plays a captured anemometer log at its recorded pace.

Two kinds of capture:

- ``timestamped``: one message per line, the line starting with the logger's ISO-8601 receive
  time, then a tab or space, then the bytes as received (the CSAT3B ``timestamped.tsv``, the
  ship's mast log). Lines starting with ``#`` are comments. Each message is released when its
  recorded time (relative to the first) has passed, divided by ``speed``.
- ``raw``: the sensor's bytes as captured, one message per line; released at ``rate_hz``
  messages per second (the capture carries no times).

Released bytes go through the protocol's real decoder, stamped with ``time.monotonic_ns()`` at
release, so a replayed sample looks like a live one.
"""

from __future__ import annotations

import collections
import time
from collections.abc import Iterator
from datetime import datetime, timezone
from pathlib import Path

from drivers.anemometer.base import Anemometer, AnemometerConfigError, DecoderCounts, WindSample
from drivers.anemometer.registry import make_decoder

FORMATS = ("timestamped", "raw")


def parse_iso_ns(text: str) -> int:
    """ISO-8601 time (``Z`` or offset; naive means UTC) to integer ns since the epoch."""
    t = text.strip()
    if t.endswith("Z"):
        t = t[:-1] + "+00:00"
    dt = datetime.fromisoformat(t)
    if dt.tzinfo is None:
        dt = dt.replace(tzinfo=timezone.utc)
    whole = int(dt.replace(microsecond=0).timestamp())
    return whole * 1_000_000_000 + dt.microsecond * 1000


def read_timestamped(path: Path) -> Iterator[tuple[int, bytes]]:
    """(receive time ns, message bytes with CR LF) for each line of a timestamped capture."""
    with path.open("rb") as fh:
        for lineno, raw in enumerate(fh, 1):
            line = raw.rstrip(b"\r\n")
            if not line or line.startswith(b"#"):
                continue
            stamp, sep, rest = line.replace(b"\t", b" ", 1).partition(b" ")
            try:
                t_ns = parse_iso_ns(stamp.decode("ascii"))
            except (UnicodeDecodeError, ValueError):
                raise ValueError(
                    f"{path}:{lineno}: expected an ISO-8601 time at the start of the line, "
                    f"got {stamp[:40]!r}"
                ) from None
            if not sep:
                continue
            yield t_ns, rest + b"\r\n"


class ReplayAnemometer(Anemometer):
    """Replay a captured log (see the module docstring).

    Parameters
    ----------
    path : str
        The capture file.
    protocol : str
        Registry name of the protocol in the capture.
    format : {"timestamped", "raw"}
    rate_hz : float
        Messages per second for ``raw`` captures.
    speed : float
        Playback speed factor (2.0 = twice as fast).
    loop : bool
        Start again at the end instead of stopping.
    """

    backend = "replay"

    def __init__(
        self,
        path: str,
        protocol: str,
        *,
        format: str = "timestamped",
        rate_hz: float = 20.0,
        speed: float = 1.0,
        loop: bool = False,
    ) -> None:
        super().__init__()
        if format not in FORMATS:
            raise AnemometerConfigError(f"replay format must be one of {FORMATS}, got {format!r}")
        if not speed > 0 or not rate_hz > 0:
            raise AnemometerConfigError(
                f"speed and rate_hz must be > 0, got speed={speed!r}, rate_hz={rate_hz!r}"
            )
        self.path = Path(path)
        if not self.path.is_file():
            raise AnemometerConfigError(f"replay file not found: {self.path}")
        self.format = format
        self.rate_hz = rate_hz
        self.speed = speed
        self.loop = loop
        self.decoder = make_decoder(protocol)
        self._messages = self._load()
        if not self._messages:
            raise AnemometerConfigError(f"replay file {self.path} holds no messages")
        self._next = 0
        self._t0 = time.monotonic()
        self._pending: collections.deque[WindSample] = collections.deque()
        #: True once every message has been played (and ``loop`` is off).
        self.finished = False

    def _load(self) -> list[tuple[float, bytes]]:
        """(seconds after the first message, bytes) for every message."""
        if self.format == "timestamped":
            rows = list(read_timestamped(self.path))
            if not rows:
                return []
            first = rows[0][0]
            return [((t - first) / 1e9, data) for t, data in rows]
        lines = self.path.read_bytes().splitlines(keepends=True)
        return [(i / self.rate_hz, line) for i, line in enumerate(lines) if line.strip()]

    @property
    def counts(self) -> DecoderCounts:
        return self.decoder.counts

    def _recv_internal(self, timeout: float) -> WindSample | None:
        deadline = time.monotonic() + timeout
        while True:
            if self._pending:
                return self._pending.popleft()
            if self.finished or self._closed:
                time.sleep(max(0.0, min(0.05, deadline - time.monotonic())))
                return None
            offset, data = self._messages[self._next]
            due = self._t0 + offset / self.speed
            now = time.monotonic()
            if now < due:
                if now >= deadline:
                    return None
                time.sleep(min(due, deadline) - now)
                continue
            self._pending.extend(self.decoder.feed(data, time.monotonic_ns()))
            self._next += 1
            if self._next == len(self._messages):
                if self.loop:
                    self._next = 0
                    self._t0 = time.monotonic()
                else:
                    self._pending.extend(self.decoder.flush())
                    self.finished = True
