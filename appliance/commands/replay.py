"""``ogiflow replay``: run the scene-flow pipeline again over a recording.

Reads the raw frames of FILE.mcap (every frame of both cameras, with their original
timestamps), stamps and pairs them exactly as the live appliance does, runs the same
chain (:func:`processing.chain.compute_scene_flow`) on EVERY consecutive triple - nothing
is skipped offline - and writes a new MCAP file with the pairs, the per-frame summaries,
the wind (copied, and rotated into the camera frame at every pair) and the result fields.

The geometry and the chain parameters recorded in the file are used unless overridden:
``--param alpha=0.1`` (repeatable; any field of processing.chain.ChainParameters, value in
YAML syntax) changes a parameter, ``--calibration FILE`` the geometry. By default it runs
at the recorded pace (for watching with ``--live``); ``--fast`` runs as fast as possible.
A recording cut by a crash is processed up to the cut.
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import json
import shutil
import sys
import time
from pathlib import Path
from typing import Any

import yaml

from appliance.cli import CommandError


def register(root: argparse._SubParsersAction) -> None:
    p = root.add_parser("replay", help="reprocess a recording (same pipeline), write a new MCAP",
                        description=__doc__,
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("file", type=Path, metavar="FILE.mcap", help="recording to reprocess")
    p.add_argument("--out", type=Path, default=None,
                   help="output file (default: FILE-replay.mcap beside the input)")
    p.add_argument("--fast", action="store_true", help="as fast as possible (default: paced)")
    p.add_argument("--param", metavar="KEY=VALUE", action="append", default=[],
                   help="override one chain parameter (repeatable), e.g. --param alpha=0.1")
    p.add_argument("--calibration", type=Path, default=None,
                   help="stereo calibration file to use instead of the recorded geometry")
    p.add_argument("--fields-every", type=int, default=1, metavar="N",
                   help="record the full fields of every N-th result (default 1: all)")
    p.add_argument("--live", metavar="MODE", nargs="+", default=["off"],
                   help="also show it live: serve | connect URL | save FILE | off (default)")
    p.add_argument("--force", action="store_true", help="overwrite an existing output file")
    p.set_defaults(func=run)


def _geometry(meta: dict[str, dict[str, str]], calibration: Path | None) -> Any:
    from processing.calibration import load_calibration
    from processing.chain import StereoGeometry

    if calibration is not None:
        return StereoGeometry.from_calibration(load_calibration(calibration))
    cal_yaml = meta.get("calibration", {}).get("yaml", "")
    if cal_yaml.strip():
        import tempfile

        with tempfile.NamedTemporaryFile("w", suffix=".yaml", delete=False) as f:
            f.write(cal_yaml)
        try:
            return StereoGeometry.from_calibration(load_calibration(Path(f.name)))
        finally:
            Path(f.name).unlink()
    geo = meta.get("geometry", {}).get("json")
    if geo is None:
        raise ValueError("the recording carries no calibration or geometry; give --calibration")
    g = json.loads(geo)
    return StereoGeometry(camera_constant=float(g["camera_constant"]),
                          principal_point=tuple(g["principal_point"]),
                          baseline=float(g["baseline"]), image_size=tuple(g["image_size"]))


def _parameters(meta: dict[str, dict[str, str]], overrides: list[str]) -> Any:
    from processing.chain import ChainParameters

    values: dict[str, Any] = {}
    recorded = meta.get("processing", {}).get("json")
    if recorded is not None:
        values.update(json.loads(recorded))
    for text in overrides:
        key, sep, raw = text.partition("=")
        if not sep or not key.strip():
            raise ValueError(f"--param expects KEY=VALUE, got {text!r}")
        values[key.strip()] = yaml.safe_load(raw)
    names = {f.name for f in dataclasses.fields(ChainParameters)}
    return ChainParameters.from_mapping({k: v for k, v in values.items()
                                         if k in names or k in dict(_kv(overrides))})


def _kv(overrides: list[str]) -> list[tuple[str, str]]:
    return [(t.partition("=")[0].strip(), t.partition("=")[2]) for t in overrides]


def _recorded_config(meta: dict[str, dict[str, str]]) -> dict[str, Any]:
    text = meta.get("config", {}).get("yaml", "")
    return yaml.safe_load(text) or {} if text.strip() else {}


def _wind_history(path: Path, config: dict[str, Any], publisher: Any) -> Any:
    """Rebuild the wind history (camera frame) from the recorded raw samples; copy them."""
    from appliance.recording import schemas
    from appliance.recording.reader import iter_json
    from drivers.anemometer.base import AnemometerConfigError
    from drivers.anemometer.history import WindHistory
    from drivers.anemometer.mounting import CameraWind, Mounting

    anem = config.get("anemometer", {}) or {}
    try:
        mounting = Mounting.from_config(anem.get("protocol", "gill"), anem.get("mounting", {}))
    except AnemometerConfigError as exc:
        print(f"warning: recorded anemometer mounting unusable ({exc}); no wind in the camera "
              "frame", file=sys.stderr)
        mounting = None
    history = WindHistory()
    _reader, messages = iter_json(path, ["/wind/raw"])
    for _topic, m in messages:
        publisher.record_json("/wind/raw", schemas.WIND_SAMPLE, m, m["t_mono_ns"])
        if mounting is not None:
            vec = mounting.rotation @ [m["u"], m["v"], m["w"]]
            history.add(CameraWind(host_ns=m["t_mono_ns"], vector=vec, valid=bool(m["valid"]),
                                   vertical_measured=True))
    return history if mounting is not None and len(history) else None


def _wall_offset(path: Path) -> int:
    from appliance.recording.reader import iter_json

    _reader, messages = iter_json(path, ["/pairs", "/wind/raw"])
    for _topic, m in messages:
        return int(m["t_wall_ns"]) - int(m["t_mono_ns"])
    return 0


def run(args: argparse.Namespace) -> int:
    from appliance.config import RecordingConfig, live_overrides, load_config
    from appliance.recording.reader import read_metadata
    from appliance.recording.recorder import Recorder
    from appliance.runtime.publishing import ResultPublisher
    from appliance.runtime.stamping import StereoStamper
    from appliance.runtime.workers import WorkerResult, compute_scene_flow_on, pack_result
    from drivers.camera.mcap_format import FrameLogReader
    from processing.chain import ChainState

    src: Path = args.file
    if not src.is_file():
        raise ValueError(f"{src}: no such file")
    out = args.out or src.with_name(src.stem + "-replay.mcap")
    if out.exists() and not args.force:
        raise ValueError(f"{out} exists; use --force to overwrite")
    if args.fields_every < 1:
        raise ValueError(f"--fields-every must be >= 1, got {args.fields_every}")
    meta = read_metadata(src)
    geometry = _geometry(meta, args.calibration)
    params = _parameters(meta, args.param)
    config = _recorded_config(meta)
    fps = float(((config.get("cameras") or {}).get("left") or {}).get("frame_rate_hz", 30.0))
    tolerance = (config.get("pairing") or {}).get("tolerance_s")

    tmp = out.with_name(f".{out.name}.tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    rc = RecordingConfig(dir=tmp, rotate_mb=1e9, rotate_s=1e9, quota_gb=None,
                         queue_size=100_000, fields_every=args.fields_every)
    replay_meta = {"replay": {"source": str(src), "parameters": json.dumps(
        dataclasses.asdict(params), default=str)}}
    for name in ("config", "calibration", "geometry"):
        if name in meta:
            replay_meta[name] = meta[name]
    replay_meta["processing"] = {"json": replay_meta["replay"]["parameters"]}
    recorder = Recorder(rc, replay_meta).start()
    live = None
    if args.live != ["off"]:
        from appliance.live.view import LiveView

        live_cfg = load_config(None, live_overrides(args.live)).live
        live = LiveView(live_cfg).start()
    offset = _wall_offset(src)
    publisher = ResultPublisher(recorder, live, lambda t: int(t + offset), args.fields_every)
    history = _wind_history(src, config, publisher)
    if history is not None:
        publisher.wind_at = history.at

    stamper = StereoStamper(fps, tolerance)
    reader = FrameLogReader(src)
    state = ChainState()
    window: collections.deque[tuple[int, Any]] = collections.deque(maxlen=3)
    index = 0
    processed = failed = 0
    t_start = time.monotonic()
    t_first: int | None = None

    def handle(pair: Any) -> None:
        nonlocal index, processed, failed, t_first
        publisher.record_pair(index, pair)
        window.append((index, pair))
        index += 1
        if len(window) < 3:
            return
        if not args.fast:
            t_first = pair.time_ns if t_first is None else t_first
            ahead = (pair.time_ns - t_first) / 1e9 - (time.monotonic() - t_start)
            if ahead > 0:
                time.sleep(ahead)
        idx = [i for i, _ in window]
        pairs = [p for _, p in window]
        t_mono = tuple(p.time_ns for p in pairs)
        base = WorkerResult(worker=0, pair_indices=tuple(idx), t_mono_ns=t_mono,  # type: ignore[arg-type]
                            t_wall_ns=int(t_mono[1] + offset), skipped=0, done_mono_ns=0)
        import numpy as np

        left = np.stack([p.left.image for p in pairs]).astype(np.uint16, copy=False)
        right = np.stack([p.right.image for p in pairs]).astype(np.uint16, copy=False)
        try:
            res = compute_scene_flow_on(left, right, t_mono, geometry, params, state)
            pack_result(res, base)
            processed += 1
        except ValueError as exc:
            base.error = str(exc)
            failed += 1
            print(f"\npairs {idx}: {exc}", file=sys.stderr)
        publisher.publish(base)
        while recorder.stats().queue_depth > 1000:  # offline: wait for the writer, never drop
            time.sleep(0.01)
        if sys.stderr.isatty():
            sys.stderr.write(f"\rreplay: {index} pairs, {processed} processed")
            sys.stderr.flush()
        elif processed % 100 == 0:
            print(f"replay: {index} pairs, {processed} processed", file=sys.stderr)

    try:
        for side, frame in reader:
            for pair in stamper.push(side, frame, frame.host_ns):
                handle(pair)
        for pair in stamper.flush():
            handle(pair)
    finally:
        if sys.stderr.isatty():
            sys.stderr.write("\n")
        if live is not None:
            live.close()
        recorder.close(timeout=30.0)
    stats = recorder.stats()
    files = sorted(tmp.glob("ogiflow-*.mcap"))
    if len(files) != 1:
        raise CommandError(f"expected one output file in {tmp}, found {len(files)}")
    files[0].replace(out)
    shutil.rmtree(tmp, ignore_errors=True)
    unpaired = stamper.unpaired()
    print(f"replayed {src}: {index} pairs (unpaired frames left {unpaired['left']}, right "
          f"{unpaired['right']}), {processed} triples processed, {failed} failed -> {out}")
    if reader.truncated:
        print(f"warning: {src} ends early (cut by a crash?); processed everything up to the cut",
              file=sys.stderr)
    if stats.messages_dropped:
        raise CommandError(f"{stats.messages_dropped} output messages were dropped")
    return 0
