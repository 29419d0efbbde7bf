"""Campbell Scientific CSAT3B ASCII output.

One line per record, CR LF terminated::

    -2.17605,-4.00771,0.14649,30.70251,0,11,3c57

= Ux, Uy, Uz [m/s], Ts [degC], diagnostic word, record counter, signature (4 hex digits).
The signature is Campbell's signature algorithm, seed 0xAAAA, over every byte before the last
comma. The counter increments by one per record and wraps (0-255 in the NCAR M2HATS capture
in ``tests/data/anemometer``; set ``counter_modulus`` if your firmware differs); a jump is a
lost record and is counted as a counter gap.
"""

from __future__ import annotations

import math
import re

from drivers.anemometer.base import WindSample
from drivers.anemometer.framing import LineDecoder

SIGNATURE_SEED = 0xAAAA

# Rotating the low byte left by one bit, precomputed: the inner step of the signature.
_ROTL = bytes(((b << 1) | (b >> 7)) & 0xFF for b in range(256))

_NUM = rb"[-+]?(?:\d+(?:\.\d*)?|\.\d+|nan|NAN|NaN)"
#: A record body (everything before the signature) that ends where the search ends.
_BODY = re.compile(_NUM + rb"(?:," + _NUM + rb"){3},\d+,\d+$")


def campbell_signature(data: bytes, seed: int = SIGNATURE_SEED) -> int:
    """Campbell Scientific's 16-bit signature of ``data``.

    Each byte b updates the state (msb, lsb) to (lsb, rotl8(lsb) + msb + b mod 256), starting
    from ``seed``; the result is msb * 256 + lsb.
    """
    msb = seed >> 8
    lsb = seed & 0xFF
    rotl = _ROTL
    for b in data:
        msb, lsb = lsb, (rotl[lsb] + msb + b) & 0xFF
    return (msb << 8) | lsb


def format_csat3b(
    ux: float, uy: float, uz: float, ts: float, diag: int, counter: int
) -> bytes:
    """Encode one CSAT3B ASCII record with its signature and CR LF (simulator, tests)."""
    body = f"{ux:.5f},{uy:.5f},{uz:.5f},{ts:.5f},{diag:d},{counter:d}".encode()
    return body + b",%04x\r\n" % campbell_signature(body)


class CampbellCSAT3BDecoder(LineDecoder):
    """Decoder of the CSAT3B ASCII record (see the module docstring).

    Parameters
    ----------
    counter_modulus : int
        The record counter wraps to 0 after ``counter_modulus - 1``.
    """

    protocol = "campbell_csat3b"

    def __init__(self, *, counter_modulus: int = 256) -> None:
        super().__init__()
        if counter_modulus < 2:
            raise ValueError(f"counter_modulus must be >= 2, got {counter_modulus!r}")
        self.counter_modulus = counter_modulus
        self._last_counter: int | None = None

    def _decode_line(self, line: bytes, host_ns: int) -> WindSample | None:
        self._start = 0
        counts = self.counts
        cut = line.rfind(b",")
        sig = line[cut + 1 :]
        if cut <= 0 or not _is_sig(sig):
            counts.malformed += 1
            return None
        # The record is the well-formed body ending at the last comma. Junk may precede it on
        # the same line (a logger's time prefix, line noise): try each start where a
        # well-formed body begins, leftmost first (normally 0), and keep the first whose
        # signature verifies.
        expected = int(sig, 16)
        m = _BODY.search(line, 0, cut)
        if m is None:
            counts.malformed += 1
            return None
        while m is not None:
            p = m.start()
            body = line[p:cut]
            if campbell_signature(body) == expected:
                sample = self._make(body, host_ns)
                if sample is not None and p:
                    counts.skipped_bytes += p
                    self._start = p
                return sample
            m = _BODY.search(line, p + 1, cut)
        counts.checksum_failures += 1
        return None

    def _make(self, body: bytes, host_ns: int) -> WindSample | None:
        counts = self.counts
        parts = body.split(b",")
        try:
            ux, uy, uz, ts = float(parts[0]), float(parts[1]), float(parts[2]), float(parts[3])
            diag = int(parts[4])
            counter = int(parts[5])
        except ValueError:
            counts.malformed += 1
            return None
        if self._last_counter is not None:
            gap = (counter - self._last_counter - 1) % self.counter_modulus
            if gap:
                counts.counter_gaps += 1
                counts.missed_records += gap
        self._last_counter = counter
        finite = math.isfinite(ux) and math.isfinite(uy) and math.isfinite(uz)
        if diag == 0 and finite:
            text = "OK"
            valid = True
        else:
            counts.status_errors += 1
            valid = False
            if diag:
                bits = [str(i) for i in range(diag.bit_length()) if diag >> i & 1]
                text = f"diagnostic word {diag} (bits {','.join(bits)} set; see CSAT3B manual)"
            else:
                text = "non-finite wind component"
        counts.messages += 1
        if valid:
            counts.valid += 1
        # The CSAT3B sends Ts, not c; Campbell defines Ts = c^2 / 403 K m^-2 s^2 (dry-air
        # gamma * R), so c follows exactly.
        sos = math.sqrt(403.0 * (ts + 273.15)) if ts > -273.15 else math.nan
        return WindSample(host_ns, counter, ux, uy, uz, sos, ts, diag, text, valid)


_HEX = frozenset(b"0123456789abcdefABCDEF")


def _is_sig(sig: bytes) -> bool:
    return len(sig) == 4 and all(c in _HEX for c in sig)
