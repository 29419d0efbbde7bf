"""``ogiflow reprocess`` (local Ray, all cores) against ``ogiflow replay --fast``, same run.

Run from the repository root (needs the ``cluster`` extra):

    PYTHONPATH=. python benchmarks/bench_reprocess.py [--recordings N] [--duration S]
        [--segment-s S] [--fields-every N] [RECORDING.mcap ...]

Without recordings it first records N runs of the default simulated appliance
(``ogiflow run --duration S``, processing off, 320x240 at 30 Hz, the default chain
parameters). Then, on the same files and with the same segmenting:

1. ``ogiflow replay --fast --segment-s S`` on each file in turn (one process, as a user
   runs it today);
2. ``ogiflow reprocess FILES --segment-s S`` (local Ray on all cores);
3. the machine's own ceiling: one ``replay --fast`` process per file, all at once (no Ray,
   no segments): how much faster two chains run side by side than one after the other on
   these cores (shared memory bandwidth and caches make it less than the core count).

All are timed as whole commands (start-up, planning and merging included) and their
summaries are checked to be identical. Prints triples/s of each, the speed-up, and the
measured cost of one segment (from the manifest), which the scaling estimate of
docs/reprocessing.md uses.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from appliance.recording.reader import iter_json

ROOT = Path(__file__).resolve().parent.parent


def _cli(*args: str) -> float:
    """Run ``python -m appliance ARGS``; wall time in s (raises on failure)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    t = time.perf_counter()
    subprocess.run([sys.executable, "-m", "appliance", *args], cwd=ROOT, env=env, check=True,
                   stdout=subprocess.DEVNULL)
    return time.perf_counter() - t


def _cli_parallel(runs: list[list[str]]) -> float:
    """Run several ``python -m appliance ARGS`` at once; wall time of all in s."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    t = time.perf_counter()
    procs = [subprocess.Popen([sys.executable, "-m", "appliance", *args], cwd=ROOT, env=env,
                              stdout=subprocess.DEVNULL) for args in runs]
    codes = [p.wait() for p in procs]
    if any(codes):
        raise RuntimeError(f"a parallel replay failed: exit codes {codes}")
    return time.perf_counter() - t


def _record(n: int, duration: float, where: Path) -> list[Path]:
    for i in range(n):
        _cli("run", "--duration", str(duration), "--live", "off", "--record-dir",
             str(where / f"appliance-{i}"), "--set", "processing.enabled=false",
             "--set", "recording.split=false")
    return sorted(where.glob("appliance-*/ogiflow-*.mcap"))


def _summaries(path: Path) -> list[tuple[int, str]]:
    _r, msgs = iter_json(path, ["/sceneflow/summary"])
    return sorted((m["pair_index"], json.dumps(m, sort_keys=True)) for _t, m in msgs)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("recordings", nargs="*", type=Path)
    ap.add_argument("--recordings-to-make", "--recordings", dest="n", type=int, default=2)
    ap.add_argument("--duration", type=float, default=45.0, help="s per made recording")
    ap.add_argument("--segment-s", type=float, default=10.0)
    ap.add_argument("--fields-every", type=int, default=30)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-reprocess-") as tmp:
        work = Path(tmp)
        files = [p.resolve() for p in args.recordings] or _record(args.n, args.duration, work)
        common = ["--segment-s", str(args.segment_s), "--fields-every", str(args.fields_every)]
        t_replay = 0.0
        replayed = []
        (work / "parallel").mkdir(parents=True, exist_ok=True)
        for i, f in enumerate(files):
            out = work / "replay" / f"{i}.mcap"
            out.parent.mkdir(parents=True, exist_ok=True)
            t_replay += _cli("replay", str(f), "--fast", "--out", str(out), *common)
            replayed.append(out)
        t_parallel = _cli_parallel([
            ["replay", str(f), "--fast", "--out", str(work / "parallel" / f"{i}.mcap"), *common]
            for i, f in enumerate(files)]) if len(files) > 1 else None
        out_dir = work / "reprocess"
        t_reprocess = _cli("reprocess", *map(str, files), "--out", str(out_dir), *common)
        triples = sum(len(_summaries(p)) for p in replayed)
        merged = sorted(p for p in out_dir.glob("*/*.mcap"))
        same = sorted(s for p in replayed for s in _summaries(p)) == sorted(
            s for p in merged for s in _summaries(p))
        entries = [json.loads(line) for line in (out_dir / "manifest.jsonl").read_text()
                   .splitlines()]
        segs = [e for e in entries if e["kind"] == "segment"]
        per_seg = statistics.median(e["seconds"] for e in segs)
        per_triple = statistics.median(e["seconds"] / max(1, e["expected"]) for e in segs)
    print(f"inputs: {len(files)} recording(s), {triples} triples, segment {args.segment_s} s, "
          f"fields every {args.fields_every}, {os.cpu_count()} cores")
    print(f"replay --fast (one process, files in turn): {t_replay:7.1f} s  "
          f"{triples / t_replay:6.2f} triples/s")
    print(f"reprocess (local Ray, all cores):           {t_reprocess:7.1f} s  "
          f"{triples / t_reprocess:6.2f} triples/s")
    print(f"speed-up: {t_replay / t_reprocess:.2f}x; summaries identical: {same}")
    if t_parallel is not None:
        print(f"ceiling, one replay per file all at once (no Ray): {t_parallel:7.1f} s  "
              f"{t_replay / t_parallel:.2f}x; reprocess reaches "
              f"{t_parallel / t_reprocess * 100:.0f} % of it")
    print(f"one segment ({len(segs)} run): median {per_seg:.1f} s, {per_triple * 1e3:.0f} ms "
          f"per triple inside a task (reading the file up to the segment included)")


if __name__ == "__main__":
    main()
