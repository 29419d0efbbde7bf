"""Speed of the whole scene-flow chain at 320x240 (issues 3 and 15; ``ogiflow bench``).

Measures, in one run on one input (:mod:`appliance.evaluation.bench_input`):

- the median wall time of each stage of :func:`processing.chain.compute_scene_flow` (its own
  ``timings_ms``) and of the whole call, twice: *warm*, over consecutive triples through one
  :class:`~processing.chain.ChainState` as the daemon's workers run them (only calls that
  did start warm count), and *cold*, every triple on its own (full pyramid, SGM start), after
  a warm-up (numba loads or compiles its kernels on the first call);
- the median process CPU time of one call (load-independent as long as the process is not
  starved of cache and memory bandwidth);
- OpenCV Farneback flow on the same differential images as a reference, and each stage's
  ratio to it: this machine is shared and noisy, ratios are what stays comparable;
- a roofline-style floor: the bytes a warm triple streams through memory
  (:mod:`appliance.evaluation.roofline`) over the copy bandwidth measured in the same run;
- stereo pairs per second with N worker processes (spawned), each pinned to one OpenCV and
  one numba thread and taking every N-th triple as the daemon's workers do, back to back for a
  fixed wall time after its own warm-up: completed triples / wall time. In streaming every
  new stereo pair completes one triple, so triples/s = pairs/s.
"""

from __future__ import annotations

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
    SOURCES,
    BenchFrames,
    blob_frames,
    field_frames,
    geometry,
    iter_triples,
    load_frames,
)
from appliance.memory import keep_freed_memory
from appliance.runtime.workers import single_threaded
from processing.chain import ChainParameters, ChainState, compute_scene_flow
from processing.chain.state import STRIDES
from processing.flow.opencv import farneback_flow

__all__ = ["FRAME_RATE_HZ", "SOURCES", "STAGES", "BenchFrames", "StageTimes", "Throughput",
           "blob_frames", "field_frames", "geometry", "iter_triples", "load_average",
           "load_frames", "measure_stages", "measure_throughput", "single_thread"]

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


@dataclass(frozen=True)
class StageTimes:
    """Warm and cold chain times, the Farneback reference and the roofline floor."""

    warm: ChainTimes
    cold: ChainTimes
    farneback_ms: float
    farneback_cpu_ms: float
    floor: Any  # roofline.Floor

    def ratios(self, kind: str = "warm") -> dict[str, float]:
        """Each stage's and the chain's median over Farneback's median."""
        t = self.warm if kind == "warm" else self.cold
        out = {k: v / self.farneback_ms for k, v in t.stages_ms.items()}
        out["chain"] = t.chain_ms / self.farneback_ms
        return out


def _time_calls(calls: Any, runs: int) -> ChainTimes:
    """Run ``calls`` (an iterator of zero-argument chain calls) ``runs`` times."""
    per_stage: dict[str, list[float]] = {s: [] for s in STAGES}
    per_stage_cpu: dict[str, list[float]] = {s: [] for s in STAGES}
    total, cpu = [], []
    for _ in range(runs):
        call = next(calls)
        c0 = time.process_time()
        result = call()
        cpu.append((time.process_time() - c0) * 1e3)
        total.append(result.timings_ms["total"])
        share = cpu[-1] / total[-1]
        for s in STAGES:
            per_stage[s].append(result.timings_ms.get(s, 0.0))
            per_stage_cpu[s].append(result.timings_ms.get(s, 0.0) * share)
    return ChainTimes(
        stages_ms={s: statistics.median(v) for s, v in per_stage.items()},
        stages_cpu_est_ms={s: statistics.median(v) for s, v in per_stage_cpu.items()},
        chain_ms=statistics.median(total), cpu_ms=statistics.median(cpu), runs=runs)


def measure_stages(frames: BenchFrames, *, runs: int = 30, warmup: int = 3) -> StageTimes:
    """Median per-stage and whole-chain times, warm and cold, in this process (one thread)."""

    if runs < 1 or warmup < 1:
        raise ValueError(f"runs and warmup must be >= 1, got {runs} and {warmup}")
    single_thread()
    geo, params = geometry(), ChainParameters()
    triples = iter_triples(frames)
    state = ChainState()
    result = None
    for _ in range(warmup):
        result = compute_scene_flow(*next(triples), geo, params, state)

    def warm_calls() -> Any:
        while True:
            args = next(triples)
            if not state.follows(args[2]):  # the wrap of the input: start it, untimed
                compute_scene_flow(*args, geo, params, state)
                continue
            yield lambda args=args: compute_scene_flow(*args, geo, params, state)

    def cold_calls() -> Any:
        while True:
            args = next(triples)
            yield lambda args=args: compute_scene_flow(*args, geo, params)

    warm = _time_calls(warm_calls(), runs)
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
                      farneback_cpu_ms=statistics.median(fb_cpu), floor=floor)


@dataclass(frozen=True)
class Throughput:
    """Result of one throughput measurement with ``workers`` processes."""

    workers: int
    triples: int
    wall_s: float
    cpu_s: float

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


def _worker(frames: BenchFrames, seconds: float, warmup: int, offset: int, stride: int,
            barrier: Any, results: Any) -> None:
    """One throughput worker (spawned): warm up, wait for the others, run ``seconds``.

    It takes every ``stride``-th triple from ``offset`` on, as the daemon's workers do.
    """
    os.environ["NUMBA_NUM_THREADS"] = "1"  # before numba is first imported in this process
    os.environ["OMP_NUM_THREADS"] = "1"
    single_thread()

    geo, params = geometry(), ChainParameters()
    state = ChainState(stride=stride if stride in STRIDES else 1)
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
    deadline = t0 + seconds
    done = 0
    now = t0
    while now < deadline:
        run_one()
        done += 1
        now = time.perf_counter()
    results.put((done, now - t0, time.process_time() - c0))


def measure_throughput(frames: BenchFrames, workers: int, *, seconds: float = 10.0,
                       warmup: int = 3) -> Throughput:
    """Pairs/s with ``workers`` spawned processes running the chain back to back.

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
    procs = [ctx.Process(target=_worker, args=(frames, seconds, warmup, i, workers, barrier,
                                               results), daemon=True)
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
                      wall_s=max(r[1] for r in out), cpu_s=sum(r[2] for r in out))


def load_average() -> tuple[float, float, float] | None:
    """The 1, 5 and 15 min load averages (None where the platform has none)."""
    try:
        return os.getloadavg()
    except OSError:
        return None
