"""Gill Instruments ASCII output: WindMaster / WindMaster Pro UVW and the polar form.

A frame is ``<STX>payload<ETX>hh`` followed by CR LF, where ``hh`` is the XOR of every byte of
``payload`` (between STX and ETX) as two hex digits. Payloads (comma-separated, trailing
comma):

- UVW (WindMaster): ``node,U,V,W,units,SoS,Ts,status,[analogue inputs...]``; SoS and Ts may be
  disabled in the sensor, leaving ``node,U,V,W,units,status,``.
- Polar (WindObserver family, 2-D): ``node,direction,speed,units,[SoS,Ts,]status,`` e.g.
  ``A,338,009.29,M,+344.54,+021.56,60,``. The direction is where the wind comes from, in
  degrees clockwise from the sensor's north mark; the direction field is blank when the wind
  is too light to have one.

Units letters: M m/s, N knots, P mph, K km/h, F ft/min; converted to m/s here.
Status codes (Gill manuals): 00 OK, 60 heating enabled and OK are normal; 0A (system gain at
maximum) and 0B (retries used) are warnings with a valid measurement; heater faults
61-66 leave the wind valid; everything else (axis failures 01/02/04, NVM/ROM checksum
08/09, unknown codes) marks the sample invalid. Any code other than 00 and 60 counts as a
status error.
"""

from __future__ import annotations

import math

from drivers.anemometer.base import Decoder, WindSample

STX = 0x02
ETX = 0x03

#: Unit letter -> factor to m/s.
UNITS: dict[bytes, float] = {
    b"M": 1.0,
    b"N": 1852.0 / 3600.0,
    b"P": 0.44704,
    b"K": 1.0 / 3.6,
    b"F": 0.3048 / 60.0,
}

#: Status code -> (text, measurement valid).
STATUS: dict[int, tuple[str, bool]] = {
    0x00: ("OK", True),
    0x01: ("axis 1 failed", False),
    0x02: ("axis 2 failed", False),
    0x04: ("axis 3 failed (WindMaster) / axes 1 and 2 failed (2-D sensors)", False),
    0x08: ("NVM checksum failed", False),
    0x09: ("ROM checksum failed", False),
    0x0A: ("system gain at maximum", True),
    0x0B: ("retries used", True),
    0x60: ("heating enabled and OK", True),
    0x61: ("heating enabled, thermistor failure", True),
    0x62: ("heating enabled, heater temperature above range", True),
    0x63: ("heating enabled, heater temperature below range", True),
    0x66: ("heating enabled, heater failure", True),
}
_NORMAL = frozenset((0x00, 0x60))


def xor_checksum(payload: bytes) -> int:
    """XOR of every byte of ``payload`` (Gill's checksum), computed on whole words."""
    n = len(payload)
    if n == 0:
        return 0
    x = int.from_bytes(payload, "big")
    # Fold the integer in halves (byte aligned): XOR is associative, so the last byte left
    # is the XOR of all bytes. log2(n) big-int operations instead of n Python steps.
    while n > 1:
        half = n // 2
        bits = 8 * half
        x = (x >> bits) ^ (x & ((1 << bits) - 1))
        n -= half
    return x & 0xFF


def format_gill_uvw(
    u: float,
    v: float,
    w: float,
    sos: float,
    ts: float,
    status: int = 0,
    node: str = "Q",
    units: str = "M",
) -> bytes:
    """Encode one WindMaster UVW frame with its checksum and CR LF (simulator, tests).

    ``u, v, w`` are in the unit named by ``units`` (normally M, m/s).
    """
    payload = (
        f"{node},{u:+07.3f},{v:+07.3f},{w:+07.3f},{units},{sos:+07.2f},{ts:+07.2f},{status:02X},"
    )
    data = payload.encode()
    return b"\x02" + data + b"\x03%02X\r\n" % xor_checksum(data)


def format_gill_polar(
    direction: float, speed: float, sos: float, ts: float, status: int = 0, node: str = "A"
) -> bytes:
    """Encode one polar frame (WindObserver style, with SoS and Ts) and CR LF."""
    payload = f"{node},{direction:03.0f},{speed:06.2f},M,{sos:+07.2f},{ts:+07.2f},{status:02X},"
    data = payload.encode()
    return b"\x02" + data + b"\x03%02X\r\n" % xor_checksum(data)


class GillDecoder(Decoder):
    """Decoder of Gill ASCII frames (UVW or polar).

    Parameters
    ----------
    mode : {"auto", "uvw", "polar"}
        ``auto`` tells the two apart by the position of the units letter.
    """

    protocol = "gill"
    max_message_bytes = 256

    def __init__(self, *, mode: str = "auto") -> None:
        super().__init__()
        if mode not in ("auto", "uvw", "polar"):
            raise ValueError(f"Gill mode must be 'auto', 'uvw' or 'polar', got {mode!r}")
        self.mode = mode

    def flush(self) -> list[WindSample]:
        # A frame is complete only with its checksum; nothing to salvage at end of stream.
        return []

    def feed(self, chunk: bytes, host_ns: int) -> list[WindSample]:
        if not chunk:
            return []
        carry = self._carry
        carried = len(carry.data)
        data = carry.join(bytes(chunk), host_ns)
        counts = self.counts
        out: list[WindSample] = []
        n = len(data)
        pos = 0
        while True:
            i = data.find(b"\x02", pos)
            if i < 0:
                counts.skipped_bytes += _junk(data, pos, n)
                pos = n
                break
            if i > pos:
                counts.skipped_bytes += _junk(data, pos, i)
            j = data.find(b"\x03", i + 1)
            if j < 0:
                k = data.rfind(b"\x02", i + 1)
                if k > 0:
                    # A newer frame start: the older one was cut off.
                    counts.resyncs += 1
                    counts.skipped_bytes += k - i
                    i = k
                if n - i > self.max_message_bytes:
                    counts.resyncs += 1
                    counts.skipped_bytes += n - i
                    i = n
                pos = i
                break
            k = data.rfind(b"\x02", i + 1, j)
            if k > 0:
                counts.resyncs += 1
                counts.skipped_bytes += k - i
                i = k
            if j + 3 > n:
                pos = i
                break
            ns = host_ns if i >= carried else carry.stamp(i)
            check = data[j + 1 : j + 3]
            sample = self._frame(data[i + 1 : j], check, ns)
            if sample is not None:
                out.append(sample)
            # Consume the checksum only when it looks like one, so that a stray ETX right
            # before a real frame cannot swallow that frame's STX.
            pos = j + 3 if _is_hex2(check) else j + 1
        carry.keep(data, pos)
        return out

    def _frame(self, payload: bytes, check: bytes, host_ns: int) -> WindSample | None:
        counts = self.counts
        if not _is_hex2(check):
            counts.malformed += 1
            return None
        expected = int(check, 16)
        if xor_checksum(payload) != expected:
            counts.checksum_failures += 1
            return None
        parts = payload.split(b",")
        if parts and parts[-1] == b"":
            parts.pop()
        mode = self.mode
        if mode == "auto":
            if len(parts) >= 6 and parts[4] in UNITS:
                mode = "uvw"
            elif len(parts) >= 5 and parts[3] in UNITS:
                mode = "polar"
            else:
                counts.malformed += 1
                return None
        try:
            if mode == "uvw":
                factor = UNITS[parts[4]]
                u = float(parts[1]) * factor
                v = float(parts[2]) * factor
                w = float(parts[3]) * factor
                rest = parts[5:]
            else:
                factor = UNITS[parts[3]]
                speed = float(parts[2]) * factor
                if parts[1].strip():
                    direction = math.radians(float(parts[1]))
                elif speed == 0.0:
                    direction = 0.0
                else:
                    raise ValueError("blank direction with non-zero speed")
                # Direction the wind comes FROM, clockwise from the north mark; the sensor's
                # U axis points to the mark and V 90 deg anticlockwise (see mounting.py).
                u = -speed * math.cos(direction)
                v = speed * math.sin(direction)
                w = math.nan
                rest = parts[4:]
            if len(rest) >= 3:
                sos = float(rest[0])
                ts = float(rest[1])
                status = int(rest[2], 16)
            elif len(rest) == 1:
                sos = ts = math.nan
                status = int(rest[0], 16)
            else:
                raise ValueError("unexpected field count")
        except (KeyError, ValueError, IndexError):
            counts.malformed += 1
            return None
        text, valid = STATUS.get(status, (f"unknown status code {status:02X}", False))
        if status not in _NORMAL:
            counts.status_errors += 1
        counts.messages += 1
        if valid:
            counts.valid += 1
        return WindSample(host_ns, None, u, v, w, sos, ts, status, text, valid)


def _is_hex2(check: bytes) -> bool:
    return len(check) == 2 and all(c in _HEX for c in check)


_HEX = frozenset(b"0123456789ABCDEFabcdef")


def _junk(data: bytes, start: int, end: int) -> int:
    """Bytes in data[start:end] other than line terminators (the normal gap between frames)."""
    if end - start <= 2:
        return sum(1 for b in data[start:end] if b not in (10, 13))
    return end - start - data.count(b"\r", start, end) - data.count(b"\n", start, end)


class GillUVWDecoder(GillDecoder):
    """Gill WindMaster UVW only."""

    protocol = "gill_uvw"

    def __init__(self) -> None:
        super().__init__(mode="uvw")


class GillPolarDecoder(GillDecoder):
    """Gill polar (WindObserver family) only."""

    protocol = "gill_polar"

    def __init__(self) -> None:
        super().__init__(mode="polar")
