"""Core of ``ogiflow eval emission``: the emission rate on simulated sequences vs the truth.

For every sequence written by ``ogiflow simulate`` under a folder, the chain runs on every
consecutive raw triple (i, i+1, i+2), as the appliance would, and per triple:

- column density: the left camera's counts -> in-band radiance (the sequence's calibration
  file, as a site has it), a background model without gas
  (:class:`processing.emission.BackgroundModel`, fed the chain's gas masks), the gas
  temperature of the scene (what the anemometer's sonic temperature gives a real site: the
  plume is at ambient temperature) and the band-averaged absorption coefficient of the
  scene (what a gas-cell calibration gives); averaged over frames i and i+1;
- curtains downstream of the detected source (:func:`processing.emission.place_curtains`);
- stereo rate (our 3D velocity and per-pixel depth) and the single-camera QOGI rate
  (image-plane flow, one typed-in distance: the source's distance, as a rangefinder would
  give it) through the same curtains;
- the true flux through the same curtains from the simulator's flux moment
  (:func:`processing.emission.truth.true_curtain_flux`, mean of frames i and i+1, matching
  the velocity reference of ``ogiflow eval sceneflow``), and the true release rate.

Only curtains on which the stereo rate is defined count, for all three. The sequence's
numbers are means over the triples with a defined rate; the stereo uncertainty is the
:class:`processing.emission.RateWindow` one over the whole sequence. Nothing here reads the
truth to tune a measurement: the truth only scores it.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from appliance.evaluation.robustness import FIELD_DISPARITY_OPTIONS
from appliance.evaluation.sceneflow_figures import _line_panel
from appliance.paths import walk
from processing.calibration import load_calibration
from processing.chain import (
    ChainParameters,
    ChainState,
    SceneFlowResult,
    StereoGeometry,
    compute_scene_flow,
)
from processing.emission import METHANE, RateWindow
from processing.emission.estimator import (
    TUNED_WIDTH_PX,
    CurtainRates,
    EmissionEstimator,
    EmissionSettings,
)
from processing.emission.rate import LINE_OF_SIGHT_DEG
from processing.emission.truth import true_curtain_flux
from processing.synthetic import SyntheticFrame, read_frame, read_sequence_meta
from processing.synthetic.storage import META_NAME
from processing.synthetic.volume_exit import sequence_plume_exit

Log = Callable[[str], None]
#: Name of the calibration file ``ogiflow simulate`` writes beside the frames.
CALIBRATION_NAME = "calibration.yaml"
#: Acceptance targets: every sequence within 20 %, median within 10 %.
TARGET_WORST, TARGET_MEDIAN = 0.20, 0.10


def find_emission_sequences(data: Path) -> list[Path]:
    """Every sequence folder (holding a ``meta.json``) at or below ``data``, sorted."""
    if not data.exists():
        raise ValueError(f"{data} does not exist; write sequences with ogiflow simulate "
                         f"--preset field --out {data}/NAME (see benchmarks/emission_sequences.sh)")
    found = sorted(p.parent for p in walk(data) if p.name == META_NAME and p.is_file())
    if not found:
        raise ValueError(f"{data} holds no sequence written by ogiflow simulate (no meta.json)")
    return found


def chain_parameters(meta: dict[str, Any]) -> ChainParameters:
    """The chain's settings for a field scene, as a site sets them: the gas depth band of
    the simulation volume (d0 = s b / Z_far, 64 px searched), field solver options,
    registration on only when the cameras shake (the uniform background has no texture)."""
    sim, cam = meta["simulation"], meta["camera"]
    z_far = float(sim["volume_origin_m"][2]) + int(sim["grid_zyx"][0]) * float(sim["voxel_m"])
    d0 = float(np.floor(float(cam["s_px"]) * float(cam["b_m"]) / z_far))
    register = float(meta["options"].get("jitter_px", 0.0)) > 0
    return ChainParameters(d0=d0, sgm_num_disparities=64, register=register,
                           disparity_options=dict(FIELD_DISPARITY_OPTIONS))


def typed_distance_m(meta: dict[str, Any]) -> float:
    """The single-camera method's typed-in distance: the (first) source's depth, m."""
    sim = meta["simulation"]
    src = sim["sources"][0]["position_m"]
    return float(sim["volume_origin_m"][2]) + float(src[2])


def _geometry(directory: Path, meta: dict[str, Any]) -> StereoGeometry:
    calib = directory / CALIBRATION_NAME
    if calib.is_file():
        return StereoGeometry.from_calibration(load_calibration(calib), rectify=False)
    return StereoGeometry.from_synthetic_camera(meta["camera"])


@dataclass(frozen=True)
class Triple:
    """One triple of a sequence as ``eval emission`` processes it.

    ``sigma_kg_m2`` is the column density the rate used (mean of frames i and i+1),
    ``rates`` the stereo and single-camera rates on its curtains.
    """

    index: int
    first: SyntheticFrame
    second: SyntheticFrame
    result: SceneFlowResult
    sigma_kg_m2: np.ndarray
    rates: CurtainRates


@dataclass(frozen=True)
class SequenceSetup:
    """What the rate of a sequence needs: its meta, geometry, chain parameters, estimator,
    gas temperature (K) and the single camera's typed-in distance (m)."""

    meta: dict[str, Any]
    geometry: StereoGeometry
    params: ChainParameters
    estimator: EmissionEstimator
    t_gas_k: float
    z_typed_m: float


def sequence_setup(directory: Path) -> SequenceSetup:
    """The calibrated site of a simulated sequence (module docstring)."""
    meta = read_sequence_meta(directory)
    geometry = _geometry(directory, meta)
    rad = meta["radiometry"]
    # A calibrated site: alpha from a gas cell, the gas at the ambient (sonic) temperature.
    gas = replace(METHANE, alpha_per_ppm_m=float(rad["alpha_per_ppm_m"]),
                  source="the scene's (a gas-cell calibration)")
    z_typed = typed_distance_m(meta)
    settings = EmissionSettings(gas=gas, typed_distance_m=z_typed,
                                pixel_scale=geometry.image_size[0] / TUNED_WIDTH_PX)
    estimator = EmissionEstimator(settings, geometry.principal_point, geometry.camera_constant,
                                  geometry.curve_left)
    return SequenceSetup(meta, geometry, chain_parameters(meta), estimator,
                         float(rad["t_gas_k"]), z_typed)


def iter_triples(directory: Path, setup: SequenceSetup,
                 max_triples: int | None = None) -> Iterator[Triple]:
    """Run the chain and the rate on every consecutive triple (i, i+1, i+2) in order."""
    meta, est = setup.meta, setup.estimator
    n = int(meta["n_frames"])
    frames = [read_frame(directory, i, meta) for i in range(n)]
    if frames[0].flux_moment_kg_s is None:
        raise ValueError(f"{directory}: written before the emission ground truth; simulate "
                         "it again")
    sigmas: list[np.ndarray] = []
    state = ChainState()
    for i in range(n - 2 if max_triples is None else min(n - 2, max_triples)):
        f0, f1, f2 = frames[i:i + 3]
        res = compute_scene_flow([f0.left, f1.left, f2.left], [f0.right, f1.right, f2.right],
                                 [f0.t_s, f1.t_s, f2.t_s], setup.geometry, setup.params, state)
        if i == 0:
            sigmas.append(est.column_kg_m2(f0.left, res.gas_mask, setup.t_gas_k))
        sigmas.append(est.column_kg_m2(f1.left, res.gas_mask, setup.t_gas_k))
        sigma = 0.5 * (sigmas[i] + sigmas[i + 1])
        rates = est.rates(sigma, flow=res.flow, velocity=res.velocity,
                          depth=res.position[..., 2], valid=res.valid, gas_mask=res.gas_mask,
                          dt_s=res.dt_s)
        yield Triple(i, f0, f1, res, sigma, rates)


def evaluate_emission_sequence(directory: Path, *, name: str | None = None,
                               max_triples: int | None = None,
                               log: Log | None = None) -> dict[str, Any]:
    """Stereo, single-camera and true rates of one sequence (module docstring).

    Returns
    -------
    dict
        The JSON record (``true_release_g_s``, ``true_flux_g_s``, ``stereo_g_s``,
        ``stereo_uncertainty_g_s``, ``single_camera_g_s``, errors, counts) and ``series``
        (per-triple rates, None where undefined) for the figure.
    """
    setup = sequence_setup(directory)
    meta, name = setup.meta, name or directory.name
    pp, s = setup.geometry.principal_point, setup.geometry.camera_constant
    window = RateWindow(window_s=1e9)
    series: dict[str, list[float | None]] = {"truth": [], "stereo": [], "single": [],
                                             "release": []}
    triples = int(meta["n_frames"]) - 2
    triples = triples if max_triples is None else min(triples, max_triples)
    start = time.perf_counter()
    for tr in iter_triples(directory, setup, max_triples):
        i, f0, f1, rates = tr.index, tr.first, tr.second, tr.rates
        moment = 0.5 * (f0.flux_moment_kg_s.astype(np.float64)
                        + f1.flux_moment_kg_s.astype(np.float64))
        release = [f.release_rate_g_s for f in (f0, f1) if f.release_rate_g_s is not None]
        series["release"].append(float(np.mean(release)) if release else None)
        rate = rates.stereo()
        defined = rate.rate_g_s is not None
        truth = [true_curtain_flux(c, moment, principal_point=pp, camera_constant=s) * 1e3
                 for c in rates.curtains]
        series["stereo"].append(rate.rate_g_s)
        series["single"].append(rates.single().rate_g_s)
        series["truth"].append(float(np.mean(truth)) if defined else None)
        window.push(f1.t_s, rate)
        if log is not None:
            log(f"  {name} triple {i + 1}/{triples}: "
                + (f"stereo {rate.rate_g_s:.2f} g/s, true {series['truth'][-1]:.2f} g/s"
                   if defined else f"no rate ({rate.reason})")
                + f" ({time.perf_counter() - start:.0f} s)")
    return _record(meta, series, window, setup.z_typed_m, time.perf_counter() - start)


def _mean(values: list[float | None]) -> float | None:
    v = [x for x in values if x is not None]
    return float(np.mean(v)) if v else None


def _rel(x: float | None, ref: float | None) -> float | None:
    return None if x is None or ref is None or ref == 0 else x / ref - 1.0


def _record(meta: dict[str, Any], series: dict[str, list[float | None]], window: RateWindow,
            z_typed: float, seconds: float) -> dict[str, Any]:
    est = window.estimate()
    truth, stereo, single = (_mean(series[k]) for k in ("truth", "stereo", "single"))
    wind = [float(w) for w in meta["wind_m_s"]]
    opts = meta["options"]
    leave = sequence_plume_exit(meta)
    return {
        "true_release_g_s": _mean(series["release"]),
        "true_flux_g_s": truth,
        "stereo_g_s": stereo,
        "stereo_uncertainty_g_s": est.uncertainty_g_s,
        "out_of_plane_deg": est.out_of_plane_deg,
        "flags": list(est.flags),
        "single_camera_g_s": single,
        "stereo_error": _rel(stereo, truth),
        "single_camera_error": _rel(single, truth),
        "frames_defined": est.frames,
        "frames_total": est.frames_total,
        "nominal_release_g_s": float(meta["release_rate_g_s"]),
        "wind_m_s": wind,
        "distance_m": z_typed,
        "camera_effects": bool(opts.get("noise_netd_k") or opts.get("jitter_px")
                               or opts.get("gain_mismatch") or opts.get("radiometric_mismatch")),
        "volume_exit": None if leave is None else leave.describe(),
        "vanishes_in_view": leave is not None and leave.vanishes_in_view,
        "seconds": seconds,
        "series": series,
    }


def acceptance(results: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """Worst and median |stereo error|, and whether stereo beats single-camera on every
    sequence whose wind has an out-of-plane (Z) component."""
    errs = [abs(r["stereo_error"]) for r in results.values() if r["stereo_error"] is not None]
    out_of_plane = [r for r in results.values() if abs(r["wind_m_s"][2]) > 0.1
                    and r["stereo_error"] is not None and r["single_camera_error"] is not None]
    beats = [abs(r["stereo_error"]) < abs(r["single_camera_error"]) for r in out_of_plane]
    worst = max(errs) if errs else None
    median = float(np.median(errs)) if errs else None
    return {"worst_error": worst, "median_error": median,
            "stereo_beats_single_out_of_plane": f"{sum(beats)}/{len(beats)}",
            "undefined_sequences": len(results) - len(errs),
            "pass": bool(errs) and len(errs) == len(results) and worst <= TARGET_WORST
            and median <= TARGET_MEDIAN and all(beats)}


def format_table(results: dict[str, dict[str, Any]]) -> str:
    """The table ``ogiflow eval emission`` prints (g/s, errors in %)."""
    def f(v: float | None, spec: str = ".2f") -> str:
        return "n/a" if v is None else format(v, spec)

    def pct(v: float | None) -> str:
        return "n/a" if v is None else f"{100 * v:+.1f}"

    lines = [f"{'sequence':<22} {'release':>8} {'true flux':>9} {'stereo':>14} {'err/%':>6} "
             f"{'single':>7} {'err/%':>6} {'wind (X,Y,Z) m/s':>18} {'Z/m':>5} {'frames':>7} "
             f"{'out of plane':>12}",
             "-" * 125]
    for name, r in results.items():
        st = ("n/a" if r["stereo_g_s"] is None else
              f"{r['stereo_g_s']:.2f}+-{f(r['stereo_uncertainty_g_s'])}")
        wind = "(" + ", ".join(f"{w:.1f}" for w in r["wind_m_s"]) + ")"
        fx = (" *" if r["camera_effects"] else "") + (" v" if r.get("vanishes_in_view") else "")
        lines.append(f"{(name + fx):<22} {f(r['true_release_g_s']):>8} {f(r['true_flux_g_s']):>9} "
                     f"{st:>14} {pct(r['stereo_error']):>6} {f(r['single_camera_g_s']):>7} "
                     f"{pct(r['single_camera_error']):>6} {wind:>18} {r['distance_m']:>5.1f} "
                     f"{r['frames_defined']:>3}/{r['frames_total']:<3} "
                     f"{f(r.get('out_of_plane_deg'), '.0f'):>5} deg{_flag_mark(r)}")
    acc = acceptance(results)
    lines.append(f"|stereo error|: worst {pct(acc['worst_error'])} %, median "
                 f"{pct(acc['median_error'])} % (targets 20 / 10 %); stereo closer than "
                 f"single camera with out-of-plane wind: {acc['stereo_beats_single_out_of_plane']}"
                 "; * = camera non-idealities; v = the simulated plume leaves its volume "
                 "through the near or far face inside the view (its gas vanishes in "
                 "mid-image: ogiflow simulate --volume-depth); LOS = rate flagged "
                 f"line_of_sight (the gas's motion more than {LINE_OF_SIGHT_DEG:.0f} deg out of "
                 "the image plane)")
    return "\n".join(lines)


def _flag_mark(record: dict[str, Any]) -> str:
    return " LOS" if "line_of_sight" in record.get("flags", ()) else ""


def public(results: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """The JSON of ``--json`` (per-triple series included, no NaN)."""
    return {name: {k: v for k, v in r.items() if k != "seconds"} for name, r in results.items()}


def write_figure(directory: Path, name: str, record: dict[str, Any]) -> Path:
    """``<name>_rate.png``: true flux, stereo and single-camera rate (and the true release)
    per triple, g/s."""

    s = record["series"]
    img = _line_panel({"reference": s["truth"], "proposed": s["stereo"],
                       "sgm_farneback": s["single"], "release": s["release"]},
                      f"{name}: rate g/s", size=(520, 300))
    legend = np.full((22, img.shape[1], 3), 255, np.uint8)
    for k, (label, colour) in enumerate((("true flux", (0, 0, 0)), ("stereo", (40, 40, 220)),
                                         ("single camera", (0, 160, 0)),
                                         ("release", (100, 100, 100)))):
        x = 10 + 125 * k
        cv2.line(legend, (x, 11), (x + 20, 11), colour, 2)
        cv2.putText(legend, label, (x + 25, 15), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1,
                    cv2.LINE_AA)
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / f"{name}_rate.png"
    cv2.imwrite(str(path), np.vstack([img, legend]))
    return path
