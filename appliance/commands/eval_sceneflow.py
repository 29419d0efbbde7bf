"""``ogiflow eval sceneflow``: 3D gas velocity accuracy on synthetic sequences (paper Table 3).

For every sequence (``ogiflow-synthetic/1``, written by ``ogiflow simulate``) and every
consecutive raw triple (i, i+1, i+2) of it, three methods compute the 3D velocity V of the
left view from the same pre-processed differential images:

- ``proposed``: the whole chain, :func:`processing.chain.compute_scene_flow` (Brox flow,
  joint d and d' of Eq. 6, Eq. 4, segmentation of Eq. 9);
- ``sgm_brox`` and ``sgm_farneback``: the decoupled baselines of
  :mod:`processing.baselines` on the chain's four normalised differential images, turned
  into V by the same Eq. 4 (:func:`processing.velocity.scene_flow_velocity`) with the same
  dt.

All three are scored over the chain's segmented gas region (the baselines have no
segmentation of their own, and one region keeps the comparison about velocity) against
the triplet's reference V* (:func:`processing.synthetic.reference.triplet_reference`)
with the metrics of :mod:`processing.sceneflow_metrics` (Sec. 5.1, Eq. 10). RMVE and AEMV
are given as mean and standard deviation over the frames, the other metrics as means.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

from appliance import cli

#: Default folder of the sequences: where the README's ``ogiflow simulate --out synthetic``
#: writes them (relative to the working directory). Generated data, so not under ``data/``,
#: which holds real reference recordings with provenance.
DEFAULT_DATA = Path("synthetic")

METHODS = ("proposed", "sgm_brox", "sgm_farneback")
METHOD_LABELS = {"proposed": "Proposed", "sgm_brox": "SGM+Brox", "sgm_farneback": "SGM+Fbck"}

#: The paper's Table 3, keyed by our Table-2 preset names (S1, S2, S3).
PAPER_TABLE3: dict[str, dict[str, dict[str, Any]]] = {
    "table2_1": {
        "proposed": {"rmve": 6.56, "rmve_std": 5.65, "aemv": 12.20, "aemv_std": 5.41,
                     "aee_3d_mm_s": 72.00, "aae_3d_deg": 33.79, "c_usf": 0.92, "sa": 58.31,
                     "r_sf": [0.68, 0.79, 0.73]},
        "sgm_brox": {"rmve": 16.06, "rmve_std": 5.51},
        "sgm_farneback": {"rmve": 36.07, "rmve_std": 2.37},
    },
    "table2_2": {
        "proposed": {"rmve": 15.35, "rmve_std": 4.52, "aemv": 11.61, "aemv_std": 5.98,
                     "aee_3d_mm_s": 66.78, "aae_3d_deg": 30.84, "c_usf": 0.91, "sa": 67.57,
                     "r_sf": [0.56, 0.74, 0.56]},
        "sgm_brox": {"rmve": 35.31, "rmve_std": 8.05},
        "sgm_farneback": {"rmve": 46.74, "rmve_std": 6.25},
    },
    "table2_3": {
        "proposed": {"rmve": 9.60, "rmve_std": 4.30, "aemv": 11.59, "aemv_std": 5.35,
                     "aee_3d_mm_s": 72.43, "aae_3d_deg": 34.09, "c_usf": 0.90, "sa": 71.40,
                     "r_sf": [0.44, 0.73, 1.00]},
        "sgm_brox": {"rmve": 47.10, "rmve_std": 14.70},
        "sgm_farneback": {"rmve": 65.81, "rmve_std": 9.30},
    },
}


def register(root: argparse._SubParsersAction) -> None:
    """Add ``eval sceneflow`` to the ``eval`` group."""
    group = cli.command_group(root, "eval", "evaluate the processing against reference data")
    p = group.add_parser(
        "sceneflow",
        help="3D velocity accuracy of the chain and two baselines on synthetic sequences "
             "(paper Table 3)",
        description=(
            "Run the scene-flow chain (proposed method) and the SGM+Brox and SGM+Farneback "
            "baselines on every consecutive triple of every synthetic sequence in --data and "
            "compare with the ground truth: RMVE (relative error of the mean velocity's "
            "magnitude, %) and AEMV (angle of the mean velocity, deg) as mean +- std over "
            "the frames; 3D AEE (mm/s) and 3D AAE (deg, with Eq. 10's |V*.V|) over the gas "
            "region; c_USF (Eq. 8); SA (segmented / reference gas area, %); histogram "
            "correlations r_SF of V_X, V_Y, V_Z. Printed beside the paper's Table 3. "
            "Ideal conditions as in the paper: no registration, ideal rectified cameras."
        ),
        epilog="example: ogiflow simulate --out synthetic && ogiflow eval sceneflow "
               "--json table3.json --figures figures/",
    )
    p.add_argument("--data", type=Path, default=DEFAULT_DATA,
                   help=f"folder holding sequence directories (default {DEFAULT_DATA}), or one "
                        "sequence directory")
    p.add_argument("--json", type=Path, metavar="OUT",
                   help='write {"<sequence>": {"<method>": {"rmve": .., ...}}} to this file')
    p.add_argument("--figures", type=Path, metavar="DIR",
                   help="write PNG figures: mean velocity per frame (computed vs reference) "
                        "and the velocity fields of one frame, per sequence")
    p.add_argument("--disparity-init", choices=("sgm", "d0"), default="sgm",
                   help="initial disparity of the joint solver: an SGM estimate (default) or "
                        "the constant minimum disparity --d0 (with the solver's default "
                        "iterations, a start ~17 px short leaves a d' bias of ~0.09 px, "
                        "i.e. V_Z errors of ~2 m/s at 1 ms frames; see README)")
    p.add_argument("--d0", type=float, default=60.0,
                   help="minimum disparity in px for the farthest expected gas, s*b/Z_max "
                        "(default 60 = 780 px * 0.2 m / 2.6 m): start of the SGM search "
                        "range, fill value of its holes")
    p.add_argument("--sgm-range", type=int, default=64,
                   help="width N of the SGM search range [d0, d0 + N) in px, multiple of 16, "
                        "for the chain's initialisation and the baselines (default 64: gas "
                        "between s*b/(d0 + 64) = 1.26 m and 2.6 m)")
    p.add_argument("--frames", type=int, metavar="N",
                   help="evaluate only the first N triples of each sequence")
    p.set_defaults(func=run)


# ---------------------------------------------------------------------------- evaluation


def chain_parameters(disparity_init: str, d0: float, sgm_range: int) -> Any:
    """The chain's parameters for synthetic data under the paper's ideal conditions."""
    from processing.chain import ChainParameters

    # register=False: the registration estimates camera jitter on the static background.
    # The synthetic background is featureless (uniform black body) and there is no jitter,
    # so the only texture it could lock onto is the gas itself, whose motion it would then
    # cancel; the chain also refuses shifts above max_jitter_px, but shifts below that
    # would still be wrong. The paper's Sec. 5.1 conditions have no jitter to remove.
    return ChainParameters(register=False, disparity_init=disparity_init, d0=d0,
                           sgm_num_disparities=sgm_range)


def _geometry(meta: dict[str, Any]) -> Any:
    from processing.chain import StereoGeometry

    try:
        return StereoGeometry.from_synthetic_camera(meta["camera"])
    except ValueError as exc:
        raise ValueError(f"sequence {meta['name']!r}: {exc}") from None


def frame_metrics(velocity: Any, valid: Any, gas_mask: Any, u_sf: Any, u_sf_valid: Any,
                  reference: Any, reference_mask: Any) -> dict[str, Any]:
    """All per-frame metrics of one method (see :mod:`processing.sceneflow_metrics`).

    ``velocity``/``valid`` are the method's V and validity, ``gas_mask`` the segmented
    region, ``reference``/``reference_mask`` V* and the reference gas mask. Undefined
    values are None.
    """
    import numpy as np

    from processing import sceneflow_metrics as sm
    from processing.quality import c_usf

    region = gas_mask & valid
    ref_clean = np.where(reference_mask[..., None], reference, 0.0)
    v_avg = sm.mean_velocity(velocity, region)
    v_ref = sm.mean_velocity(ref_clean, reference_mask)
    both = region & reference_mask
    aee = sm.aee_3d(ref_clean, velocity, both)
    # Eq. 10 averages V and V* over different regions (segmented vs reference), so RMVE
    # mixes velocity error with segmentation mismatch; the same two metrics over the
    # common pixels isolate the velocity error (not in the paper; for the analysis).
    v_avg_c = sm.mean_velocity(velocity, both)
    v_ref_c = sm.mean_velocity(ref_clean, both)
    return {
        "rmve": sm.rmve(v_ref, v_avg),
        "aemv": sm.aemv(v_ref, v_avg),
        "rmve_common": sm.rmve(v_ref_c, v_avg_c),
        "aemv_common": sm.aemv(v_ref_c, v_avg_c),
        "aee_3d_mm_s": None if aee is None else 1e3 * aee,
        "aae_3d_deg": sm.aae_3d(ref_clean, velocity, both),
        "c_usf": c_usf(u_sf, gas_mask, valid & u_sf_valid),
        "sa": sm.segmentation_ratio(gas_mask, reference_mask),
        "sa_overlap": sm.segmentation_overlap(gas_mask, reference_mask),
        "r_sf": list(sm.histogram_correlations(ref_clean, reference_mask, velocity, region)),
        "mean_velocity": None if v_avg is None else [float(x) for x in v_avg],
        "reference_mean_velocity": None if v_ref is None else [float(x) for x in v_ref],
        "pixels": int(region.sum()),
    }


def _mean_std(values: list[float | None]) -> tuple[float | None, float | None, int]:
    import numpy as np

    vals = [v for v in values if v is not None]
    if not vals:
        return None, None, len(values)
    arr = np.asarray(vals, dtype=np.float64)
    return float(arr.mean()), float(arr.std()), len(values) - len(vals)


def aggregate(frames: list[dict[str, Any]]) -> dict[str, Any]:
    """Sequence summary of one method from its per-frame metrics (None where undefined).

    ``undefined`` counts, per metric, the frames where it was undefined (left out of the
    mean); a metric undefined in every frame is None.
    """
    out: dict[str, Any] = {"n_frames": len(frames)}
    undefined: dict[str, int] = {}
    for key in ("rmve", "aemv", "rmve_common", "aemv_common", "aee_3d_mm_s", "aae_3d_deg",
                "c_usf", "sa", "sa_overlap"):
        mean, std, n_undef = _mean_std([f[key] for f in frames])
        out[key] = mean
        if key in ("rmve", "aemv", "rmve_common", "aemv_common"):
            out[key + "_std"] = std
        if n_undef:
            undefined[key] = n_undef
    r = []
    for c, axis in enumerate("XYZ"):
        mean, _, n_undef = _mean_std([f["r_sf"][c] for f in frames])
        r.append(mean)
        if n_undef:
            undefined[f"r_sf_{axis}"] = n_undef
    out["r_sf"] = r
    out["undefined"] = undefined
    out["frames"] = frames
    return out


def _baseline_velocity(kind: str, res: Any, geometry: Any, params: Any) -> Any:
    from processing.baselines import sgm_brox, sgm_farneback
    from processing.quality import scene_flow_energy
    from processing.velocity import scene_flow_velocity

    il0, il1 = res.diff_left
    ir0, ir1 = res.diff_right
    fn = sgm_brox if kind == "sgm_brox" else sgm_farneback
    # The same search range as the chain's SGM initialisation: [d0, d0 + N).
    b = fn(il0, ir0, il1, ir1, min_disparity=math.floor(params.d0),
           num_disparities=params.sgm_num_disparities)
    vel, valid = scene_flow_velocity(b.flow, b.d, b.d_change,
                                     principal_point=geometry.principal_point,
                                     camera_constant=geometry.camera_constant,
                                     baseline=geometry.baseline, dt=res.dt_s)
    valid &= b.valid
    u_sf, u_ok = scene_flow_energy(il0, ir0, il1, ir1, b.flow, b.d, b.d_change)
    return vel, valid, u_sf, u_ok


def evaluate_sequence(directory: Path, params: Any, max_triples: int | None = None,
                      log: Any = None) -> tuple[dict[str, Any], dict[str, Any]]:
    """Run the three methods on every triple of one sequence.

    Returns
    -------
    (summary, figure_data)
        summary: {"<method>": aggregate(...)} plus "reference" (mean |V*| over frames) and
        "seconds"; figure_data: the fields of the middle triple for the figures.
    """
    import numpy as np

    from processing.chain import ChainState, compute_scene_flow
    from processing.synthetic import read_frame, read_sequence_meta
    from processing.synthetic.reference import triplet_reference

    meta = read_sequence_meta(directory)
    geometry = _geometry(meta)
    n = int(meta["n_frames"])
    if n < 3:
        raise ValueError(f"{directory}: {n} frame(s); a triple needs at least 3")
    frames = [read_frame(directory, i, meta) for i in range(n)]
    triples = n - 2 if max_triples is None else min(n - 2, max_triples)
    per_method: dict[str, list[dict[str, Any]]] = {m: [] for m in METHODS}
    state = ChainState()
    fig: dict[str, Any] = {}
    start = time.perf_counter()
    for i in range(triples):
        f0, f1, f2 = frames[i:i + 3]
        res = compute_scene_flow([f0.left, f1.left, f2.left], [f0.right, f1.right, f2.right],
                                 [f0.t_s, f1.t_s, f2.t_s], geometry, params, state)
        ref, ref_mask = triplet_reference(f0, f1)
        fields = {"proposed": (res.velocity, res.valid, res.u_sf, res.u_sf_valid)}
        for kind in METHODS[1:]:
            fields[kind] = _baseline_velocity(kind, res, geometry, params)
        for m in METHODS:
            vel, valid, u_sf, u_ok = fields[m]
            per_method[m].append(frame_metrics(vel, valid, res.gas_mask, u_sf, u_ok,
                                               ref, ref_mask))
        if i == triples // 2:
            fig = {"index": i, "reference": np.where(ref_mask[..., None], ref, 0.0),
                   "reference_mask": ref_mask, "gas_mask": res.gas_mask,
                   "fields": {m: (fields[m][0], fields[m][1]) for m in METHODS}}
        if log is not None:
            p = per_method["proposed"][-1]
            rm = "n/a" if p["rmve"] is None else f"{p['rmve']:.1f} %"
            log(f"  {Path(directory).name} triple {i + 1}/{triples}: proposed RMVE {rm} "
                f"({time.perf_counter() - start:.0f} s)")
    summary: dict[str, Any] = {m: aggregate(per_method[m]) for m in METHODS}
    ref_speeds = [float(np.linalg.norm(f["reference_mean_velocity"]))
                  for f in per_method["proposed"] if f["reference_mean_velocity"] is not None]
    summary["reference"] = {"mean_speed_m_s": float(np.mean(ref_speeds)) if ref_speeds
                            else None, "triples": triples}
    summary["seconds"] = time.perf_counter() - start
    return summary, fig


# ---------------------------------------------------------------------------- output


def _fmt(v: float | None, spec: str) -> str:
    return "n/a" if v is None else format(v, spec)


def _pm(mean: float | None, std: float | None) -> str:
    return "n/a" if mean is None else f"{mean:.2f}+-{_fmt(std, '.2f')}"


def format_table(results: dict[str, dict[str, Any]]) -> str:
    """A Table-3-shaped text table: ours and, where known, the paper's row below it."""
    head = (f"{'S':<10} {'':<6} {'RMVE/%':>13} {'AEMV/deg':>13} {'AEE/mm/s':>9} "
            f"{'AAE/deg':>8} {'c_USF':>6} {'SA/%':>7} {'(r_X, r_Y, r_Z)':>20} "
            f"{'Brox RMVE/%':>13} {'Fbck RMVE/%':>13}")
    lines = [head, "-" * len(head)]

    def row(name: str, who: str, p: dict[str, Any], b: dict[str, Any],
            f: dict[str, Any]) -> str:
        r = p.get("r_sf")
        rs = "n/a" if r is None else "(" + ", ".join(_fmt(x, ".2f") for x in r) + ")"
        return (f"{name:<10} {who:<6} {_pm(p.get('rmve'), p.get('rmve_std')):>13} "
                f"{_pm(p.get('aemv'), p.get('aemv_std')):>13} "
                f"{_fmt(p.get('aee_3d_mm_s'), '.1f'):>9} {_fmt(p.get('aae_3d_deg'), '.2f'):>8} "
                f"{_fmt(p.get('c_usf'), '.2f'):>6} {_fmt(p.get('sa'), '.1f'):>7} {rs:>20} "
                f"{_pm(b.get('rmve'), b.get('rmve_std')):>13} "
                f"{_pm(f.get('rmve'), f.get('rmve_std')):>13}")

    for name, res in results.items():
        lines.append(row(name, "ours", res["proposed"], res["sgm_brox"], res["sgm_farneback"]))
        paper = PAPER_TABLE3.get(name)
        if paper is not None:
            lines.append(row("", "paper", paper["proposed"], paper["sgm_brox"],
                             paper["sgm_farneback"]))
    lines.append("AEE/AAE/c_USF/r_SF: proposed method. Baselines' full metrics are in --json.")
    return "\n".join(lines)


def _public(results: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """The JSON document: per sequence and method the metrics, per-frame values included."""
    return {name: {k: v for k, v in res.items()} for name, res in results.items()}


# ---------------------------------------------------------------------------- figures

_COLOURS = {"reference": (0, 0, 0), "proposed": (40, 40, 220), "sgm_brox": (200, 120, 0),
            "sgm_farneback": (0, 160, 0)}


def _line_panel(series: dict[str, list[float | None]], title: str,
                size: tuple[int, int] = (360, 260)) -> Any:
    """One line plot (OpenCV drawing) of several series over the frame index."""
    import cv2
    import numpy as np

    w, h = size
    img = np.full((h, w, 3), 255, np.uint8)
    left, right, top, bottom = 52, 10, 26, 30
    vals = [v for s in series.values() for v in s if v is not None]
    lo, hi = (min(vals), max(vals)) if vals else (0.0, 1.0)
    if hi - lo < 1e-6:
        lo, hi = lo - 0.5, hi + 0.5
    pad = 0.08 * (hi - lo)
    lo, hi = lo - pad, hi + pad
    n = max(len(s) for s in series.values())

    def xy(i: int, v: float) -> tuple[int, int]:
        x = left + (w - left - right) * (i / max(n - 1, 1))
        y = top + (h - top - bottom) * (hi - v) / (hi - lo)
        return round(x), round(y)

    cv2.rectangle(img, (left, top), (w - right, h - bottom), (160, 160, 160), 1)
    for k in range(5):
        v = lo + (hi - lo) * k / 4
        _, y = xy(0, v)
        cv2.line(img, (left - 4, y), (left, y), (0, 0, 0), 1)
        cv2.putText(img, f"{v:.2f}", (2, y + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 0, 0), 1,
                    cv2.LINE_AA)
    for i in range(n):
        x, _ = xy(i, lo)
        cv2.putText(img, str(i), (x - 3, h - bottom + 14), cv2.FONT_HERSHEY_SIMPLEX, 0.35,
                    (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, title, (left, 17), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1,
                cv2.LINE_AA)
    cv2.putText(img, "triple", (w // 2 - 15, h - 3), cv2.FONT_HERSHEY_SIMPLEX, 0.35,
                (0, 0, 0), 1, cv2.LINE_AA)
    for name, s in series.items():
        colour = _COLOURS.get(name, (100, 100, 100))
        pts = [xy(i, v) for i, v in enumerate(s) if v is not None]
        for a, b in itertools.pairwise(pts):
            cv2.line(img, a, b, colour, 2 if name == "reference" else 1, cv2.LINE_AA)
        for p in pts:
            cv2.circle(img, p, 3, colour, -1, cv2.LINE_AA)
    return img


def _legend(width: int) -> Any:
    import cv2
    import numpy as np

    img = np.full((24, width, 3), 255, np.uint8)
    x = 10
    for name in ("reference", *METHODS):
        cv2.line(img, (x, 12), (x + 20, 12), _COLOURS[name], 2)
        label = "reference V*" if name == "reference" else METHOD_LABELS[name]
        cv2.putText(img, label, (x + 25, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1,
                    cv2.LINE_AA)
        x += 35 + 9 * len(label)
    return img


def mean_velocity_figure(summary: dict[str, Any]) -> Any:
    """BGR image: V_X, V_Y, V_Z and |V| of the mean velocity per triple, all methods."""
    import numpy as np

    frames = summary["proposed"]["frames"]
    panels = []
    for c, label in enumerate(("mean V_X / m/s", "mean V_Y / m/s", "mean V_Z / m/s",
                               "|mean V| / m/s")):
        series: dict[str, list[float | None]] = {}

        def comp(v: list[float] | None, c: int = c) -> float | None:
            if v is None:
                return None
            return float(np.linalg.norm(v)) if c == 3 else float(v[c])

        series["reference"] = [comp(f["reference_mean_velocity"]) for f in frames]
        for m in METHODS:
            series[m] = [comp(f["mean_velocity"]) for f in summary[m]["frames"]]
        panels.append(_line_panel(series, label))
    top = np.hstack(panels[:2])
    bottom = np.hstack(panels[2:])
    return np.vstack([_legend(top.shape[1]), top, bottom])


def _colour_field(field: Any, mask: Any, limit: float) -> Any:
    import cv2
    import numpy as np

    scaled = np.clip((field / limit + 1.0) * 127.5, 0, 255).astype(np.uint8)
    img = cv2.applyColorMap(scaled, cv2.COLORMAP_JET)
    img[~mask] = (90, 90, 90)
    return img


def fields_figure(fig: dict[str, Any]) -> Any:
    """BGR image: rows V*, proposed, SGM+Brox, SGM+Fbck; columns V_X, V_Y, V_Z (one triple).

    Each column has one symmetric colour range [-L, L] m/s (L = the reference's 99th
    percentile of |V_c|, printed in the header); grey: outside the region scored.
    """
    import cv2
    import numpy as np

    ref, ref_mask, gas = fig["reference"], fig["reference_mask"], fig["gas_mask"]
    rows = [("reference V*", ref, ref_mask)]
    for m in METHODS:
        vel, valid = fig["fields"][m]
        rows.append((METHOD_LABELS[m], vel, gas & valid))
    limits = []
    for c in range(3):
        vals = np.abs(ref[..., c][ref_mask])
        limits.append(float(np.percentile(vals, 99)) if vals.size else 1.0)
    limits = [lim if lim > 0 else 1.0 for lim in limits]
    out_rows = []
    h, w = ref.shape[:2]
    header = np.full((22, 120 + 3 * w, 3), 255, np.uint8)
    for c, axis in enumerate("XYZ"):
        cv2.putText(header, f"V_{axis} (+-{limits[c]:.2f} m/s)", (120 + c * w + 5, 16),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    out_rows.append(header)
    for label, vel, mask in rows:
        lab = np.full((h, 120, 3), 255, np.uint8)
        cv2.putText(lab, label, (4, h // 2), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1,
                    cv2.LINE_AA)
        tiles = [_colour_field(vel[..., c], mask, limits[c]) for c in range(3)]
        out_rows.append(np.hstack([lab, *tiles]))
    return np.vstack(out_rows)


def write_figures(directory: Path, name: str, summary: dict[str, Any],
                  fig: dict[str, Any]) -> list[Path]:
    """Write ``<name>_mean_velocity.png`` and ``<name>_fields.png``; return their paths."""
    import cv2

    directory.mkdir(parents=True, exist_ok=True)
    out = []
    for suffix, img in (("mean_velocity", mean_velocity_figure(summary)),
                        ("fields", fields_figure(fig) if fig else None)):
        if img is None:
            continue
        path = directory / f"{name}_{suffix}.png"
        if not cv2.imwrite(str(path), img):
            raise cli.CommandError(f"cannot write figure {path}")
        out.append(path)
    return out


# ---------------------------------------------------------------------------- command


def _sequences(data: Path) -> list[Path]:
    from processing.synthetic.storage import META_NAME, list_sequences

    if not data.exists():
        raise ValueError(
            f"no synthetic sequences: {data} does not exist. Generate the three Table-2 "
            f"sequences first (about 1-2 min): ogiflow simulate --out {data}"
        )
    if (data / META_NAME).is_file():
        return [data]
    seqs = list_sequences(data)
    if not seqs:
        raise ValueError(
            f"{data} holds no synthetic sequence (no */meta.json). Generate them with: "
            f"ogiflow simulate --out {data}"
        )
    return seqs


def run(args: argparse.Namespace) -> int:
    """Evaluate every sequence in --data; print the table, write JSON and figures."""
    from processing.synthetic.storage import SequenceFormatError

    if args.sgm_range < 16 or args.sgm_range % 16:
        raise ValueError(f"--sgm-range must be a positive multiple of 16, got {args.sgm_range}")
    if not args.d0 >= 0:
        raise ValueError(f"--d0 must be >= 0 px, got {args.d0}")
    if args.frames is not None and args.frames < 1:
        raise ValueError(f"--frames must be >= 1, got {args.frames}")
    seqs = _sequences(args.data)
    params = chain_parameters(args.disparity_init, args.d0, args.sgm_range)

    def log(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    results: dict[str, dict[str, Any]] = {}
    for seq in seqs:
        log(f"evaluating {seq.name} ...")
        try:
            summary, fig = evaluate_sequence(seq, params, max_triples=args.frames, log=log)
        except SequenceFormatError as exc:
            raise cli.CommandError(f"cannot read sequence {seq}: {exc}") from exc
        results[seq.name] = summary
        if args.figures is not None:
            for path in write_figures(args.figures, seq.name, summary, fig):
                log(f"  wrote {path}")
    lo = math.floor(args.d0)
    init = (f"SGM over [{lo}, {lo + args.sgm_range}) px, holes {args.d0:g} px"
            if args.disparity_init == "sgm" else f"d0 = {args.d0:g} px")
    print(f"Scene flow on synthetic data (paper Table 3); disparity init: {init}; "
          f"means over triples")
    print(format_table(results))
    for name, res in results.items():
        undef = {m: res[m]["undefined"] for m in METHODS if res[m]["undefined"]}
        if undef:
            print(f"{name}: frames with undefined metrics (left out of the means): {undef}")
    if args.json is not None:
        try:
            args.json.parent.mkdir(parents=True, exist_ok=True)
            args.json.write_text(json.dumps(_public(results), indent=2) + "\n")
        except OSError as exc:
            raise cli.CommandError(f"cannot write {args.json}: {exc}") from exc
    return cli.EXIT_OK
