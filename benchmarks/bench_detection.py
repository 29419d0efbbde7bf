"""Detection delay and false alarms of the leak-event logic on the simulated site.

Two measurements with the daemon's chain and event logic (``appliance.evaluation.detection``:
``compute_scene_flow`` -> ``EvidenceStream`` -> ``LeakDetector``, default ``events`` config),
on scenes rendered on the fly (nothing written to disk):

- ``schedule``: the ``field`` leak (Stable Fluids plume, 30 Hz) switched on and off by a
  release schedule; per release the alarm delay (time the logic says "leak" - release
  start) and whether it was found; events matching no release are false events.
- ``no-release``: the ``no_release`` scene (no gas; NETD 0.03 K noise, 0.3 px jitter, a warm
  person walking 3 m to and fro every ``--walker-s`` s, a background drift of up to
  0.02 K/s over a ``--drift-s`` period, plant wall) for ``--minutes`` of scene time; every
  event is a false event.

Both process the triple starting at every ``--every``-th frame, as the daemon does when it
keeps up at 30 / every Hz (the event logic's windows are in seconds). Slow (a few minutes
per minute of scene on this class of machine), hence a benchmark, not a test;
``tests/test_detection_simulated.py`` runs short versions.

``--fields DIR`` also records what the event logic sees of every processed triple (gas
mask, flow inside it; one file per scene minute, written as the run goes), and ``replay
DIR`` runs the current event logic over such a recording in seconds: the chain's output
does not depend on the event rules, so a replay gives the events a new run would.

    python benchmarks/bench_detection.py schedule --every 6 --json schedule.json
    python benchmarks/bench_detection.py no-release --minutes 30 --json no_release.json
    python benchmarks/bench_detection.py no-release --minutes 30 --fields nr7/
    python benchmarks/bench_detection.py replay nr7/ --json no_release.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))  # `python benchmarks/bench_detection.py` from a checkout

import numpy as np  # noqa: E402

from appliance.evaluation.detection import (  # noqa: E402
    DetectionSettings,
    detect_fields,
    detect_frames,
    score_releases,
    simulated_frames,
)
from appliance.runtime.events import EventConfig  # noqa: E402
from processing.synthetic.presets import (  # noqa: E402
    FIELD_FRAME_RATE_HZ,
    preset_field,
    preset_no_release,
)
from processing.synthetic.schedule import ReleaseSchedule  # noqa: E402


def _progress(frames: Iterator[Any], step_s: float) -> Iterator[Any]:
    """Pass frames through, printing the scene time every ``step_s`` (partial results of a
    long run stay readable in its log)."""
    next_s = step_s
    for f in frames:
        if f.t_s >= next_s:
            print(f"scene time {f.t_s:.0f} s", flush=True)
            next_s += step_s
        yield f


def _print_event(kind: str, event: Any) -> None:
    print(f"event {event.id} {kind}: frame {event.start_frame} t {event.start_t_s:.1f} s, "
          f"source {event.source_xy}", flush=True)


class FieldRecorder:
    """Writes every processed triple's gas mask and the flow inside it to ``folder``, one
    ``fields-NNNN.npz`` per ``chunk_s`` of scene time (a stopped run keeps what it did)."""

    def __init__(self, folder: Path, info: dict[str, Any], chunk_s: float = 60.0) -> None:
        folder.mkdir(parents=True, exist_ok=True)
        if any(folder.glob("fields-*.npz")):
            raise ValueError(f"{folder} already holds a recording")
        self.folder, self.chunk_s, self.info = folder, chunk_s, info
        self._rows: list[tuple[float, int, np.ndarray, np.ndarray]] = []
        self._chunk = 0
        (folder / "info.json").write_text(json.dumps(info, indent=1) + "\n")

    def __call__(self, t_s: float, frame: int, mask: np.ndarray, flow: np.ndarray) -> None:
        if self._rows and t_s >= (self._chunk + 1) * self.chunk_s:
            self.flush()
        m = np.asarray(mask, bool)
        self._rows.append((t_s, frame, m, np.asarray(flow, np.float32)[m]))

    def flush(self) -> None:
        if not self._rows:
            return
        shape = self._rows[0][2].shape
        np.savez_compressed(
            self.folder / f"fields-{self._chunk:04d}.npz", shape=np.asarray(shape),
            t_s=np.asarray([r[0] for r in self._rows]),
            frame=np.asarray([r[1] for r in self._rows]),
            mask=np.stack([np.packbits(r[2]) for r in self._rows]),
            counts=np.asarray([len(r[3]) for r in self._rows]),
            flow=np.concatenate([r[3] for r in self._rows]).reshape(-1, 2))
        self._rows = []
        self._chunk += 1


def read_fields(folder: Path) -> Iterator[tuple[float, int, np.ndarray, np.ndarray]]:
    """The triples of a :class:`FieldRecorder` recording: (t_s, frame, mask, flow), the flow
    zero outside the mask (the event logic reads it only inside)."""
    files = sorted(folder.glob("fields-*.npz"))
    if not files:
        raise ValueError(f"no fields-*.npz in {folder}")
    for path in files:
        with np.load(path) as z:
            h, w = (int(v) for v in z["shape"])
            offsets = np.concatenate([[0], np.cumsum(z["counts"])])
            for k in range(len(z["t_s"])):
                mask = np.unpackbits(z["mask"][k])[:h * w].reshape(h, w).astype(bool)
                flow = np.zeros((h, w, 2), np.float32)
                flow[mask] = z["flow"][offsets[k]:offsets[k + 1]]
                yield float(z["t_s"][k]), int(z["frame"][k]), mask, flow


def run_schedule(intervals: list[list[float]], period_s: float, cycles: int, voxel_m: float,
                 every: int, seed: int, settings: DetectionSettings) -> dict[str, Any]:
    """The scheduled leak for ``cycles`` periods; per-release delays and false events."""
    schedule = ReleaseSchedule.from_lists(intervals, period_s)
    duration = cycles * period_s
    cfg = replace(preset_field(n_frames=round(duration * FIELD_FRAME_RATE_HZ),
                               voxel_m=voxel_m, seed=seed), release_schedule=schedule)
    t0 = time.perf_counter()
    report = detect_frames(_progress(simulated_frames(cfg, every), 5.0), cfg.meta(), settings,
                           every, on_event=_print_event)
    # gas released last drifts through the view for a few seconds: allow the end window
    score = score_releases(report, schedule.releases(duration), settings.events.end_window_s)
    report.pop("per_frame")
    return {"scene": "field", "schedule": schedule.to_json(), "cycles": cycles,
            "duration_s": duration, "voxel_m": voxel_m, "every": every, "seed": seed,
            "processing_hz": FIELD_FRAME_RATE_HZ / every, **score, "report": report,
            "wall_s": round(time.perf_counter() - t0, 1)}


def run_no_release(minutes: float, walker_s: float, drift_s: float, every: int, seed: int,
                   settings: DetectionSettings, fields: Path | None = None) -> dict[str, Any]:
    """The no-release scene for ``minutes`` of scene time; every event is false."""
    n = round(minutes * 60.0 * FIELD_FRAME_RATE_HZ)
    cfg = preset_no_release(n_frames=n, walker_period_s=walker_s, drift_period_s=drift_s,
                            seed=seed)
    info = {"scene": "no_release", "minutes": minutes, "walker_period_s": walker_s,
            "drift_period_s": drift_s, "every": every, "seed": seed,
            "processing_hz": FIELD_FRAME_RATE_HZ / every}
    recorder = None if fields is None else FieldRecorder(fields, info)
    t0 = time.perf_counter()
    report = detect_frames(_progress(simulated_frames(cfg, every), 60.0), cfg.meta(),
                           settings, every, on_event=_print_event, on_fields=recorder)
    if recorder is not None:
        recorder.flush()
    return _no_release_result(info, report, time.perf_counter() - t0)


def _no_release_result(info: dict[str, Any], report: dict[str, Any], wall_s: float
                       ) -> dict[str, Any]:
    per_frame = report.pop("per_frame")
    return {**info, "false_events": len(report["events"]), "triples": len(per_frame),
            "gas_triples": report["gas_frames"],
            "positive_triples": sum(p["positive"] for p in per_frame),
            "report": report, "wall_s": round(wall_s, 1)}


def replay_no_release(folder: Path, settings: DetectionSettings) -> dict[str, Any]:
    """The current event logic over a no-release recording of ``--fields`` (its scene time:
    the triples recorded, also of a run that was stopped)."""
    info = json.loads((folder / "info.json").read_text())
    t0 = time.perf_counter()
    fields = list(read_fields(folder))
    frames = fields[-1][1] + int(info["every"])
    report = detect_fields(iter(fields), frames, settings, on_event=_print_event)
    info = {**info, "minutes": round(frames / FIELD_FRAME_RATE_HZ / 60.0, 2),
            "replayed_from": str(folder)}
    return _no_release_result(info, report, time.perf_counter() - t0)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="what", required=True)
    s = sub.add_parser("schedule", help="detection delay of every release of a schedule")
    s.add_argument("--intervals", default="1:8,18:24",
                   help="ON:OFF[,ON:OFF...] in s within a period (default 1:8,18:24; leave "
                        "the end window, 6 s, plus a few s for the gas to clear between "
                        "releases, or two releases are one event)")
    s.add_argument("--period", type=float, default=30.0, help="schedule period, s (30)")
    s.add_argument("--cycles", type=int, default=1, help="periods to simulate (1)")
    s.add_argument("--voxel", type=float, default=0.06,
                   help="fluid voxel, m (0.06; the daemon's default 0.04 renders 3x slower)")
    n = sub.add_parser("no-release", help="false events in a no-release scene")
    n.add_argument("--minutes", type=float, default=30.0, help="scene time, min (30)")
    n.add_argument("--walker-s", type=float, default=20.0,
                   help="period of the warm person's walk to and fro, s (20: 0.3 m/s)")
    n.add_argument("--drift-s", type=float, default=600.0,
                   help="period of the background drift, s (600)")
    n.add_argument("--fields", type=Path,
                   help="record every triple's gas mask and flow in this new folder "
                        "(for `replay`)")
    r = sub.add_parser("replay", help="the event logic over a `no-release --fields` "
                                      "recording")
    r.add_argument("fields", type=Path, help="folder written by `no-release --fields`")
    for q in (s, n, r):
        if q is not r:
            q.add_argument("--every", type=int, default=10,
                           help="process every N-th triple (10: 3 results/s, the daemon's "
                                "rate on a 2-core machine)")
            q.add_argument("--seed", type=int, default=7)
        q.add_argument("--min-duration-s", type=float, default=EventConfig().min_duration_s,
                       help="events.min_duration_s (default the config's; the start "
                            "window is at least 1 s longer)")
        q.add_argument("--json", type=Path, help="write the result here")
    args = p.parse_args(argv)
    settings = DetectionSettings(events=EventConfig(
        min_duration_s=args.min_duration_s,
        start_window_s=max(EventConfig().start_window_s, args.min_duration_s + 1.0)))
    if args.what == "schedule":
        pairs = [[float(v) for v in part.split(":")] for part in args.intervals.split(",")]
        out = run_schedule(pairs, args.period, args.cycles, args.voxel, args.every, args.seed,
                           settings)
        for r in out["releases"]:
            delay = "missed" if r["delay_s"] is None else f"alarm after {r['delay_s']:.2f} s"
            print(f"release {r['on_s']:.1f}-{r['off_s']:.1f} s: {delay}")
        print(f"found {out['found']}/{len(out['releases'])}, false events "
              f"{out['false_events']}, max delay {out['max_delay_s']} s "
              f"({out['wall_s']} s wall)")
    else:
        out = (replay_no_release(args.fields, settings) if args.what == "replay" else
               run_no_release(args.minutes, args.walker_s, args.drift_s, args.every, args.seed,
                              settings, args.fields))
        print(f"{out['minutes']:g} min of no-release scene, {out['triples']} triples at "
              f"{out['processing_hz']:g} Hz: {out['false_events']} false events "
              f"({out['gas_triples']} triples with gas pixels, {out['positive_triples']} "
              f"positive; {out['wall_s']} s wall)")
        for e in out["report"]["events"]:
            print(f"  false event frames {e['start_frame']}-{e['end_frame']} source "
                  f"{e['source_xy']}")
    if args.json is not None:
        args.json.write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
