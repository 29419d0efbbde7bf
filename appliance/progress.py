"""A plain-text progress bar for long commands (no dependency).

On a terminal it is redrawn in place; elsewhere (journald, CI logs, pipes) it writes a
line at every tenth of the way, so logs stay readable.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO


class ProgressBar:
    """Call with ``(done, total)``; ``unit`` names what is counted.

    With ``rate=True`` it also shows the rate (``unit``/s) and the remaining time.
    """

    def __init__(self, label: str, stream: TextIO | None = None, *, unit: str = "",
                 width: int = 30, rate: bool = False) -> None:
        self.label = label
        self.stream = stream if stream is not None else sys.stderr
        self.unit = unit
        self.width = width
        self.rate = rate
        self.start = time.perf_counter()
        self.tty = self.stream.isatty()
        self._last_decile = -1

    def __call__(self, done: int, total: int) -> None:
        frac = done / total if total else 1.0
        if not self.tty:
            decile = int(10 * frac)
            if decile == self._last_decile:
                return
            self._last_decile = decile
        fill = int(self.width * frac)
        bar = "#" * fill + "." * (self.width - fill)
        count = f"{done}/{total} {self.unit}".rstrip() if self.unit else f"{100 * frac:5.1f} %"
        elapsed = time.perf_counter() - self.start
        text = f"{self.label} [{bar}] {count} {elapsed:6.1f} s"
        if self.rate and done > 0 and elapsed > 0:
            per_s = done / elapsed
            eta = (total - done) / per_s
            text += f", {per_s:.2f} {self.unit or 'items'}/s, ETA {_clock(eta)}"
        if self.tty:
            self.stream.write("\r" + text + ("\n" if done >= total else ""))
        else:
            self.stream.write(text + "\n")
        self.stream.flush()


def _clock(seconds: float) -> str:
    """``h:mm:ss`` of a duration."""
    s = round(seconds)
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"
