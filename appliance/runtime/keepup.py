"""Does processing keep up with the cameras? Measured once at start, said once.

Processing skips windows when it falls behind (acquisition and recording never wait), so a
configuration that is too slow for its frame rate still runs - and silently sees only part
of what the cameras deliver. :class:`KeepUpCheck` watches the processed and skipped triples
over a measuring window that opens with the first result (so the workers' warm-up, numba
loading its kernels, is not counted) and, at its end, returns one message: either the share
processed is at least ``threshold``, or it is not and by how much. :class:`StageTimes`
says where the time goes: the median time of each stage of the chain over the last results
(the workers measure every call), so that a site that cannot keep up knows which setting
to lower.
"""

from __future__ import annotations

import statistics
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path


@dataclass
class KeepUpCheck:
    """One measurement of the processed share over ``window_s`` after the first result.

    Parameters
    ----------
    window_s : float
        Length of the measuring window in s.
    threshold : float
        Smallest processed share (processed / (processed + skipped)) that counts as
        keeping up.
    """

    window_s: float = 20.0
    threshold: float = 0.9
    #: What to change when processing does not keep up (:func:`keep_up_advice`).
    advice: str = ("lower the frame rate, add workers/cores, or reduce the solvers' "
                   "iterations (processing.parameters)")
    _start: tuple[float, int, int] | None = None
    _done: bool = False

    def __post_init__(self) -> None:
        if not self.window_s > 0:
            raise ValueError(f"window_s must be positive, got {self.window_s!r}")
        if not 0 < self.threshold <= 1:
            raise ValueError(f"threshold must be in (0, 1], got {self.threshold!r}")

    def observe(self, now_s: float, processed: int, skipped: int) -> tuple[bool, str] | None:
        """Feed the running totals at a result; returns (keeps_up, message) exactly once.

        Parameters
        ----------
        now_s : float
            Monotonic time in s.
        processed, skipped : int
            Triples processed and skipped so far (totals over all workers).
        """
        if self._done:
            return None
        if self._start is None:
            self._start = (now_s, processed, skipped)
            return None
        t0, p0, s0 = self._start
        elapsed = now_s - t0
        if elapsed < self.window_s:
            return None
        self._done = True
        p, s = processed - p0, skipped - s0
        total = p + s
        share = p / total if total else 1.0
        rate = p / elapsed
        if share >= self.threshold:
            return True, (f"processing keeps up: {100 * share:.0f} % of triples processed "
                          f"({rate:.1f}/s) over the first {elapsed:.0f} s")
        return False, (f"processing cannot keep up: only {100 * share:.0f} % of triples "
                       f"processed ({rate:.1f}/s, {s / elapsed:.1f}/s skipped) over the first "
                       f"{elapsed:.0f} s; {self.advice}")


def keep_up_advice(image_size: tuple[int, int], binning: int, *,
                   rendering: bool = False) -> str:
    """What a site that does not keep up can change, for cameras of ``image_size`` (W, H)
    and the chain's ``binning``: a camera wider than 320 px first of all its binning (the
    chain then costs what it costs at 320x240), then the documented speed settings.

    ``rendering``: the simulated scene was still rendering in a background process at the
    start (a first start shows its preview meanwhile). That process takes CPU from the
    workers (measured: 89 % and 56 % processed with two and one worker against 100 % and
    75 % with the scene cached), so it is named first: the settings are not the cause.
    """
    w, h = image_size
    hints = ["lower the frame rate", "add workers/cores"]
    if rendering:
        hints.insert(0, "the simulated scene was rendering in a background process at the "
                        "start and takes CPU from the workers (`ogiflow run --prepare` "
                        "renders it before a start); otherwise")
    if w > 320 and binning == 1 and w % 2 == 0 and h % 2 == 0:
        hints.append(f"bin the {w}x{h} cameras' pixels (processing.parameters.binning: 2, a "
                     "quarter of the chain's work)")
    hints.append("or trade accuracy for speed (processing.parameters: a coarser warm pyramid, "
                 "fewer warm pyramid levels, with active_region on as by default; "
                 "docs/performance.md, benchmarks/configs/)")
    return ", ".join(hints)


@dataclass
class StageTimes:
    """Median wall time of each chain stage over the last ``keep`` results, ms.

    Fed with each result's ``timings_ms`` (:attr:`processing.chain.driver.SceneFlowResult.
    timings_ms`: one entry per stage and ``total``, measured in the worker).
    """

    keep: int = 300
    _times: dict[str, deque[float]] = field(default_factory=dict)

    def add(self, timings_ms: Mapping[str, float]) -> None:
        """One result's stage times (ms); stages it does not name keep their history."""
        for stage, ms in timings_ms.items():
            q = self._times.get(stage)
            if q is None:
                q = self._times[stage] = deque(maxlen=self.keep)
            q.append(float(ms))

    def medians(self) -> dict[str, float]:
        """{stage: median ms} in the order the stages were first seen."""
        return {k: statistics.median(q) for k, q in self._times.items() if q}

    def describe(self) -> str | None:
        """"chain 58 ms per triple (median of the last N: preprocess 11, flow 15, ...;
        slowest disparity)", or None before the first result."""
        med = self.medians()
        total = med.pop("total", None)
        if total is None:
            return None
        n = len(self._times["total"])
        parts = ", ".join(f"{k} {v:.1f}" for k, v in med.items())
        slowest = max(med, key=med.__getitem__) if med else None
        return (f"chain {total:.1f} ms per triple (median of the last {n}, ms: {parts}"
                + (f"; slowest {slowest})" if slowest else ")"))


def peak_rss_mb(pid: int | None) -> float | None:
    """Peak resident memory (VmHWM) of a process in MB (None: this one); None if unknown.

    Read from /proc, not getrusage: a spawned child inherits its parent's ru_maxrss across
    fork and exec, which would report the daemon's peak for every worker.
    """
    return _proc_status_mb(pid, "VmHWM:")


def rss_mb(pid: int | None) -> float | None:
    """Resident memory now (VmRSS) of a process in MB (None: this one); None if unknown."""
    return _proc_status_mb(pid, "VmRSS:")


def _proc_status_mb(pid: int | None, key: str) -> float | None:
    try:
        text = Path(f"/proc/{pid or 'self'}/status").read_text()
    except OSError:
        return None
    for line in text.splitlines():
        if line.startswith(key):
            return int(line.split()[1]) / 1024  # kB
    return None
