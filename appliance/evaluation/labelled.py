"""Scoring a set's events against its ``labels.json`` (known release classes and source box).

A labelled set (the GasVid videos of ``data/ogi/gasvid``) holds ``labels.json``: the frame
interval, the no-release seconds, release classes (``class``, ``start_s``, ``end_s``,
``rate_g_h``) and the labelled source box ``source_box_xywh`` (px). Scored per class, over
its settled part (``start_s + SETTLE_S`` to ``end_s``: the valve steps take a few seconds):

- *windows alarmed*: of the 10-s windows (those with at least half their frames processed:
  a clip holds part of a class), those in which an alarmed event is open (from its alarm to
  its end);
- *first alarm*: seconds from the class start to the first frame with an alarmed event open
  (0: an event open from the class before);
- *source error*: distance of the open event's source (its running median) from the box
  centre, median over the class's frames, px;
- *apparent size*: median, over the frames with an event open, of the plume's integrated
  temporal contrast (:func:`apparent_size`).

An event is false when its alarm comes before the first visible class (class 1) has been on
for ``SETTLE_S``: class 0 (5.3 g/h) is far below what an OGI camera sees at these distances.
The Spearman rank correlation of the apparent size with the rate is over classes 1-7.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from appliance.runtime.occupancy import CELL_PX

#: Seconds after a class change left out of its figures (the valve's step).
SETTLE_S = 15.0

#: Length of the windows of "windows alarmed", s.
WINDOW_S = 10.0

#: First class counted as a visible leak.
FIRST_VISIBLE_CLASS = 1


@dataclass(frozen=True)
class FrameState:
    """What the evaluation records of one frame: time, the open event (alarmed) and its
    running source, and the apparent size of the gas (None: not measured)."""

    frame: int
    t_s: float
    event_id: int | None
    source_xy: tuple[float, float] | None
    size: float | None


def load_labels(folder: Path) -> dict[str, Any] | None:
    """The set's ``labels.json``, or None when it has none.

    Raises
    ------
    ValueError
        The file is not JSON or lacks ``classes`` or ``frame_interval_s``.
    """
    path = folder / "labels.json"
    if not path.is_file():
        return None
    try:
        labels = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not JSON ({exc})") from exc
    if not isinstance(labels, dict) or "classes" not in labels or not (
            float(labels.get("frame_interval_s", 0)) > 0):
        raise ValueError(f"{path}: needs 'classes' and a positive 'frame_interval_s'")
    return labels


def apparent_size(raw: np.ndarray, previous: np.ndarray | None, occupancy: np.ndarray | None,
                  threshold: float) -> float | None:
    """Integrated temporal contrast of the gas: the sum of |raw - previous| (counts) over the
    pixels of the occupancy cells at or above ``threshold``, counts px.

    The persistent region rather than one frame's mask: the segmentation drops frames when a
    plume fills the view, the region stays; the raw frames rather than the differential
    images, which the normalisation clips at a few counts.
    """

    if previous is None or occupancy is None or previous.shape != raw.shape:
        return None
    region = np.kron(occupancy >= threshold, np.ones((CELL_PX, CELL_PX), bool))
    region = region[:raw.shape[0], :raw.shape[1]]
    diff = np.abs(raw.astype(np.float64) - previous.astype(np.float64))
    return float(diff[region].sum())


def _spearman(x: list[float], y: list[float]) -> float | None:
    # scipy.stats costs seconds to import; only labelled sets need it.
    from scipy.stats import spearmanr

    if len(x) < 3 or len(set(y)) < 2:
        return None
    return float(spearmanr(x, y).statistic)


def score_labelled(report: dict[str, Any], states: list[FrameState],
                   evidence_at_alarm: dict[int, str], labels: dict[str, Any]
                   ) -> dict[str, Any]:
    """Per-class figures and false events of one labelled set (module docstring).

    Parameters
    ----------
    report : dict
        The set's report (its ``events`` with ``alarm_t_s``).
    states : list of FrameState
        Every processed frame, in time order.
    evidence_at_alarm : dict
        Per event id, what the evidence said at its alarm (why it started).
    """
    bx, by, bw, bh = (float(v) for v in labels["source_box_xywh"])
    centre = (bx + 0.5 * bw, by + 0.5 * bh)
    classes = sorted(labels["classes"], key=lambda c: c["start_s"])
    visible = [c for c in classes if c["class"] >= FIRST_VISIBLE_CLASS]
    false_before = visible[0]["start_s"] + SETTLE_S if visible else np.inf
    events = report["events"]
    t = np.array([s.t_s for s in states])
    false = [{"alarm_t_s": e["alarm_t_s"], "start_t_s": e["start_t_s"], "end_t_s": e["end_t_s"],
              "source_xy": e["source_xy"],
              "why": evidence_at_alarm.get(i + 1, "")}
             for i, e in enumerate(events) if e["alarm_t_s"] is not None
             and e["alarm_t_s"] < false_before]
    rows = []
    for c in classes:
        a, b = float(c["start_s"]) + SETTLE_S, float(c["end_s"])
        # windows with at least half their frames processed (a clip holds part of a class)
        need = 0.5 * WINDOW_S / float(labels["frame_interval_s"])
        starts = [a + k * WINDOW_S for k in range(int((b - a) // WINDOW_S))]
        starts = [w for w in starts if np.count_nonzero((t >= w) & (t < w + WINDOW_S)) >= need]
        n_windows = len(starts)
        alarmed = sum(
            any(e["alarm_t_s"] is not None and e["alarm_t_s"] < w + WINDOW_S
                and (e["end_t_s"] is None or e["end_t_s"] >= w) for e in events)
            for w in starts)
        in_class = [s for s in states if c["start_s"] <= s.t_s < b]
        first = next((s.t_s - c["start_s"] for s in in_class if s.event_id is not None), None)
        settled = [s for s in in_class if s.t_s >= a and s.event_id is not None]
        errors = [float(np.hypot(s.source_xy[0] - centre[0], s.source_xy[1] - centre[1]))
                  for s in settled if s.source_xy is not None]
        sizes = [s.size for s in settled if s.size is not None]
        rows.append({
            "class": int(c["class"]), "rate_g_h": float(c["rate_g_h"]),
            "start_s": c["start_s"], "end_s": c["end_s"], "windows": n_windows,
            "windows_alarmed": int(alarmed),
            "alarmed_pct": round(100.0 * alarmed / n_windows, 1) if n_windows else None,
            "first_alarm_after_s": first,
            "source_error_px": round(float(np.median(errors)), 1) if errors else None,
            "apparent_size": float(np.median(sizes)) if sizes else None,
        })
    ranked = [r for r in rows if r["class"] >= FIRST_VISIBLE_CLASS
              and r["apparent_size"] is not None]
    event_errors = [round(float(np.hypot(e["source_xy"][0] - centre[0],
                                         e["source_xy"][1] - centre[1])), 1)
                    for e in events if e["source_xy"] is not None
                    and e["alarm_t_s"] is not None and e["alarm_t_s"] >= false_before]
    return {
        "distance_m": labels.get("distance_m"),
        "source_box_centre_xy": list(centre),
        "frames_processed": len(states),
        "false_events": false,
        "event_source_error_px": event_errors,
        "classes": rows,
        "size_rate_spearman": _spearman([r["rate_g_h"] for r in ranked],
                                        [r["apparent_size"] for r in ranked]),
    }


def format_labelled(name: str, scored: dict[str, Any]) -> list[str]:
    """The stdout table of one labelled set."""
    out = [f"{name}: {scored['distance_m']} m, false events {len(scored['false_events'])}, "
           f"event source error {scored['event_source_error_px']} px, apparent size vs rate "
           f"Spearman {_fmt(scored['size_rate_spearman'], '.3f')}",
           f"  {'class':>5} {'g/h':>7} {'windows alarmed':>16} {'first alarm s':>13} "
           f"{'source err px':>13} {'apparent size':>13}"]
    for r in scored["classes"]:
        win = f"{r['windows_alarmed']}/{r['windows']} {_fmt(r['alarmed_pct'], '.0f')} %"
        out.append(f"  {r['class']:>5} {r['rate_g_h']:>7.1f} {win:>16} "
                   f"{_fmt(r['first_alarm_after_s'], '.0f'):>13} "
                   f"{_fmt(r['source_error_px'], '.1f'):>13} "
                   f"{_fmt(r['apparent_size'], '.3g'):>13}")
    for f in scored["false_events"]:
        out.append(f"  false event: alarm at {f['alarm_t_s']:.0f} s, {f['why']}")
    return out


def _fmt(v: float | None, spec: str) -> str:
    return "-" if v is None else format(v, spec)
