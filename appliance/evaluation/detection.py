"""Leak-event detection over recorded image sets (``ogiflow eval detection``).

Runs the chain and the event logic of the daemon (:mod:`appliance.runtime.events`) over
every image set under a folder and reports, per set, the frames, the frames with gas and the
events (first and last frame, times, source, confidence). Two kinds of set:

- a folder of consecutive single-camera frames (``*frame<N>.jpg``, like ``data/ogi``): the
  chain's first stages (differential images, flow, segmentation; no stereo, no rate);
- a sequence written by ``ogiflow simulate`` (``meta.json`` + frames): the whole stereo
  chain, with the simulator's ground truth of where gas is.

Frame times are ``N / fps``: gaps in the frame numbers are gaps in time, so the event logic
sees separate runs as separate stretches of time.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from appliance.evaluation.footage import FootageSettings, find_sets, iter_mono_triples
from appliance.runtime.events import EventConfig, EvidenceStream, FrameEvidence, LeakDetector


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
            events: EventConfig) -> dict[str, Any]:
    gas = sum(1 for e in evidence if e.gas_pixels >= events.min_gas_pixels)
    return {
        "frames": frames,
        "gas_frames": gas,
        "events": [{"start_frame": e.start_frame, "end_frame": e.end_frame,
                    "start_t_s": e.start_t_s, "end_t_s": e.end_t_s,
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


def detect_folder(name: str, frames: list[tuple[int, Path]], settings: DetectionSettings
                  ) -> dict[str, Any]:
    """Events in one single-camera set (folder of ``*frame<N>`` images)."""
    det = LeakDetector(settings.events)
    stream = EvidenceStream()
    evidence = []
    for tr in iter_mono_triples(name, frames, settings.footage):
        ev = stream(tr.frame / settings.fps, tr.frame, tr.mask, tr.flow)
        evidence.append(ev)
        det.update(ev)
    if evidence:
        det.close(evidence[-1].t_s, evidence[-1].frame, "end of data")
    return _report(len(frames), evidence, det, settings.events)


def detect_sequence(folder: Path, settings: DetectionSettings) -> dict[str, Any]:
    """Events in one synthetic stereo sequence (``ogiflow simulate``), whole chain."""
    from processing.chain import ChainParameters, ChainState, StereoGeometry, compute_scene_flow
    from processing.synthetic import read_frame, read_sequence_meta

    meta = read_sequence_meta(folder)
    geometry = StereoGeometry.from_synthetic_camera(meta["camera"])
    n = int(meta["n_frames"])
    det = LeakDetector(settings.events)
    stream = EvidenceStream()
    evidence: list[FrameEvidence] = []
    window: list[Any] = []
    params: ChainParameters | None = None
    state = ChainState()
    for k in range(n):
        window.append(read_frame(folder, k, meta))
        if params is None:
            params = _sequence_parameters(window[0], geometry)
        if len(window) < 3:
            continue
        trio, window = window, window[1:]
        res = compute_scene_flow([f.left for f in trio], [f.right for f in trio],
                                 [f.t_s for f in trio], geometry, params, state)
        ev = stream(trio[0].t_s, trio[0].index, res.gas_mask, res.flow)
        evidence.append(ev)
        det.update(ev)
    if evidence:
        det.close(evidence[-1].t_s, evidence[-1].frame, "end of data")
    return _report(n, evidence, det, settings.events)


def _sequence_parameters(first: Any, geometry: Any) -> Any:
    """Chain parameters of a synthetic sequence: the site's d0 (disparity of twice the gas
    distance, as the simulated appliance configures it), no registration (ideal cameras)."""
    from processing.chain import ChainParameters

    z = np.asarray(first.gt_position)[..., 2][np.asarray(first.gt_mask, bool)]
    z = z[np.isfinite(z)]
    if z.size == 0:
        return ChainParameters(register=False)
    d0 = geometry.camera_constant * geometry.baseline / (2.0 * float(np.median(z)))
    return ChainParameters(register=False, d0=d0)


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


def frames_in_events(report: dict[str, Any]) -> np.ndarray:
    """Frame numbers covered by the set's events (for per-frame scoring)."""
    covered: list[int] = []
    for e in report["events"]:
        covered.extend(range(e["start_frame"], (e["end_frame"] or e["start_frame"]) + 1))
    return np.asarray(sorted(set(covered)), dtype=int)
