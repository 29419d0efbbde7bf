"""METEK uSonic-3 / USA-1 ASCII output.

One line per sample, CR LF terminated::

    M:x =   -123 y =    456 z =    -78 t =   2345

x, y, z in cm/s and t (sonic temperature) in 0.01 degC, integers. The letter before the colon
is a prefix: ``M`` a normal measurement, ``H`` a measurement while the transducer heating is on
(both valid). Any other letter (``D`` in some firmware) is decoded but flagged invalid and
counted as a status error, because its meaning depends on the firmware: check the manual of
your unit before trusting it. Values whose magnitude exceeds 60 m/s (the sensor's range) are
flagged too.

Axes: METEK's coordinate system is left-handed (x toward the north mark, y 90 deg clockwise
from it, z up); mounting.py turns it right-handed.
"""

from __future__ import annotations

import math
import re

from drivers.anemometer.base import WindSample
from drivers.anemometer.framing import LineDecoder

_LINE = re.compile(
    rb"([A-Z]):\s*x\s*=\s*([-+]?\d+)\s+y\s*=\s*([-+]?\d+)\s+z\s*=\s*([-+]?\d+)\s+t\s*=\s*([-+]?\d+)"
)
_VALID_PREFIXES = frozenset((b"M", b"H"))
_MAX_CM_S = 6000


def format_metek(
    x_cm_s: int, y_cm_s: int, z_cm_s: int, t_centi_c: int, prefix: str = "M"
) -> bytes:
    """Encode one METEK line with CR LF (tests, simulator)."""
    text = f"{prefix}:x = {x_cm_s:6d} y = {y_cm_s:6d} z = {z_cm_s:6d} t = {t_centi_c:6d}\r\n"
    return text.encode()


class MetekDecoder(LineDecoder):
    """Decoder of METEK uSonic-3 / USA-1 ``M:x = .. y = .. z = .. t = ..`` lines."""

    protocol = "metek_usonic3"

    def _decode_line(self, line: bytes, host_ns: int) -> WindSample | None:
        counts = self.counts
        m = _LINE.search(line)
        if m is None:
            self._start = 0
            counts.malformed += 1
            return None
        start = m.start()
        self._start = start
        if start and line[:start].strip():
            counts.skipped_bytes += start
        prefix, x, y, z, t = m.groups()
        xi, yi, zi = int(x), int(y), int(z)
        counts.messages += 1
        if prefix in _VALID_PREFIXES and max(abs(xi), abs(yi), abs(zi)) <= _MAX_CM_S:
            valid = True
            text = "OK" if prefix == b"M" else "OK (heating on)"
            counts.valid += 1
        else:
            valid = False
            counts.status_errors += 1
            if prefix in _VALID_PREFIXES:
                text = "value out of the sensor's range"
            else:
                text = f"prefix {prefix.decode()}: not a plain measurement (see METEK manual)"
        return WindSample(
            host_ns, None, xi / 100.0, yi / 100.0, zi / 100.0, math.nan, int(t) / 100.0,
            None, text, valid,
        )
