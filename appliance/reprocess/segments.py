"""Cutting a recording into time segments and running the chain over them.

Pairs are numbered 0 .. P-1 in recording order; triple k is (pair k, k+1, k+2), so there
are P-2 triples. A segment owns a contiguous range of pairs [first, stop): it records
their ``/pairs`` messages and processes the triples that *start* in it, k in
[first, min(stop, P-2)), reading the two pairs after ``stop`` as overlap. Segments are cut
by time: pair k belongs to segment floor((t_k - t_0) / S). So every pair and every triple
belongs to exactly one segment, whatever S is.

Warm starts at borders: every segment starts from a fresh
:class:`~processing.chain.ChainState` (cold start: SGM disparity, a new normalisation
scale, no previous flow), and inside a segment the state is carried from triple to
triple exactly as in the live appliance. A segment's results therefore depend only on the
recording, the parameters and its borders - not on which process or machine ran it, nor
on the order segments ran in - which is what makes ``ogiflow reprocess`` and
``ogiflow replay --segment-s S`` give identical files.
"""

from __future__ import annotations

import collections
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from appliance.reprocess.source import (
    PairStream,
    Recording,
    load_parameters,
    read_wind,
    wind_history,
)
from appliance.runtime.emission_setup import NO_RADIOMETRY, EmissionSetup, emission_rate
from appliance.runtime.gas_temperature import GateTemperature
from appliance.runtime.publishing import ResultPublisher
from appliance.runtime.worker_result import WorkerResult, pack_result
from appliance.runtime.workers import compute_scene_flow_on
from processing.chain import ChainParameters, ChainState, StereoGeometry
from processing.emission.estimator import EmissionSettings
from processing.emission.gas import METHANE, load_gas


@dataclass(frozen=True)
class Segment:
    """Pairs [first, stop) of a recording; ``index`` is its number in the recording."""

    index: int
    first: int
    stop: int

    def triples(self, n_pairs: int) -> range:
        """Triples (by t0 pair index) this segment processes."""
        return range(self.first, min(self.stop, n_pairs - 2))


def cut_segments(times_ns: Sequence[int], segment_s: float | None) -> list[Segment]:
    """Segments of pairs with capture times ``times_ns`` (increasing), ``segment_s`` long.

    None (or a recording with fewer than two pairs) gives one segment of everything.
    """
    n = len(times_ns)
    if segment_s is None or n < 2:
        return [Segment(0, 0, n)]
    if not segment_s > 0:
        raise ValueError(f"--segment-s must be > 0, got {segment_s}")
    t = np.asarray(times_ns, dtype=np.int64)
    bins = ((t - t[0]) // round(segment_s * 1e9)).astype(np.int64)
    starts = [0, *(np.flatnonzero(np.diff(bins)) + 1).tolist()]
    ends = [*starts[1:], n]
    return [Segment(i, a, b) for i, (a, b) in enumerate(zip(starts, ends, strict=True))]


@dataclass
class SegmentReport:
    """What running one or more segments did (summed by the caller over segments)."""

    pairs: int = 0
    triples: int = 0
    failed: int = 0
    truncated: bool = False
    unpaired: dict[str, int] = field(default_factory=lambda: {"left": 0, "right": 0})
    errors: list[str] = field(default_factory=list)
    seconds: float = 0.0


def run_segments(
    rec: Recording,
    geometry: StereoGeometry,
    params: ChainParameters,
    segments: Sequence[Segment],
    publisher: Any,
    *,
    fields_every: int = 1,
    pace: bool = False,
    on_triple: Callable[[SegmentReport], None] | None = None,
    emission: Any = None,
) -> SegmentReport:
    """Process ``segments`` (ascending, of one recording) and publish their results.

    Reads the recording from its start (the stamper's clock models need every frame) up to
    the last pair the last segment needs, then stops.

    Parameters
    ----------
    rec, geometry, params
        The recording and how to process it.
    segments : sequence of Segment
        Which pairs to record and which triples to process; each starts cold.
    publisher : appliance.runtime.publishing.ResultPublisher
        Records ``/pairs``, summaries, wind in the camera frame and fields.
    fields_every : int
        Record the full fields of triple k when (k + 1) % fields_every == 0 (by the
        triple's index, so the choice does not depend on segmenting).
    pace : bool
        Run at the recorded pace (for watching live) instead of as fast as possible.
    on_triple : callable, optional
        Called with the running report after each triple (progress display).
    emission : appliance.runtime.emission_setup.EmissionSetup, optional
        Compute every triple's emission rate (its background model starts anew with each
        segment, like the chain).

    Returns
    -------
    SegmentReport
        ``truncated`` when the recording ends inside a record (cut by a crash):
        everything up to the cut was processed.
    """

    owner = _Owner(segments)
    report = SegmentReport()
    pairs = PairStream(rec)
    window: collections.deque[tuple[int, Any]] = collections.deque(maxlen=3)
    state = ChainState()
    estimator = None if emission is None else emission.estimator(geometry, params.binning)
    pacer = _Pacer() if pace else None
    t_start = time.monotonic()
    for index, pair in _until(pairs, owner.last_needed):
        if owner.records_pair(index):
            publisher.record_pair(index, pair)
            report.pairs += 1
        window.append((index, pair))
        if len(window) < 3 or not owner.processes(k := window[0][0]):
            continue
        if owner.starts_segment(k):
            state = ChainState()  # cold start at every segment border (module docstring)
            estimator = None if emission is None else emission.estimator(geometry, params.binning)
            publisher.restart_rate_window()
        if pacer is not None:
            pacer.wait(pair.time_ns)
        base = _process_triple(rec, k, [p for _, p in window], geometry, params, state,
                               estimator, emission, report)
        publisher.publish(base, fields=(k + 1) % fields_every == 0)
        if on_triple is not None:
            on_triple(report)
    report.truncated = pairs.truncated
    report.unpaired = dict(pairs.unpaired)
    report.seconds = time.monotonic() - t_start
    return report


class _Pacer:
    """Sleeps so that pairs come at their recorded pace.

    The clock starts with the first triple, not before the set-up (loading the compiled
    kernels can take seconds; counted in, the first seconds of the recording would then run
    unpaced).
    """

    def __init__(self) -> None:
        self._t_first: int | None = None
        self._t_pace = 0.0

    def wait(self, t_ns: int) -> None:
        """Wait until the pair recorded at ``t_ns`` (ns) is due."""
        if self._t_first is None:
            self._t_first, self._t_pace = t_ns, time.monotonic()
        ahead = (t_ns - self._t_first) / 1e9 - (time.monotonic() - self._t_pace)
        if ahead > 0:
            time.sleep(ahead)


def _process_triple(rec: Recording, k: int, trio: list[Any], geometry: StereoGeometry,
                    params: ChainParameters, state: ChainState, estimator: Any,
                    emission: Any, report: SegmentReport) -> WorkerResult:
    """The chain (and the emission rate) on the triple of pairs k, k + 1, k + 2, packed as
    the daemon's workers pack it; a ValueError is the result's error, counted in
    ``report``."""
    t_mono = tuple(p.time_ns for p in trio)
    base = WorkerResult(worker=0, pair_indices=(k, k + 1, k + 2), t_mono_ns=t_mono,  # type: ignore[arg-type]
                        t_wall_ns=rec.wall_ns(t_mono[1]), skipped=0, done_mono_ns=0)
    left = np.stack([p.left.image for p in trio]).astype(np.uint16, copy=False)
    right = np.stack([p.right.image for p in trio]).astype(np.uint16, copy=False)
    try:
        res = compute_scene_flow_on(left, right, t_mono, geometry, params, state)
        pack_result(res, base, binning=params.binning)
        if estimator is not None and emission is not None:
            base.rate = emission_rate(estimator, left[1], res, emission.temperature_k())
        elif emission is not None:
            base.rate = NO_RADIOMETRY
        report.triples += 1
    except ValueError as exc:
        base.error = str(exc)
        report.failed += 1
        report.errors.append(f"pairs {(k, k + 1, k + 2)}: {exc}")
    return base


def process_into(
    sink: Any,
    rec: Recording,
    geometry: StereoGeometry,
    params: ChainParameters,
    segments: Sequence[Segment],
    *,
    fields_every: int = 1,
    copy_wind: bool = False,
    live: Any = None,
    pace: bool = False,
    on_triple: Callable[[SegmentReport], None] | None = None,
    keep_summaries: bool = False,
    wind: Sequence[dict[str, Any]] | None = None,
) -> tuple[SegmentReport, Any]:
    """Run ``segments`` of ``rec`` and publish into ``sink`` as the appliance would.

    Builds the :class:`~appliance.runtime.publishing.ResultPublisher` with the recording's
    wind in the camera frame (all of the file's samples, so every segment interpolates the
    same wind) and calls :func:`run_segments`. ``copy_wind`` also copies the raw wind
    samples into ``sink`` first (a whole-file replay; reprocess copies them once, when
    merging). Returns the report and the publisher (with ``keep_summaries`` its ``summaries``
    hold every summary). ``wind``: the recording's raw wind samples when the caller has
    read them already (:func:`appliance.reprocess.source.read_wind`).
    """

    wind = read_wind(rec.path) if wind is None else wind
    if copy_wind:
        sink.record_wind(wind, rec.wall_offset_ns)
    events = rec.config.get("events", {}) or {}
    publisher = ResultPublisher(sink, live, rec.wall_ns, fields_every,
                                keep_summaries=keep_summaries,
                                rate_window_s=float(events.get("rate_window_s", 30.0)))
    history = wind_history(rec, wind)
    if history is not None:
        publisher.wind_at = history.at
    report = run_segments(rec, geometry, params, segments, publisher,
                          fields_every=fields_every, pace=pace, on_triple=on_triple,
                          emission=recorded_emission(rec.meta, rec.config, wind))
    return report, publisher


class _Owner:
    """Which pairs and triples a list of segments covers."""

    def __init__(self, segments: Sequence[Segment]) -> None:
        if not segments:
            raise ValueError("no segment to run")
        self.segments = sorted(segments, key=lambda s: s.first)
        self._firsts = {s.first for s in self.segments}
        self.last_needed = self.segments[-1].stop + 1  # two pairs of overlap

    def _find(self, index: int) -> Segment | None:
        for s in self.segments:
            if s.first <= index < s.stop:
                return s
        return None

    def records_pair(self, index: int) -> bool:
        return self._find(index) is not None

    def processes(self, k: int) -> bool:
        # The triple exists (its last pair was read); it belongs to the segment of pair k.
        return self._find(k) is not None

    def starts_segment(self, k: int) -> bool:
        return k in self._firsts


def _until(pairs: PairStream, last: int) -> Iterator[tuple[int, Any]]:
    """Pairs up to index ``last`` (inclusive); stops reading the file there."""
    it = iter(pairs)
    try:
        for index, pair in it:
            yield index, pair
            if index >= last:
                return
    finally:
        close = getattr(it, "close", None)
        if close is not None:
            close()


def recorded_emission(meta: Any, config: dict[str, Any],
                      wind: Sequence[dict[str, Any]]) -> Any:
    """The emission settings a recording was made with (None: disabled): its ``emission``
    metadata when it has one, else its configuration, where the gas temperature is the
    configured one or the median recorded sonic temperature, and a gas file that is no
    longer readable falls back to methane (warned)."""

    recorded = (meta.get("emission", {}) or {}).get("json")
    if recorded:
        try:
            return EmissionSetup.from_json(recorded)
        except ValueError as exc:
            print(f"warning: {exc}; using the recorded configuration", file=sys.stderr)
    em = config.get("emission", {}) or {}
    if not em.get("enabled", True):
        return None
    gas = METHANE
    if em.get("gas_file"):
        try:
            gas = load_gas(em["gas_file"])
        except (OSError, ValueError) as exc:
            print(f"warning: recorded gas file unusable ({exc}); methane", file=sys.stderr)
    t_gas = em.get("gas_temperature_k")
    if t_gas is None:
        t_gas = median_sonic_k(wind)
    settings = EmissionSettings(gas=gas, pressure_pa=float(em.get("pressure_pa", 101325.0)),
                                background_frames=int(em.get("background_frames", 60)))
    return EmissionSetup(settings, None if t_gas is None else float(t_gas))


def recorded_gas_temperature_k(emission: Any, config: dict[str, Any],
                               wind: Sequence[dict[str, Any]]) -> float | None:
    """The gas temperature of a recording, K: the configured (or simulated scene's) one of
    its emission settings, else the median of its sonic temperatures; None: neither."""
    configured = (emission.gas_temperature_k if emission is not None
                  else (config.get("emission", {}) or {}).get("gas_temperature_k"))
    return float(configured) if configured is not None else median_sonic_k(wind)


def median_sonic_k(wind: Sequence[dict[str, Any]]) -> float | None:
    """Median sonic temperature of recorded wind samples, K; None: none reported one."""
    sonic = [m["sonic_temperature_c"] for m in wind if m.get("sonic_temperature_c") is not None]
    return float(np.median(sonic)) + 273.15 if sonic else None


def replay_parameters(rec: Recording, overrides: dict[str, Any],
                      wind: Sequence[dict[str, Any]] | None = None) -> ChainParameters:
    """The chain parameters to reprocess ``rec`` with: the recorded ones with ``overrides``
    (:func:`appliance.reprocess.source.load_parameters`); a recording that ran the
    opaque-edge gate at the site's gas temperature (``processing.opaque_gate``) gets the
    gate at the recording's (:func:`recorded_gas_temperature_k`; 15 degC without one) -
    one value for the whole file where the live run took each moment's - unless an
    override sets ``opaque_gate_gas_k``. ``wind``: the recording's raw wind samples when
    the caller has read them already."""
    params = load_parameters(rec.meta, overrides)
    if not (rec.config.get("processing", {}) or {}).get("opaque_gate") \
            or "opaque_gate_gas_k" in overrides:
        return params
    wind = read_wind(rec.path) if wind is None else wind
    t_gas = recorded_gas_temperature_k(recorded_emission(rec.meta, rec.config, wind),
                                       rec.config, wind)
    return GateTemperature(t_gas).parameters(params)
