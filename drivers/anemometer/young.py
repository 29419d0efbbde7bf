"""R.M. Young 81000 ultrasonic anemometer, ASCII serial output.

One line per sample, whitespace-separated fixed-width fields, CR (LF optional) terminated:

- default (polar) form: ``speed azimuth elevation SoS Ts`` e.g.
  ``  5.25 185.4  -1.2 343.45  22.35``: speed in m/s, azimuth in degrees clockwise from the
  sensor's north mark that the wind comes FROM, elevation in degrees (positive: wind blowing
  upward), speed of sound m/s, sonic temperature degC;
- UVW form: ``U V W SoS Ts`` in m/s and degC.

Optional trailing fields (the 81000's voltage inputs) are ignored. The output has no checksum
and no status word: a sample is flagged invalid when a value lies outside the sensor's
specified range (speed 0-40 m/s, with margin to 75 m/s; Ts -50..+60 degC). Junk before a
message on the same line is recognised only when whitespace separates it from the message.

Axes: U toward the right of the north mark (east when the mark points north), V toward the
mark, W up (the meteorological convention of the 81000's own polar output; see mounting.py).
"""

from __future__ import annotations

import math

from drivers.anemometer.base import WindSample
from drivers.anemometer.framing import LineDecoder

_MAX_SPEED = 75.0
_TS_RANGE = (-50.0, 60.0)


def format_young(
    a: float, b: float, c: float, sos: float, ts: float, *, uvw: bool = False
) -> bytes:
    """Encode one 81000 line (polar: speed, azimuth, elevation; or U, V, W) with CR LF."""
    if uvw:
        return f"{a:6.2f} {b:6.2f} {c:6.2f} {sos:6.2f} {ts:6.2f}\r\n".encode()
    return f"{a:6.2f} {b:5.1f} {c:5.1f} {sos:6.2f} {ts:6.2f}\r\n".encode()


class Young81000Decoder(LineDecoder):
    """Decoder of the 81000 ASCII output.

    Parameters
    ----------
    uvw : bool
        False for the default polar form, True for the U V W form.
    fields : int
        Number of leading message fields (5 unless the sensor was reconfigured); any further
        fields (voltage inputs) are ignored.
    """

    protocol = "young_81000"

    def __init__(self, *, uvw: bool = False, fields: int = 5) -> None:
        super().__init__()
        if fields < 5:
            raise ValueError(f"an 81000 message has at least 5 fields, got fields={fields!r}")
        self.uvw = uvw
        self.fields = fields

    def _decode_line(self, line: bytes, host_ns: int) -> WindSample | None:
        self._start = 0
        counts = self.counts
        tokens = line.split()
        if len(tokens) < self.fields:
            if tokens:
                counts.malformed += 1
            return None
        if len(tokens) > self.fields:
            # Junk before the message: the message is the last `fields` tokens.
            first = tokens[-self.fields]
            tail = sum(len(t) for t in tokens[-self.fields + 1 :])
            start = line.rfind(first, 0, len(line) - tail)
            counts.skipped_bytes += max(0, start)
            self._start = max(0, start)
            tokens = tokens[-self.fields :]
        try:
            a, b, c, sos, ts = (float(t) for t in tokens[:5])
        except ValueError:
            counts.malformed += 1
            return None
        if self.uvw:
            u, v, w = a, b, c
            speed = math.sqrt(u * u + v * v + w * w)
            ok_angles = True
        else:
            speed = a
            az = math.radians(b)
            el = math.radians(c)
            horiz = speed * math.cos(el)
            # Wind FROM azimuth az blows toward az + 180 deg.
            u = -horiz * math.sin(az)
            v = -horiz * math.cos(az)
            w = speed * math.sin(el)
            ok_angles = 0.0 <= b <= 360.0 and -90.0 <= c <= 90.0 and speed >= 0.0
        valid = (
            ok_angles
            and speed <= _MAX_SPEED
            and _TS_RANGE[0] <= ts <= _TS_RANGE[1]
            and math.isfinite(speed)
        )
        counts.messages += 1
        if valid:
            counts.valid += 1
            text = "OK"
        else:
            counts.status_errors += 1
            text = "value out of the sensor's range"
        return WindSample(host_ns, None, u, v, w, sos, ts, None, text, valid)


class Young81000UVWDecoder(Young81000Decoder):
    """The 81000 in its U V W output form."""

    protocol = "young_81000_uvw"

    def __init__(self, *, fields: int = 5) -> None:
        super().__init__(uvw=True, fields=fields)
