"""Core of ``ogiflow eval sceneflow``: 3D gas velocity accuracy on synthetic sequences (Table 3).

For every sequence (``ogiflow-synthetic/1``, written by ``ogiflow simulate``) and every
consecutive raw triple (i, i+1, i+2) of it, up to three methods compute the 3D velocity V of
the left view from the same pre-processed differential images:

- ``proposed``: the whole chain, :func:`processing.chain.compute_scene_flow` (Brox flow,
  joint d and d' of Eq. 6, Eq. 4, segmentation of Eq. 9);
- ``sgm_brox`` and ``sgm_farneback``: the decoupled baselines of
  :mod:`processing.metrics.baselines` on the chain's four normalised differential images,
  turned into V by the same Eq. 4
  (:func:`processing.velocity.triangulate.scene_flow_velocity`) with the same dt.

All are scored over the chain's segmented gas region (the baselines have no segmentation
of their own, and one region keeps the comparison about velocity) against the triplet's
reference V* (:func:`processing.synthetic.reference.triplet_reference`) with the metrics of
:mod:`processing.metrics.sceneflow` (Sec. 5.1, Eq. 10). RMVE and AEMV are given as mean and
standard deviation over the frames, the other metrics as means.

``workers=2`` hands the triples out as the daemon's two workers take them: alternately to
two chain states at stride 2 that share their registration shifts, so each warm-starts
from its own triple two frames back (:mod:`appliance.runtime.workers`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from processing.chain import (
    ChainParameters,
    ChainState,
    SceneFlowResult,
    StereoGeometry,
    compute_scene_flow,
)
from processing.chain.shifts import LocalShiftMemo
from processing.chain.state import STRIDES
from processing.metrics import sceneflow as sm
from processing.metrics.baselines import sgm_brox, sgm_farneback
from processing.synthetic import SyntheticFrame
from processing.synthetic.reference import triplet_reference
from processing.synthetic.storage import META_NAME, list_sequences
from processing.velocity.quality import c_usf, scene_flow_energy
from processing.velocity.triangulate import scene_flow_velocity

METHODS = ("proposed", "sgm_brox", "sgm_farneback")
METHOD_LABELS = {"proposed": "Proposed", "sgm_brox": "SGM+Brox", "sgm_farneback": "SGM+Fbck"}

#: Column density (ppm*m) below which a segmented pixel counts as "not gas" in the
#: false-gas fraction: a tenth of the default NECL, so faint plume edges are not counted
#: as false.
NOT_GAS_PPM_M = 10.0

#: One method's fields for scoring: V (H, W, 3), valid (H, W), U_SF (H, W), U_SF valid.
Fields = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
#: A per-frame or aggregated metrics record (JSON-ready: floats, None, lists).
Metrics = dict[str, Any]
Log = Callable[[str], None]

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


def chain_parameters(disparity_init: str, d0: float, sgm_range: int) -> ChainParameters:
    """The chain's parameters for synthetic data under the paper's ideal conditions."""
    # register=False: the registration estimates camera jitter on the static background.
    # The synthetic background is featureless (uniform black body) and there is no jitter,
    # so the only texture it could lock onto is the gas itself, whose motion it would then
    # cancel; the chain also refuses shifts above max_jitter_px, but shifts below that
    # would still be wrong. The paper's Sec. 5.1 conditions have no jitter to remove.
    return ChainParameters(register=False, disparity_init=disparity_init, d0=d0,
                           sgm_num_disparities=sgm_range)


def sequence_geometry(meta: dict[str, Any]) -> StereoGeometry:
    """The ideal geometry of a sequence's rectified synthetic cameras (ValueError naming it
    when they have lens distortion)."""
    try:
        return StereoGeometry.from_synthetic_camera(meta["camera"])
    except ValueError as exc:
        raise ValueError(f"sequence {meta['name']!r}: {exc}") from None


def frame_metrics(velocity: np.ndarray, valid: np.ndarray, gas_mask: np.ndarray,
                  u_sf: np.ndarray, u_sf_valid: np.ndarray, reference: np.ndarray,
                  reference_mask: np.ndarray,
                  column_density: np.ndarray | None = None) -> Metrics:
    """All per-frame metrics of one method (see :mod:`processing.metrics.sceneflow`).

    ``velocity``/``valid`` are the method's V and validity, ``gas_mask`` the segmented
    region, ``reference``/``reference_mask`` V* and the reference gas mask. With the
    triple's ``column_density`` (ppm*m), ``false_gas`` is the fraction of segmented pixels
    whose ray holds (almost) no gas (< :data:`NOT_GAS_PPM_M`). Undefined values are None.
    """
    region = gas_mask & valid
    ref_clean = np.where(reference_mask[..., None], reference, 0.0)
    v_avg = sm.mean_velocity(velocity, region)
    v_ref = sm.mean_velocity(ref_clean, reference_mask)
    # Eq. 10 averages V and V* over different regions (segmented vs reference), so RMVE
    # mixes velocity error with segmentation mismatch; the same two metrics over the
    # common pixels isolate the velocity error (not in the paper; for the analysis).
    v_avg_c, v_ref_c, both = common_mean_velocities(velocity, valid, gas_mask, reference,
                                                    reference_mask)
    aee = sm.aee_3d(ref_clean, velocity, both)
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
        "false_gas": _false_gas(gas_mask, column_density),
    }


def common_mean_velocities(velocity: np.ndarray, valid: np.ndarray, gas_mask: np.ndarray,
                           reference: np.ndarray, reference_mask: np.ndarray
                           ) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray]:
    """The measured and the reference mean velocity on the pixels both count as gas.

    Parameters
    ----------
    velocity, reference : ndarray, shape (H, W, 3)
        Measured V and reference V*, m/s (the reference may hold NaN off its mask).
    valid, gas_mask, reference_mask : ndarray, shape (H, W), bool
        Where V is defined, the segmented gas, the reference's gas.

    Returns
    -------
    (measured, reference, common)
        The two means, shape (3,) (None where no pixel is segmented, valid and gas), and
        the (H, W) bool mask of those pixels.
    """
    common = gas_mask & valid & reference_mask
    # inside the reference's mask: no NaN of the reference is read, no cleaned copy needed
    return sm.mean_velocity(velocity, common), sm.mean_velocity(reference, common), common


def _false_gas(gas_mask: np.ndarray, column_density: np.ndarray | None) -> float | None:
    n = int(gas_mask.sum())
    if column_density is None or n == 0:
        return None
    return float((gas_mask & (column_density < NOT_GAS_PPM_M)).sum()) / n


def _mean_std(values: list[float | None]) -> tuple[float | None, float | None, int]:
    vals = [v for v in values if v is not None]
    if not vals:
        return None, None, len(values)
    arr = np.asarray(vals, dtype=np.float64)
    return float(arr.mean()), float(arr.std()), len(values) - len(vals)


def aggregate(frames: list[Metrics]) -> Metrics:
    """Sequence summary of one method from its per-frame metrics (None where undefined).

    ``undefined`` counts, per metric, the frames where it was undefined (left out of the
    mean); a metric undefined in every frame is None. ``rmve_of_mean`` and ``aemv_of_mean``
    are Eq. 10's errors of the frames' mean velocity
    (:func:`processing.metrics.sceneflow.errors_of_sequence_mean`), as a leak event
    averages the mean velocities of its frames.
    """
    out: Metrics = {"n_frames": len(frames)}
    undefined: dict[str, int] = {}
    for key in ("rmve", "aemv", "rmve_common", "aemv_common", "aee_3d_mm_s", "aae_3d_deg",
                "c_usf", "sa", "sa_overlap", "false_gas"):
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
    out["rmve_of_mean"], out["aemv_of_mean"] = sm.errors_of_sequence_mean(
        [f["mean_velocity"] for f in frames], [f["reference_mean_velocity"] for f in frames])
    out["undefined"] = undefined
    out["frames"] = frames
    return out


def baseline_fields(kind: str, res: SceneFlowResult, geometry: StereoGeometry,
                    params: ChainParameters) -> Fields:
    """V, validity and U_SF of one baseline on the chain's differential images of ``res``."""
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


def worker_states(workers: int) -> list[ChainState]:
    """The chain states of the daemon's ``workers`` (1 or 2) worker processes: triple i goes
    to state i % workers, each at stride ``workers``, one shift memo between them.

    Raises
    ------
    ValueError
        Another number: more than two workers each take the newest triple, which depends on
        the machine's timing, not on the sequence.
    """
    if workers not in STRIDES:
        raise ValueError(f"an evaluation runs the triples as {' or '.join(map(str, STRIDES))} "
                         f"worker(s) take them, got {workers} (more workers each take the "
                         "newest triple, which depends on timing)")
    memo = LocalShiftMemo()
    return [ChainState(stride=workers, shifts=memo) for _ in range(workers)]


def configured_workers(workers: int, source: str) -> int:
    """A configuration's ``processing.workers`` (from ``source``) as an evaluation takes the
    triples (:func:`worker_states`): ValueError saying what to give instead of more than
    two."""
    if workers not in STRIDES:
        raise ValueError(f"{source}: processing.workers is {workers}; an evaluation takes the "
                         "triples as 1 or 2 workers do (more each take the newest triple, "
                         "which depends on timing): give --workers 1 or 2")
    return workers


def chain_triples(frames: Sequence[SyntheticFrame], geometry: StereoGeometry,
                  params: ChainParameters, *, workers: int = 1, triples: int | None = None
                  ) -> Iterator[tuple[int, SceneFlowResult]]:
    """The chain over the first ``triples`` (None: every) consecutive triples (i, i+1, i+2)
    of ``frames``, taken as the daemon's ``workers`` take them (:func:`worker_states`): per
    triple its index and the SceneFlowResult."""
    states = worker_states(workers)
    n = len(frames) - 2 if triples is None else triples
    for i in range(n):
        f0, f1, f2 = frames[i:i + 3]
        yield i, compute_scene_flow([f0.left, f1.left, f2.left], [f0.right, f1.right, f2.right],
                                    [f0.t_s, f1.t_s, f2.t_s], geometry, params,
                                    states[i % workers])


def evaluate_frames(frames: Sequence[SyntheticFrame], geometry: StereoGeometry,
                    params: ChainParameters, *, methods: Sequence[str] = METHODS,
                    max_triples: int | None = None, name: str = "sequence",
                    log: Log | None = None, workers: int = 1
                    ) -> tuple[Metrics, dict[str, Any]]:
    """Run ``methods`` on every consecutive triple of ``frames`` (warm-started chains: one,
    or the daemon's two workers' taking every other triple, :func:`worker_states`).

    Returns
    -------
    (summary, figure_data)
        summary: {"<method>": aggregate(...)} plus "reference" (mean |V*| over frames),
        "flags" (how many triples carried each chain flag) and "seconds"; figure_data: the
        fields of the middle triple for the figures.
    """
    unknown = [m for m in methods if m not in METHODS]
    if unknown or "proposed" not in methods:
        raise ValueError(f"methods must include 'proposed' and be among {METHODS}, got "
                         f"{tuple(methods)}")
    n = len(frames)
    if n < 3:
        raise ValueError(f"{name}: {n} frame(s); a triple needs at least 3")
    triples = n - 2 if max_triples is None else min(n - 2, max_triples)
    per_method: dict[str, list[Metrics]] = {m: [] for m in methods}
    flags: dict[str, int] = {}
    fig: dict[str, Any] = {}
    start = time.perf_counter()
    for i, res in chain_triples(frames, geometry, params, workers=workers, triples=triples):
        f0, f1 = frames[i], frames[i + 1]
        for flag in res.summary.flags:
            flags[flag] = flags.get(flag, 0) + 1
        ref, ref_mask = triplet_reference(f0, f1)
        fields: dict[str, Fields] = {
            "proposed": (res.velocity, res.valid, res.u_sf, res.u_sf_valid)}
        for kind in methods:
            if kind != "proposed":
                fields[kind] = baseline_fields(kind, res, geometry, params)
        column = 0.5 * (f0.column_density_ppm_m + f1.column_density_ppm_m)
        for m in methods:
            vel, valid, u_sf, u_ok = fields[m]
            per_method[m].append(frame_metrics(vel, valid, res.gas_mask, u_sf, u_ok,
                                               ref, ref_mask, column))
        if i == triples // 2:
            fig = {"index": i, "reference": np.where(ref_mask[..., None], ref, 0.0),
                   "reference_mask": ref_mask, "gas_mask": res.gas_mask,
                   "fields": {m: (fields[m][0], fields[m][1]) for m in methods}}
        if log is not None:
            p = per_method["proposed"][-1]
            rm = "n/a" if p["rmve"] is None else f"{p['rmve']:.1f} %"
            log(f"  {name} triple {i + 1}/{triples}: proposed RMVE {rm} "
                f"({time.perf_counter() - start:.0f} s)")
    summary: Metrics = {m: aggregate(per_method[m]) for m in methods}
    ref_speeds = [float(np.linalg.norm(f["reference_mean_velocity"]))
                  for f in per_method["proposed"] if f["reference_mean_velocity"] is not None]
    summary["reference"] = {"mean_speed_m_s": float(np.mean(ref_speeds)) if ref_speeds
                            else None, "triples": triples}
    summary["flags"] = flags
    summary["seconds"] = time.perf_counter() - start
    return summary, fig


def find_sequences(data: Path) -> list[Path]:
    """The sequence directories in ``data`` (or ``data`` itself); ValueError saying how to
    generate them when there are none."""
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


def _fmt(v: float | None, spec: str) -> str:
    return "n/a" if v is None else format(v, spec)


def _pm(mean: float | None, std: float | None) -> str:
    return "n/a" if mean is None else f"{mean:.2f}+-{_fmt(std, '.2f')}"


def format_table(results: dict[str, Metrics]) -> str:
    """A Table-3-shaped text table: ours and, where known, the paper's row below it."""
    head = (f"{'S':<10} {'':<6} {'RMVE/%':>13} {'AEMV/deg':>13} {'AEE/mm/s':>9} "
            f"{'AAE/deg':>8} {'c_USF':>6} {'SA/%':>7} {'(r_X, r_Y, r_Z)':>20} "
            f"{'Brox RMVE/%':>13} {'Fbck RMVE/%':>13}")
    lines = [head, "-" * len(head)]

    def row(name: str, who: str, p: Metrics, b: Metrics, f: Metrics) -> str:
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


def public(results: dict[str, Metrics]) -> dict[str, Any]:
    """The JSON document: per sequence and method the metrics, per-frame values included."""
    return {name: {k: v for k, v in res.items()} for name, res in results.items()}
