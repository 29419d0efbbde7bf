"""Leak-event detection over recorded image sets (``ogiflow eval detection``).

Runs the chain and the event logic of the daemon (:mod:`appliance.runtime.events`) over
every image set under a folder and reports, per set, the frames, the frames with gas and the
events (first and last frame, times, source, confidence). Two kinds of set:

- a folder of consecutive single-camera frames (``*frame<N>.jpg``, like ``data/ogi``): the
  chain's first stages (differential images, flow, segmentation; no stereo, no rate);
- a sequence written by ``ogiflow simulate`` (``meta.json`` + frames): the whole stereo
  chain, with the simulator's ground truth of where gas is.

Frame times are ``N / fps`` (or ``N`` times the ``frame_interval_s`` of a set's
``labels.json``): gaps in the frame numbers are gaps in time, so the event logic sees
separate runs as separate stretches of time. The frame interval also tells the evidence
whether the flow can follow the gas (:data:`appliance.runtime.evidence.FLOW_MAX_INTERVAL_S`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from appliance.evaluation.footage import FootageSettings, find_sets, iter_mono_triples
from appliance.evaluation.labelled import FrameState, apparent_size, load_labels, score_labelled
from appliance.runtime.events import (
    EventConfig,
    EvidenceStream,
    FrameEvidence,
    LeakDetector,
    zone_mask,
)
from appliance.runtime.occupancy import REGION_OCCUPANCY
from processing.chain.driver import ChainParameters, ChainState, StereoGeometry, compute_scene_flow
from processing.synthetic import read_frame, read_sequence_meta
from processing.synthetic.sequences import SyntheticStereoScene


@dataclass(frozen=True)
class DetectionSettings:
    """Settings of one detection evaluation.

    Attributes
    ----------
    fps : float
        Frame rate of folder sets (synthetic sequences carry their own frame interval).
    events : EventConfig
        The event logic's thresholds.
    footage : FootageSettings
        Pre-processing of single-camera sets.
    """

    fps: float = 30.0
    events: EventConfig = field(default_factory=EventConfig)
    footage: FootageSettings = field(default_factory=FootageSettings)


def _report(frames: int, evidence: list[FrameEvidence], det: LeakDetector,
            events: EventConfig, alarms: dict[int, tuple[float, int]] | None = None
            ) -> dict[str, Any]:
    gas = sum(1 for e in evidence if e.gas_pixels >= events.min_gas_pixels)
    alarms = alarms or {}
    return {
        "frames": frames,
        "gas_frames": gas,
        "events": [{"start_frame": e.start_frame, "end_frame": e.end_frame,
                    "start_t_s": e.start_t_s, "end_t_s": e.end_t_s,
                    # when the logic said "leak" (the start is back-dated to the first
                    # positive frame): the alarm's delay
                    "alarm_t_s": alarms.get(e.id, (None, None))[0],
                    "alarm_frame": alarms.get(e.id, (None, None))[1],
                    "end_reason": e.end_reason, "source_xy": e.source_xy,
                    "mean_rate_g_s": e.mean_rate_g_s, "confidence": round(e.confidence, 3)}
                   for e in det.finished],
        "per_frame": [{"frame": e.frame, "gas_pixels": e.gas_pixels,
                       "coherence": round(e.coherence, 3), "source_xy": e.source_xy,
                       "positive": p}
                      for e, p in zip(evidence, _positives(evidence, events), strict=True)],
    }


def _positives(evidence: list[FrameEvidence], events: EventConfig) -> list[bool]:
    probe = LeakDetector(events)
    out = []
    for e in evidence:
        out.append(probe.positive(e))
        probe.update(e)
    return out


def _zones(shape: tuple[int, int], events: EventConfig) -> np.ndarray | None:
    """The watched pixels of the config's zones, as the daemon's monitor builds them."""
    if not events.watch_zones and not events.ignore_zones:
        return None
    return zone_mask(shape, events.watch_zones, events.ignore_zones)


def _feed(det: LeakDetector, ev: FrameEvidence, alarms: dict[int, tuple[float, int]],
          on_event: Callable[[str, Any], None] | None = None) -> None:
    for kind, event in det.update(ev):
        if kind == "start":
            alarms[event.id] = (ev.t_s, ev.frame)
        if on_event is not None and kind != "update":
            on_event(kind, event)


def detect_folder(name: str, frames: list[tuple[int, Path]], settings: DetectionSettings
                  ) -> dict[str, Any]:
    """Events in one single-camera set (folder of ``*frame<N>`` images).

    A set with a ``labels.json`` (:mod:`appliance.evaluation.labelled`) takes its frame
    interval from there instead of ``settings.fps`` and is scored against its labels (key
    ``labelled`` of the report).
    """

    labels = load_labels(frames[0][1].parent) if frames else None
    interval = float(labels["frame_interval_s"]) if labels else 1.0 / settings.fps
    det = LeakDetector(settings.events)
    stream: EvidenceStream | None = None
    evidence = []
    alarms: dict[int, tuple[float, int]] = {}
    states: list[FrameState] = []
    why: dict[int, str] = {}
    previous: tuple[int, np.ndarray] | None = None
    for tr in iter_mono_triples(name, frames, settings.footage):
        stream = stream or EvidenceStream(_zones(tr.mask.shape, settings.events),
                                          frame_interval_s=interval)
        ev = stream(tr.frame * interval, tr.frame, tr.mask, tr.flow)
        evidence.append(ev)
        known = set(alarms)
        _feed(det, ev, alarms)
        for new in set(alarms) - known:
            why[new] = _why(ev)
        cur = det.current
        prev = previous[1] if previous is not None and previous[0] == tr.frame - 1 else None
        states.append(FrameState(tr.frame, ev.t_s, None if cur is None else cur.id,
                                 None if cur is None else cur.source_xy,
                                 apparent_size(tr.raw, prev, ev.occupancy, REGION_OCCUPANCY)))
        previous = (tr.frame, tr.raw)
    if evidence:
        det.close(evidence[-1].t_s, evidence[-1].frame, "end of data")
    report = _report(len(frames), evidence, det, settings.events, alarms)
    if labels is not None:
        report["labelled"] = score_labelled(report, states, why, labels)
    return report


def _why(ev: FrameEvidence) -> str:
    """What the evidence said when an event was alarmed (reports of false events)."""
    src = "none" if ev.source_xy is None else f"({ev.source_xy[0]:.0f}, {ev.source_xy[1]:.0f})"
    if ev.occupancy is not None:
        return (f"persistent region {ev.plume_px} px, apex {src}, peak occupancy "
                f"{float(ev.occupancy.max()):.2f}")
    return f"{ev.gas_pixels} gas px, coherence {ev.coherence:.2f}, source {src}"


def detect_sequence(folder: Path, settings: DetectionSettings) -> dict[str, Any]:
    """Events in one synthetic stereo sequence (``ogiflow simulate``), whole chain."""

    meta = read_sequence_meta(folder)
    n = int(meta["n_frames"])
    return detect_frames((read_frame(folder, k, meta) for k in range(n)), meta, settings)


def detect_frames(frames: Iterable[Any], meta: dict[str, Any], settings: DetectionSettings,
                  every: int = 1, on_event: Callable[[str, Any], None] | None = None,
                  on_fields: Callable[[float, int, np.ndarray, np.ndarray], None] | None = None
                  ) -> dict[str, Any]:
    """Events in a stream of synthetic stereo frames (``SyntheticFrame``), whole chain.

    Parameters
    ----------
    frames : iterable of SyntheticFrame
        Consecutive frames of one sequence (read from disk or rendered on the fly).
    meta : dict
        The sequence's ``meta.json`` object (camera, background, simulation volume).
    every : int
        Process the triple starting at every ``every``-th frame only, as a daemon that
        keeps up at ``frame rate / every`` does (the event logic's windows are in seconds).
    on_event : callable, optional
        ``(kind, LeakEvent)`` at every start and end, as it happens (long runs).
    on_fields : callable, optional
        ``(t_s, frame, gas_mask, flow)`` of every processed triple: what the event logic
        sees, to replay it later with other rules (:func:`detect_fields`).
    """

    if every < 1:
        raise ValueError(f"every must be >= 1, got {every}")
    geometry = StereoGeometry.from_synthetic_camera(meta["camera"])
    params = sequence_parameters(meta, geometry)
    det = LeakDetector(settings.events)
    cam = meta["camera"]
    stream = EvidenceStream(_zones((int(cam["height"]), int(cam["width"])), settings.events))
    evidence: list[FrameEvidence] = []
    alarms: dict[int, tuple[float, int]] = {}
    window: list[Any] = []
    state = ChainState()
    n = 0
    for frame in frames:
        n += 1
        window = [*window[-2:], frame]
        if len(window) < 3 or window[0].index % every:
            continue
        res = compute_scene_flow([f.left for f in window], [f.right for f in window],
                                 [f.t_s for f in window], geometry, params, state)
        if on_fields is not None:
            on_fields(window[0].t_s, window[0].index, res.gas_mask, res.flow)
        ev = stream(window[0].t_s, window[0].index, res.gas_mask, res.flow)
        evidence.append(ev)
        _feed(det, ev, alarms, on_event)
    if evidence:
        det.close(evidence[-1].t_s, evidence[-1].frame, "end of data")
    return _report(n, evidence, det, settings.events, alarms)


def detect_fields(fields: Iterable[tuple[float, int, np.ndarray, np.ndarray]], frames: int,
                  settings: DetectionSettings,
                  on_event: Callable[[str, Any], None] | None = None) -> dict[str, Any]:
    """Events from recorded per-triple ``(t_s, frame, gas_mask, flow)`` (what
    :func:`detect_frames` hands ``on_fields``): the event logic alone, replayed over the
    chain's output of an earlier run (the chain does not depend on the event rules)."""
    det = LeakDetector(settings.events)
    stream: EvidenceStream | None = None
    evidence: list[FrameEvidence] = []
    alarms: dict[int, tuple[float, int]] = {}
    for t_s, frame, mask, flow in fields:
        stream = stream or EvidenceStream(_zones(mask.shape, settings.events))
        ev = stream(t_s, frame, mask, flow)
        evidence.append(ev)
        _feed(det, ev, alarms, on_event)
    if evidence:
        det.close(evidence[-1].t_s, evidence[-1].frame, "end of data")
    return _report(frames, evidence, det, settings.events, alarms)


def sequence_parameters(meta: dict[str, Any], geometry: Any) -> Any:
    """Chain parameters of a synthetic sequence, as the simulated appliance configures them:
    d0 = the disparity of twice the distance of the simulated volume's centre, and
    registration only on a textured background (a uniform one gives it nothing to lock on
    but the gas)."""

    sim = meta.get("simulation", {})
    origin = sim.get("volume_origin_m")
    grid = sim.get("grid_zyx")
    register = meta.get("background", {}).get("kind", "uniform") != "uniform"
    if not origin or not grid:
        return ChainParameters(register=register)
    z = float(origin[2]) + 0.5 * float(grid[0]) * float(sim["voxel_m"])
    d0 = geometry.camera_constant * geometry.baseline / (2.0 * z)
    return ChainParameters(register=register, d0=d0)


def evaluate_detection(data: Path, settings: DetectionSettings) -> dict[str, dict[str, Any]]:
    """Every image set under ``data``: synthetic sequences (``meta.json``) and folders of
    ``*frame<N>`` images; ``data`` itself may be one sequence.

    Raises
    ------
    ValueError
        ``data`` holds no set.
    """
    if not data.is_dir():
        raise ValueError(f"--data {data} is not a directory")
    if (data / "meta.json").is_file():
        return {data.name: detect_sequence(data, settings)}
    out: dict[str, dict[str, Any]] = {}
    sequences = sorted(p for p in data.iterdir() if (p / "meta.json").is_file())
    for seq in sequences:
        out[seq.name] = detect_sequence(seq, settings)
    try:
        folder_sets = find_sets(data)
    except ValueError:
        folder_sets = {}
    for name, frames in folder_sets.items():
        if name not in out:
            out[name] = detect_folder(name, frames, settings)
    if not out:
        raise ValueError(f"no image sets (simulated sequences or *frame<N> folders) in {data}")
    return out


def simulated_frames(config: Any, every: int = 1) -> Iterator[Any]:
    """Frames of a synthetic sequence rendered on the fly, for :func:`detect_frames`.

    The fluid advances through every frame (the gas must move as it does), but only the
    frames of the processed triples (``index % every`` in 0, 1, 2) are rendered into
    camera images; nothing is written to disk, so hours of scene cost no space.
    """

    scene = SyntheticStereoScene(config)
    for k in range(config.n_frames):
        gas = scene.next_gas()
        if k % every < 3:
            yield scene.renderer.render(gas)


def score_releases(report: dict[str, Any], releases: list[tuple[float, float]],
                   hold_s: float) -> dict[str, Any]:
    """Match a set's events to the true releases of a schedule.

    A release (on_s, off_s) is found by the first event whose alarm falls in
    ``[on_s, off_s + hold_s]`` (gas released last keeps drifting through the view for a
    while); its delay is alarm time - on_s. Events matching no release are false events.

    Returns
    -------
    dict with ``releases`` (per release: on_s, off_s, found, delay_s), ``found``,
    ``false_events`` and ``max_delay_s`` (None when nothing was found).
    """
    used: set[int] = set()
    rows = []
    for on, off in releases:
        hit = next((i for i, e in enumerate(report["events"]) if i not in used
                    and e["alarm_t_s"] is not None and on <= e["alarm_t_s"] <= off + hold_s),
                   None)
        if hit is not None:
            used.add(hit)
        delay = None if hit is None else report["events"][hit]["alarm_t_s"] - on
        rows.append({"on_s": on, "off_s": off, "found": hit is not None, "delay_s": delay})
    delays = [r["delay_s"] for r in rows if r["delay_s"] is not None]
    return {"releases": rows, "found": sum(r["found"] for r in rows),
            "false_events": len(report["events"]) - len(used),
            "max_delay_s": max(delays) if delays else None}
