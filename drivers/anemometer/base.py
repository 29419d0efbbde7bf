"""What every anemometer back end and protocol decoder shares.

- :class:`WindSample`: one decoded message, stamped on the host at the arrival of its first
  byte (``time.monotonic_ns()``), in the sensor's own axes.
- :class:`DecoderCounts` and :class:`Decoder`: a protocol decoder takes arbitrary byte chunks
  (``feed(chunk, host_ns)``) and returns whole samples; it never raises on bad bytes, it counts
  them.
- :class:`Anemometer`: the interface of a back end (serial, simulated, replay), modelled on
  python-can's ``BusABC``: the base class owns ``recv(timeout)`` bookkeeping, a back end
  overrides ``_recv_internal``.
- The error hierarchy rooted at :class:`AnemometerError`.
"""

from __future__ import annotations

import bisect
import math
from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import asdict, dataclass, fields


@dataclass(frozen=True, slots=True)
class WindSample:
    """One anemometer message.

    Attributes
    ----------
    host_ns : int
        ``time.monotonic_ns()`` on the host when the first byte of the message arrived (the
        stamp of the chunk that carried it).
    counter : int or None
        The device's own record counter when the protocol has one (CSAT3B), else None.
    u, v, w : float
        Wind components in m/s in the sensor's own axes (see ``drivers.anemometer.mounting``
        for each sensor's axes). ``w`` is NaN for 2-D sensors (Gill WindObserver polar).
    speed_of_sound : float
        m/s; NaN when the message does not carry it.
    sonic_temperature : float
        degC; NaN when the message does not carry it.
    status_code : int or None
        The sensor's status / diagnostic code as sent (Gill status byte, CSAT3B diagnostic
        word); None when the protocol has none.
    status_text : str
        Human-readable status ("OK" when nothing is wrong).
    valid : bool
        False when the sensor flagged the measurement or a value is out of range; such
        samples are still delivered (and logged) but must not be used as wind.
    """

    host_ns: int
    counter: int | None
    u: float
    v: float
    w: float
    speed_of_sound: float
    sonic_temperature: float
    status_code: int | None
    status_text: str
    valid: bool

    @property
    def horizontal_speed(self) -> float:
        """Horizontal wind speed sqrt(u^2 + v^2) in m/s."""
        return math.hypot(self.u, self.v)

    def as_dict(self) -> dict[str, object]:
        """The sample as a plain dict (JSON/CSV export); NaN stays NaN."""
        return asdict(self)


SAMPLE_FIELDS: tuple[str, ...] = tuple(f.name for f in fields(WindSample))


@dataclass(slots=True)
class DecoderCounts:
    """What a decoder has seen since it was created (never reset by the decoder itself).

    ``messages`` counts every sample emitted (valid or not); ``valid`` those with
    ``valid=True``; ``status_errors`` those the sensor flagged (their ``valid`` may still be
    True for warnings such as a Gill heater fault). ``checksum_failures`` and ``malformed``
    messages produce no sample. ``skipped_bytes`` counts bytes between or before messages
    that belong to no message (a logger's time prefix, line noise, another instrument's
    lines); ``resyncs`` counts messages abandoned part-way (a frame cut off by a new frame
    start, a line far longer than any message, a partial message dropped on reconnect).
    ``counter_gaps`` counts jumps in the device counter
    and ``missed_records`` the records those jumps imply.
    """

    messages: int = 0
    valid: int = 0
    checksum_failures: int = 0
    malformed: int = 0
    status_errors: int = 0
    resyncs: int = 0
    skipped_bytes: int = 0
    counter_gaps: int = 0
    missed_records: int = 0

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


class AnemometerError(Exception):
    """Base of every anemometer error."""


class AnemometerConfigError(AnemometerError, ValueError):
    """A wrong configuration value (unknown protocol, bad baud rate, bad mounting)."""


class AnemometerConnectionError(AnemometerError):
    """The device could not be opened or vanished (unplugged)."""


class AnemometerSetupError(AnemometerError):
    """The sensor did not answer its start-up configuration as expected."""


class _StampedBuffer:
    """Bytes left over from earlier chunks with the host stamp of each chunk's first byte.

    The decoders keep only an incomplete message here, so the list of marks stays short.
    """

    __slots__ = ("data", "marks", "offsets")

    def __init__(self) -> None:
        self.data = b""
        self.offsets: list[int] = []
        self.marks: list[int] = []

    def join(self, chunk: bytes, host_ns: int) -> bytes:
        """Return the carried bytes followed by ``chunk`` and remember where ``chunk`` began."""
        if not self.data:
            self.offsets = [0]
            self.marks = [host_ns]
            return chunk
        self.offsets.append(len(self.data))
        self.marks.append(host_ns)
        return self.data + chunk

    def stamp(self, offset: int) -> int:
        """Host stamp of the byte at ``offset`` of the last joined data."""
        return self.marks[bisect.bisect_right(self.offsets, offset) - 1]

    def keep(self, data: bytes, start: int) -> None:
        """Carry ``data[start:]`` over to the next chunk."""
        if start >= len(data):
            self.data = b""
            self.offsets = []
            self.marks = []
            return
        i = bisect.bisect_right(self.offsets, start) - 1
        self.offsets = [0] + [o - start for o in self.offsets[i + 1 :]]
        self.marks = self.marks[i:]
        self.data = data[start:]


class Decoder(ABC):
    """A protocol decoder: arbitrary byte chunks in, whole :class:`WindSample` s out.

    Subclasses implement :meth:`feed`. ``feed`` never raises on any input bytes; what it
    cannot use it counts in :attr:`counts`.
    """

    #: Registry name of the protocol (set by subclasses).
    protocol: str = ""
    #: Longest message the decoder waits for before it discards a partial one.
    max_message_bytes: int = 512

    def __init__(self) -> None:
        self.counts = DecoderCounts()
        self._carry = _StampedBuffer()

    @abstractmethod
    def feed(self, chunk: bytes, host_ns: int) -> list[WindSample]:
        """Decode ``chunk`` (any bytes) received at host time ``host_ns``.

        Parameters
        ----------
        chunk : bytes
            The next bytes of the stream, split anywhere.
        host_ns : int
            ``time.monotonic_ns()`` when the chunk's first byte arrived; every message whose
            first byte is in this chunk carries this stamp.

        Returns
        -------
        list of WindSample
            Every message completed by this chunk, in stream order.
        """

    def decode_all(self, data: bytes, host_ns: int = 0) -> list[WindSample]:
        """Decode a whole captured stream (one chunk, one stamp) and flush it."""
        samples = self.feed(data, host_ns)
        samples.extend(self.flush())
        return samples

    def flush(self) -> list[WindSample]:
        """End of stream: decode a last message that lacks only its terminator, if any."""
        return []

    def reset_stream(self) -> None:
        """Forget a partly received message (the line was reopened); counted as a resync."""
        if self._carry.data:
            self.counts.resyncs += 1
            self.counts.skipped_bytes += len(self._carry.data)
        self._carry.keep(b"", 0)


class Anemometer(ABC):
    """Interface of an anemometer back end (python-can's ``BusABC`` pattern).

    ``recv`` returns the next sample or None after ``timeout`` seconds; back ends implement
    ``_recv_internal``. A back end that loses its device keeps trying to get it back and
    returns None meanwhile; it raises only for configuration errors.
    """

    #: Registry name of the back end.
    backend: str = ""

    def __init__(self) -> None:
        self._closed = False

    @property
    @abstractmethod
    def counts(self) -> DecoderCounts:
        """The decoder's counts (checksum failures, malformed messages, ...)."""

    @property
    def stats(self) -> dict[str, int]:
        """Transport statistics (connects, disconnects, reopens); empty when not relevant."""
        return {}

    @property
    def connected(self) -> bool:
        """True while the device is open and delivering."""
        return not self._closed

    def recv(self, timeout: float | None = None) -> WindSample | None:
        """Return the next sample, or None when none arrived within ``timeout`` seconds.

        ``timeout=None`` waits until a sample arrives or the back end is closed.
        """
        if self._closed:
            raise AnemometerError(f"{type(self).__name__} is closed")
        if timeout is None:
            while not self._closed:
                sample = self._recv_internal(0.5)
                if sample is not None:
                    return sample
            return None
        return self._recv_internal(max(0.0, timeout))

    @abstractmethod
    def _recv_internal(self, timeout: float) -> WindSample | None:
        """Wait at most ``timeout`` seconds for one sample."""

    def __iter__(self) -> Iterator[WindSample]:
        while not self._closed:
            sample = self.recv(0.5)
            if sample is not None:
                yield sample

    def close(self) -> None:
        """Release the device; idempotent."""
        self._closed = True

    def __enter__(self) -> Anemometer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

