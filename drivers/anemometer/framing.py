"""Framing shared by the line-oriented ASCII protocols (CSAT3B, R.M. Young, METEK).

A line ends at CR or LF (any run of them). Bytes of an unfinished line are carried over to
the next chunk together with the host stamp of the chunk where each carried piece arrived, so
a message keeps the stamp of its first byte however the stream was split.
"""

from __future__ import annotations

import dataclasses
import re
from abc import abstractmethod

from drivers.anemometer.base import Decoder, WindSample

_EOL = re.compile(rb"[\r\n]+")


class LineDecoder(Decoder):
    """Base of decoders whose messages are single text lines.

    Subclasses implement :meth:`_decode_line`, which returns a sample or None (after counting
    why) and sets ``self._start`` to the offset in the line where the message began (> 0 when
    junk preceded it on the same line).
    """

    def __init__(self) -> None:
        super().__init__()
        self._start = 0

    def feed(self, chunk: bytes, host_ns: int) -> list[WindSample]:
        if not chunk:
            return []
        carry = self._carry
        carried = len(carry.data)
        data = carry.join(bytes(chunk), host_ns)
        lines = _EOL.split(data)
        rest = lines.pop()
        out: list[WindSample] = []
        decode = self._decode_line
        first = True
        for line in lines:
            if first:
                first = False
                if carried and line and not line.isspace():
                    # This line began in carried bytes: stamp it by its first message byte.
                    self._start = 0
                    sample = decode(line, carry.stamp(0))
                    if sample is not None:
                        if self._start:
                            sample = dataclasses.replace(sample, host_ns=carry.stamp(self._start))
                        out.append(sample)
                    continue
            if line and not line.isspace():
                sample = decode(line, host_ns)
                if sample is not None:
                    out.append(sample)
        rest_start = len(data) - len(rest)
        if len(rest) > self.max_message_bytes:
            # No terminator for far longer than any message: junk; keep only a tail that
            # could still hold the start of a message.
            drop = len(rest) - self.max_message_bytes
            self.counts.resyncs += 1
            self.counts.skipped_bytes += drop
            rest_start += drop
        carry.keep(data, rest_start)
        return out

    def flush(self) -> list[WindSample]:
        data = self._carry.data
        if not data.strip():
            self._carry.keep(b"", 0)
            return []
        ns = self._carry.stamp(0)
        self._start = 0
        sample = self._decode_line(data, ns)
        if sample is not None and self._start:
            sample = dataclasses.replace(sample, host_ns=self._carry.stamp(self._start))
        self._carry.keep(b"", 0)
        return [] if sample is None else [sample]

    @abstractmethod
    def _decode_line(self, line: bytes, host_ns: int) -> WindSample | None:
        """Decode one line (without terminator); count and return None when unusable."""
