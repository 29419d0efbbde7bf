"""Speed of the whole scene-flow chain at 320x240 or 640x480 (``ogiflow bench``).

Measures, in one run on one input (:mod:`appliance.evaluation.bench_input`):

- the median wall time of each stage of :func:`processing.chain.compute_scene_flow` (its own
  ``timings_ms``) and of the whole call: *warm*, over consecutive triples through one
  :class:`~processing.chain.ChainState` as the daemon's workers run them (only calls that
  did start warm count), once as configured and once more with the active region off (the
  solvers on the whole frame), with the mean share of the frame the solvers worked on; and
  *cold*, every triple on its own (full pyramid, SGM start), after a warm-up (numba loads
  or compiles its kernels on the first call);
- the median process CPU time of one call (load-independent as long as the process is not
  starved of cache and memory bandwidth);
- OpenCV Farneback flow on the same differential images as a reference, and each stage's
  ratio to it: this machine is shared and noisy, ratios are what stays comparable;
- a roofline-style floor: the bytes a warm triple streams through memory
  (:mod:`appliance.evaluation.roofline`) over the copy bandwidth measured in the same run;
- stereo pairs per second with N worker processes (spawned), each pinned to one OpenCV and
  one numba thread and taking every N-th triple as the daemon's workers do (sharing the
  registration shifts through shared memory as they do), back to back for a fixed wall
  time after its own warm-up: completed triples / wall time. In streaming every
  new stereo pair completes one triple, so triples/s = pairs/s. They run on a sequence of
  at least :data:`THROUGHPUT_MIN_FRAMES` frames: the wrap of a cycled sequence is a cold
  start, and on a short one two workers, each taking half of a lap's triples, started cold
  twice as often as one (every 7th triple of 16 frames against every 14th) while the
  daemon's workers start cold every ``cold_every``-th triple of their own whatever their
  number.
"""

from __future__ import annotations

import dataclasses
import multiprocessing as mp
import os
import queue
import statistics
import time
from dataclasses import dataclass
from typing import Any

from appliance.evaluation import roofline
from appliance.evaluation.bench_input import (
    FRAME_RATE_HZ,
    SIZES,
    SOURCES,
    BenchFrames,
    blob_frames,
    field_frames,
    geometry,
    iter_triples,
    load_frames,
)
from appliance.memory import keep_freed_memory
from appliance.runtime.imageshare import SharedImages, create_image_table
from appliance.runtime.shiftshare import SharedShiftMemo, create_shift_table
from appliance.runtime.workers import single_threaded
from processing.chain import ChainParameters, ChainState, compute_scene_flow
from processing.chain.state import STRIDES
from processing.flow.opencv import farneback_flow

__all__ = ["FRAME_RATE_HZ", "SIZES", "SOURCES", "STAGES", "THROUGHPUT_MIN_FRAMES", "BenchFrames",
           "StageTimes", "Throughput",
           "blob_frames", "field_frames", "geometry", "iter_triples", "load_average",
           "load_frames", "measure_stages", "measure_throughput", "single_thread"]

#: Frames of the pairs/s input at least: a lap of one worker's or of each of two workers'
#: own triples is then ``cold_every`` long, so the wrap's cold start comes as often as the
#: daemon's ``cold_every`` one (1 in 30 own triples) for either number of workers.
THROUGHPUT_MIN_FRAMES = 2 * ChainParameters().cold_every + 2

#: Order in which stages are reported (the chain's ``timings_ms`` keys, without "total";
#: "depth_gate" is 0 when the gate is off).
STAGES: tuple[str, ...] = (
    "preprocess", "depth_gate", "flow", "disparity_init", "disparity", "velocity_quality",
    "segmentation", "summary",
)


def single_thread() -> None:
    """Set a process up as the appliance's workers are: OpenCV and numba on one thread (the
    targets are per core) and glibc's allocator tuned (:mod:`appliance.memory`)."""
    keep_freed_memory()
    single_threaded()


@dataclass(frozen=True)
class ChainTimes:
    """Medians over ``runs`` chain calls of one kind (warm or cold), ms.

    ``cpu_ms`` is process CPU time; the stage times are wall times (the chain's own
    ``timings_ms``); ``stages_cpu_est_ms`` estimates each stage's CPU time as its wall time
    scaled by that call's CPU / wall ratio (assumes the load was even over the call).
    """

    stages_ms: dict[str, float]
    stages_cpu_est_ms: dict[str, float]
    chain_ms: float
    cpu_ms: float
    runs: int
    #: Mean share of the frame the solvers worked on (``SceneFlowResult.region``; a whole
    #: frame counts 1) and the calls that solved the whole frame.
    solved_share: float = 1.0
    full_frame_calls: int = 0

    @property
    def box_share(self) -> float | None:
        """Mean share of the frame of the active-region boxes alone (None: no call used
        one)."""
        boxed = self.runs - self.full_frame_calls
        if boxed == 0:
            return None
        return (self.solved_share * self.runs - self.full_frame_calls) / boxed


@dataclass(frozen=True)
class StageTimes:
    """Warm and cold chain times, the Farneback reference and the roofline floor.

    ``warm_full`` is the warm chain on the same triples with the active region off (every
    warm solve on the whole frame); None when the parameters had it off already.
    """

    warm: ChainTimes
    cold: ChainTimes
    farneback_ms: float
    farneback_cpu_ms: float
    floor: Any  # roofline.Floor
    warm_full: ChainTimes | None = None

    def times(self, kind: str) -> ChainTimes:
        """The chain times of ``kind``: "warm", "warm_full" or "cold"."""
        t = {"warm": self.warm, "cold": self.cold, "warm_full": self.warm_full}[kind]
        if t is None:
            raise ValueError(f"no {kind} times were measured")
        return t

    def ratios(self, kind: str = "warm") -> dict[str, float]:
        """Each stage's and the chain's median over Farneback's median."""
        t = self.times(kind)
        out = {k: v / self.farneback_ms for k, v in t.stages_ms.items()}
        out["chain"] = t.chain_ms / self.farneback_ms
        return out


def _time_calls(calls: Any, runs: int) -> ChainTimes:
    """Run ``calls`` (an iterator of zero-argument chain calls) ``runs`` times."""
    per_stage: dict[str, list[float]] = {s: [] for s in STAGES}
    per_stage_cpu: dict[str, list[float]] = {s: [] for s in STAGES}
    total, cpu, shares = [], [], []
    for _ in range(runs):
        call = next(calls)
        c0 = time.process_time()
        result = call()
        cpu.append((time.process_time() - c0) * 1e3)
        total.append(result.timings_ms["total"])
        shares.append(_solved_share(result))
        share = cpu[-1] / total[-1]
        for s in STAGES:
            per_stage[s].append(result.timings_ms.get(s, 0.0))
            per_stage_cpu[s].append(result.timings_ms.get(s, 0.0) * share)
    return ChainTimes(
        stages_ms={s: statistics.median(v) for s, v in per_stage.items()},
        stages_cpu_est_ms={s: statistics.median(v) for s, v in per_stage_cpu.items()},
        chain_ms=statistics.median(total), cpu_ms=statistics.median(cpu), runs=runs,
        solved_share=statistics.fmean(shares), full_frame_calls=shares.count(1.0))


def _solved_share(result: Any) -> float:
    """Share of the frame the solvers of one call worked on (1 = the whole frame)."""
    if result.region is None:
        return 1.0
    y0, y1, x0, x1 = result.region
    h, w = result.valid.shape
    return (y1 - y0) * (x1 - x0) / (h * w)


def _warm_calls(frames: BenchFrames, geo: Any, params: ChainParameters,
                warmup: int) -> Any:
    """Chain calls over consecutive triples through one state, after ``warmup`` untimed
    ones; only calls that start warm are yielded (the wrap of the input starts untimed)."""
    triples = iter_triples(frames)
    state = ChainState()
    for _ in range(warmup):
        compute_scene_flow(*next(triples), geo, params, state)
    while True:
        args = next(triples)
        if not state.follows(args[2]):
            compute_scene_flow(*args, geo, params, state)
            continue
        yield lambda args=args: compute_scene_flow(*args, geo, params, state)


def measure_stages(frames: BenchFrames, params: ChainParameters | None = None, *,
                   runs: int = 30, warmup: int = 3) -> StageTimes:
    """Median per-stage and whole-chain times, warm and cold, in this process (one thread).

    ``params`` (default: the chain's defaults) run warm and cold; with its active region on,
    the warm chain is timed a second time on the same triples with it off (``warm_full``).
    """

    if runs < 1 or warmup < 1:
        raise ValueError(f"runs and warmup must be >= 1, got {runs} and {warmup}")
    single_thread()
    geo = geometry(frames.image_size)
    params = ChainParameters() if params is None else params
    triples = iter_triples(frames)

    def cold_calls() -> Any:
        while True:
            args = next(triples)
            yield lambda args=args: compute_scene_flow(*args, geo, params)

    warm = _time_calls(_warm_calls(frames, geo, params, warmup), runs)
    warm_full = None
    if params.active_region:
        no_region = dataclasses.replace(params, active_region=False)
        warm_full = _time_calls(_warm_calls(frames, geo, no_region, warmup), runs)
    cold = _time_calls(cold_calls(), runs)
    result = compute_scene_flow(*next(triples), geo, params)
    d0, d1 = result.diff_left
    fb, fb_cpu = [], []
    for i in range(warmup + runs):
        t0, c0 = time.perf_counter(), time.process_time()
        farneback_flow(d0, d1)
        if i >= warmup:
            fb.append((time.perf_counter() - t0) * 1e3)
            fb_cpu.append((time.process_time() - c0) * 1e3)
    floor = roofline.floor(geo.image_size[::-1], params, warm=True)
    return StageTimes(warm=warm, cold=cold, farneback_ms=statistics.median(fb),
                      farneback_cpu_ms=statistics.median(fb_cpu), floor=floor,
                      warm_full=warm_full)


@dataclass(frozen=True)
class Throughput:
    """Result of one throughput measurement with ``workers`` processes."""

    workers: int
    triples: int
    wall_s: float
    cpu_s: float
    #: Per worker, the share of its timed triples' D(t0) lookups (one per camera) that found
    #: the image computed, by its own previous triple or another worker (0..1).
    d0_found: tuple[float, ...] = ()

    @property
    def pairs_per_s(self) -> float:
        """Completed triples (= new stereo pairs in streaming) per second of wall time."""
        return self.triples / self.wall_s

    @property
    def cpu_ms_per_pair(self) -> float:
        """Process CPU time per triple, summed over the workers."""
        return 1e3 * self.cpu_s / self.triples

    @property
    def pairs_per_cpu_s(self) -> float:
        """Triples per second of CPU time: the pairs/s of one worker on an idle core."""
        return self.triples / self.cpu_s


def _worker(frames: BenchFrames, params: ChainParameters, seconds: float, warmup: int,
            offset: int, stride: int, barrier: Any, results: Any, shift_table: Any,
            image_table: Any) -> None:
    """One throughput worker (spawned): warm up, wait for the others, run ``seconds``.

    It takes every ``stride``-th triple from ``offset`` on and shares registration shifts
    (``shift_table``), corrected frames and differential images (``image_table``, None for
    one worker) with the other workers, as the daemon's workers do.
    """
    os.environ["NUMBA_NUM_THREADS"] = "1"  # before numba is first imported in this process
    os.environ["OMP_NUM_THREADS"] = "1"
    single_thread()

    geo = geometry(frames.image_size)
    state = ChainState(stride=stride if stride in STRIDES else 1,
                       shifts=SharedShiftMemo(shift_table),
                       images=None if image_table is None else SharedImages(image_table))
    triples = iter_triples(frames)
    for _ in range(offset):
        next(triples)

    def run_one() -> None:
        compute_scene_flow(*next(triples), geo, params, state)
        for _ in range(stride - 1):
            next(triples)

    for _ in range(warmup):
        run_one()
    barrier.wait()
    t0, c0 = time.perf_counter(), time.process_time()
    found0 = state.differences_reused
    deadline = t0 + seconds
    done = 0
    now = t0
    while now < deadline:
        run_one()
        done += 1
        now = time.perf_counter()
    # one D(t0) lookup per camera and triple
    found = (state.differences_reused - found0) / (2 * done)
    results.put((done, now - t0, time.process_time() - c0, offset, found))


def measure_throughput(frames: BenchFrames, workers: int, *, seconds: float = 10.0,
                       warmup: int = 3, params: ChainParameters | None = None) -> Throughput:
    """Pairs/s with ``workers`` spawned processes running the chain back to back, with
    ``params`` (default: the chain's defaults).

    All workers start together after their own warm-up (a barrier); the wall time is the
    longest of theirs (each stops after the first triple completed past ``seconds``).
    """
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    if not seconds > 0:
        raise ValueError(f"seconds must be > 0, got {seconds}")
    ctx = mp.get_context("spawn")
    barrier = ctx.Barrier(workers)
    results = ctx.Queue()
    shift_table = create_shift_table(ctx)
    params = ChainParameters() if params is None else params
    image_table = (create_image_table(ctx, frames.image_size, params.binning) if workers > 1
                   else None)
    procs = [ctx.Process(target=_worker, args=(frames, params, seconds, warmup, i, workers,
                                               barrier, results, shift_table, image_table),
                         daemon=True)
             for i in range(workers)]
    for p in procs:
        p.start()
    out = []
    try:
        # generous: spawn + imports + warm-up + the run itself
        limit = time.monotonic() + seconds + 300.0
        while len(out) < workers:
            try:
                out.append(results.get(timeout=1.0))
            except queue.Empty:
                if time.monotonic() > limit or any(
                        p.exitcode not in (None, 0) for p in procs):
                    codes = [p.exitcode for p in procs]
                    raise RuntimeError(f"a bench worker failed (exit codes {codes})") from None
    finally:
        for p in procs:
            p.join(timeout=5.0)
            if p.is_alive():
                p.terminate()
                p.join()
    return Throughput(workers=workers, triples=sum(r[0] for r in out),
                      wall_s=max(r[1] for r in out), cpu_s=sum(r[2] for r in out),
                      d0_found=tuple(r[4] for r in sorted(out, key=lambda r: r[3])))


def load_average() -> tuple[float, float, float] | None:
    """The 1, 5 and 15 min load averages (None where the platform has none)."""
    try:
        return os.getloadavg()
    except OSError:
        return None
