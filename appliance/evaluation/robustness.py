"""Core of ``ogiflow eval robustness``: scene-flow accuracy under field disturbances.

The matrix crosses *scenes* (one fluid simulation each: a seed, a wind, a release rate;
the appliance's ``field`` geometry, plume 5.5 m away, b = 0.3 m, 30 Hz) with *conditions*
(camera effects rendered after the fluid step: background, NETD noise, jitter, gain
mismatch with or without the site's radiometric calibration, a moving warm object, a small
gas-background temperature difference). Each scene's gas is simulated once and cached
(:func:`gas_frames`); every condition renders those frames with its own camera effects
(:class:`processing.synthetic.cameras.StereoRenderer`) and runs the chain on every triple
(:func:`appliance.evaluation.sceneflow.evaluate_frames`, proposed method only).

:data:`DEFAULT_MATRIX` is the named matrix docs/accuracy.md's table comes from. A condition is
``realistic`` when its strengths lie within the acceptance set (NETD <= 0.03 K,
jitter <= 0.3 px, calibrated gain, one moving warm object, a textured plant background);
:func:`acceptance` checks those against the targets (mean RMVE and AEMV <= 12 % / 12 deg
per condition, no scene worse than 20 % / 20 deg).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from appliance.evaluation.gas_cache import gas_frames
from appliance.evaluation.sceneflow import Log, Metrics, aggregate, evaluate_frames
from appliance.evaluation.sceneflow_setup import band_disparities, rectified_truth
from processing.chain import ChainParameters, StereoGeometry
from processing.synthetic.cameras import StereoRenderer
from processing.synthetic.config import RenderOptions, SequenceConfig, synthetic_calibration
from processing.synthetic.imaging import Background, MovingObject
from processing.synthetic.presets import preset_field
from processing.synthetic.storage import SyntheticFrame

#: The warm object of the matrix: a 0.4 m disk 8 m away (behind the plume at 5.5 m, in
#: front of the plant wall at 12 m), 10 K above ambient, crossing the view at 1.2 m/s
#: (~4 px per frame).
WARM_OBJECT = MovingObject(z_m=8.0, radius_m=0.4, center_m=(-0.9, 0.1),
                           velocity_m_s=(1.2, 0.0), t_k=310.0)


@dataclass(frozen=True)
class Scene:
    """One fluid simulation of the ``field`` preset: turbulence seed, wind (m/s, left
    camera frame), release rate (g/s), plume distance (m) and depth of the simulated
    volume (m; deeper for a wind out of the image plane, see :func:`preset_field`)."""

    seed: int
    wind_m_s: tuple[float, float, float]
    release_rate_g_s: float = 3.0
    distance_m: float = 5.5
    depth_m: float = 1.44

    @property
    def name(self) -> str:
        w = ",".join(f"{x:g}" for x in self.wind_m_s)
        name = f"s{self.seed}_w({w})_q{self.release_rate_g_s:g}"
        if self.distance_m != 5.5:
            name += f"_z{self.distance_m:g}"
        return name + (f"_D{self.depth_m:g}" if self.depth_m != 1.44 else "")


@dataclass(frozen=True)
class Condition:
    """Camera effects of one row of the matrix.

    ``gain_mismatch`` is the right camera's relative gain excess; ``calibrated`` gives the
    chain the characteristic curves the simulator's calibration file holds (so a mismatch
    is corrected, as on a calibrated site), and its lens distortion, so that the chain
    rectifies the frames; ``lens_k1`` gives both lenses radial distortion (the scene's gas
    is then rendered through them, its own simulation). ``t_gas_k`` overrides the gas temperature
    (285 K against 300 K by default: a small difference is the low-contrast case);
    ``release_rate_g_s`` overrides the scenes' release rate (its own fluid simulation);
    ``object_z_m`` the moving object's distance (m; None: :data:`WARM_OBJECT`'s 8 m).
    """

    name: str
    background: str = "plant"
    noise_netd_k: float = 0.0
    jitter_px: float = 0.0
    gain_mismatch: float = 0.0
    calibrated: bool = True
    moving_object: bool = False
    t_gas_k: float | None = None
    release_rate_g_s: float | None = None
    lens_k1: float = 0.0
    object_z_m: float | None = None
    realistic: bool = True


@dataclass(frozen=True)
class Matrix:
    """Scenes x conditions, with the frame count and fluid resolution of every scene."""

    name: str
    scenes: tuple[Scene, ...]
    conditions: tuple[Condition, ...]
    n_frames: int = 14
    voxel_m: float = 0.05


#: Radial distortion of the lens rows: barrel, 2.6 px at the corners of the field camera
#: (r = 0.26 in normalised coordinates), a modest wide lens.
LENS_K1 = -0.2

_SCENES = (Scene(7, (1.5, 0.0, 0.0)), Scene(7, (1.0, 0.0, 1.0)),
           Scene(11, (1.5, 0.0, 0.0)), Scene(11, (1.0, 0.0, 1.0)))

DEFAULT_MATRIX = Matrix(
    name="default",
    scenes=_SCENES,
    conditions=(
        Condition("ideal"),
        Condition("noise 0.015 K", noise_netd_k=0.015),
        Condition("noise 0.03 K", noise_netd_k=0.03),
        Condition("noise 0.05 K", noise_netd_k=0.05, realistic=False),
        Condition("jitter 0.1 px", jitter_px=0.1),
        Condition("jitter 0.2 px", jitter_px=0.2),
        Condition("jitter 0.3 px", jitter_px=0.3),
        Condition("jitter 0.5 px", jitter_px=0.5, realistic=False),
        Condition("gain 2 % uncal.", gain_mismatch=0.02, calibrated=False, realistic=False),
        Condition("gain 4 % uncal.", gain_mismatch=0.04, calibrated=False, realistic=False),
        Condition("gain 8 % uncal.", gain_mismatch=0.08, calibrated=False, realistic=False),
        Condition("gain 4 % cal.", gain_mismatch=0.04),
        Condition("gain 8 % cal.", gain_mismatch=0.08),
        Condition("moving object", moving_object=True),
        Condition("lens k1 -0.2 uncal.", lens_k1=LENS_K1, calibrated=False, realistic=False),
        Condition("lens k1 -0.2 cal.", lens_k1=LENS_K1),
        Condition("low contrast 3 K", t_gas_k=297.0, realistic=False),
        Condition("low contrast 3 K, noise 0.03 K", t_gas_k=297.0, noise_netd_k=0.03,
                  realistic=False),
        Condition("low release 1 g/s", release_rate_g_s=1.0, realistic=False),
        Condition("all realistic", noise_netd_k=0.03, jitter_px=0.3, gain_mismatch=0.04,
                  moving_object=True),
        Condition("all strong", noise_netd_k=0.05, jitter_px=0.5, gain_mismatch=0.08,
                  calibrated=False, moving_object=True, realistic=False),
        Condition("sky ideal", background="sky", realistic=False),
        Condition("sky jitter 0.2 px", background="sky", jitter_px=0.2, realistic=False),
        Condition("sky all realistic", background="sky", noise_netd_k=0.03, jitter_px=0.3,
                  gain_mismatch=0.04, moving_object=True, realistic=False),
    ),
)

#: A two-scene, few-frame matrix for a quick look and for tests.
QUICK_MATRIX = Matrix(
    name="quick",
    scenes=(Scene(7, (1.0, 0.0, 1.0)),),
    conditions=(Condition("ideal"), Condition("jitter 0.3 px", jitter_px=0.3),
                Condition("moving object", moving_object=True)),
    n_frames=6,
    voxel_m=0.08,
)

#: The acceptance set on seeds the chain was never tuned on: every realistic condition of
#: :data:`DEFAULT_MATRIX` over four other seeds and the same two winds (8 scenes). The
#: default matrix's seeds 7 and 11 guided the chain's tuning; this one
#: tells whether its numbers hold beyond them.
HOLDOUT_MATRIX = Matrix(
    name="holdout",
    scenes=tuple(Scene(seed, wind) for seed in (3, 5, 13, 17)
                 for wind in ((1.5, 0.0, 0.0), (1.0, 0.0, 1.0))),
    conditions=tuple(c for c in DEFAULT_MATRIX.conditions if c.realistic),
)

MATRICES = {m.name: m for m in (DEFAULT_MATRIX, QUICK_MATRIX, HOLDOUT_MATRIX)}

#: Iterations of the joint d/d' solver (Eq. 6) for the field scenes, passed as the chain's
#: ``disparity_options``: one more warp and inner iteration on the coarse levels and more at
#: the finest level than the solver's defaults. With the defaults d' came out short on
#: out-of-plane wind (V_Z 0.2-0.6 m/s for 0.9 m/s: the coarse levels had not converged);
#: these recover it (ideal RMVE 15.5 -> 4.5 % on one scene) for about 25 % more chain time.
#: Not the chain's default: on the paper's Table-2 sequence 3 (1 ms frames) they raised
#: RMVE from 2.4 to 4.9 % (AEMV fell from 6.9 to 2.2 deg). A site sets them in
#: ``processing.parameters.disparity_options``.
FIELD_DISPARITY_OPTIONS: dict[str, int] = {"n_warps": 3, "n_inner": 4, "n_inner_finest": 6,
                                           "n_sor": 15}

#: Acceptance targets over the realistic conditions.
TARGET_MEAN = {"rmve": 12.0, "aemv": 12.0}
TARGET_WORST = {"rmve": 20.0, "aemv": 20.0}


def scene_config(scene: Scene, matrix: Matrix,
                 release_rate_g_s: float | None = None, lens_k1: float = 0.0) -> SequenceConfig:
    """The ``field`` preset of one scene (no camera effect yet but the lens: the gas is
    rendered through it, so a distorted lens has its own cached gas)."""
    rate = scene.release_rate_g_s if release_rate_g_s is None else release_rate_g_s
    config = preset_field(n_frames=matrix.n_frames, wind_m_s=scene.wind_m_s,
                          release_rate_g_s=rate, seed=scene.seed, voxel_m=matrix.voxel_m,
                          distance_m=scene.distance_m, depth_m=scene.depth_m)
    if lens_k1:
        config = replace(config, camera=replace(config.camera, k1=float(lens_k1)))
    return config


def condition_config(base: SequenceConfig, cond: Condition) -> SequenceConfig:
    """``base`` with the camera effects of ``cond``."""
    opts = RenderOptions(noise_netd_k=cond.noise_netd_k, jitter_px=cond.jitter_px,
                         gain_mismatch=cond.gain_mismatch,
                         moving_object=_moving_object(cond))
    rad = base.radiometry
    if cond.t_gas_k is not None:
        rad = replace(rad, t_gas_k=cond.t_gas_k)
    return replace(base, options=opts, radiometry=rad,
                   background=Background(kind=cond.background, seed=base.seed))


def _moving_object(cond: Condition) -> MovingObject | None:
    if not cond.moving_object:
        return None
    return WARM_OBJECT if cond.object_z_m is None else replace(WARM_OBJECT, z_m=cond.object_z_m)


def condition_geometry(config: SequenceConfig, cond: Condition) -> StereoGeometry:
    """What the chain knows of the cameras: the simulator's calibration file (curves, and
    rectification maps when the lenses distort), or (for an uncalibrated condition) the
    ideal geometry without characteristic curves or maps."""
    calib = synthetic_calibration(config)
    if not cond.calibrated:
        calib = replace(calib, radiometric=None)
    return StereoGeometry.from_calibration(calib, rectify=cond.calibrated and cond.lens_k1 != 0)


def chain_parameters(config: SequenceConfig) -> ChainParameters:
    """The chain's parameters for a field scene, as a site would set them.

    Registration is on (the daemon's default). The gas depth band is the simulation
    volume's (:func:`appliance.evaluation.sceneflow_setup.band_disparities`: d0 = s b /
    Z_far, the farthest gas, searched over at least 64 px). The joint solver runs
    :data:`FIELD_DISPARITY_OPTIONS`.
    """
    d0, n = scene_band(config)
    return ChainParameters(d0=d0, sgm_num_disparities=n,
                           disparity_options=dict(FIELD_DISPARITY_OPTIONS))


def scene_band(config: SequenceConfig) -> tuple[float, int]:
    """d0 and the SGM range (px) of the gas depth band of a scene's simulated volume."""
    z_near = config.volume_origin_m[2]
    z_far = z_near + config.fluid.shape[0] * config.fluid.voxel_m
    cam = config.effective_camera()
    return band_disparities(cam.s_px, cam.b_m, z_near, z_far)


# ---------------------------------------------------------------------------- evaluation

ParamsHook = Callable[[ChainParameters], ChainParameters]


def scene_frames(matrix: Matrix, scene: Scene, cond: Condition, cache_dir: Path | None,
                 log: Log | None = None
                 ) -> tuple[list[SyntheticFrame], StereoGeometry, ChainParameters]:
    """One scene under one condition as the chain sees it: the rectified frames with their
    truth, the geometry the chain is given and the chain's parameters (the gas simulated
    once per scene and cached in ``cache_dir``)."""
    base = scene_config(scene, matrix, cond.release_rate_g_s, cond.lens_k1)
    gas = gas_frames(base, cache_dir, log)
    cfg = condition_config(base, cond)
    renderer = StereoRenderer(cfg)
    geometry = condition_geometry(cfg, cond)
    frames = [rectified_truth(renderer.render(g), geometry) for g in gas]
    return frames, geometry, chain_parameters(cfg)


def evaluate_condition(matrix: Matrix, cond: Condition, cache_dir: Path | None, *,
                       params_hook: ParamsHook | None = None,
                       log: Log | None = None, workers: int = 1) -> Metrics:
    """Every scene of ``matrix`` under ``cond``: per-scene summaries and the pooled one,
    the triples taken as ``workers`` (1 or 2) daemon workers take them
    (:func:`appliance.evaluation.sceneflow.worker_states`).

    Returns
    -------
    {"condition": asdict(cond), "scenes": {name: summary}, "pooled": aggregate over every
    triple of every scene, "flags": triples per chain flag, "seconds", "workers"}
    """
    start = time.perf_counter()
    scenes: dict[str, Metrics] = {}
    pooled: list[Metrics] = []
    flags: dict[str, int] = {}
    for scene in matrix.scenes:
        frames, geometry, params = scene_frames(matrix, scene, cond, cache_dir, log)
        if params_hook is not None:
            params = params_hook(params)
        summary, _ = evaluate_frames(frames, geometry, params, methods=("proposed",),
                                     name=scene.name, workers=workers)
        scenes[scene.name] = summary["proposed"]
        pooled.extend(summary["proposed"]["frames"])
        for k, v in summary["flags"].items():
            flags[k] = flags.get(k, 0) + v
        if log is not None:
            p = summary["proposed"]
            log(f"  {cond.name:<20} {scene.name:<22} RMVE {_f(p['rmve'])} % "
                f"AEMV {_f(p['aemv'])} deg  false gas {_f(p['false_gas'], 2)}  "
                f"mean V: RMVE {_f(p['rmve_of_mean'])} % AEMV {_f(p['aemv_of_mean'])} deg")
    together = aggregate(pooled)
    # The mean velocity of triples of different scenes means nothing: the pooled figure is
    # the scenes' mean of their own.
    for key in ("rmve_of_mean", "aemv_of_mean"):
        vals = [s[key] for s in scenes.values() if s[key] is not None]
        together[key] = float(np.mean(vals)) if vals else None
    return {"condition": asdict(cond), "scenes": scenes, "pooled": together,
            "flags": flags, "seconds": time.perf_counter() - start, "workers": workers}


def run_matrix(matrix: Matrix, cache_dir: Path | None, *,
               conditions: Sequence[str] | None = None,
               params_hook: ParamsHook | None = None,
               log: Log | None = None, workers: int = 1) -> dict[str, Metrics]:
    """:func:`evaluate_condition` for every (selected) condition, in matrix order."""
    chosen = matrix.conditions
    if conditions:
        names = {c.name for c in matrix.conditions}
        unknown = [c for c in conditions if c not in names]
        if unknown:
            raise ValueError(f"unknown condition(s) {unknown}; the {matrix.name} matrix has: "
                             f"{', '.join(sorted(names))}")
        chosen = tuple(c for c in matrix.conditions if c.name in conditions)
    out: dict[str, Metrics] = {}
    for cond in chosen:
        if log is not None:
            log(f"condition {cond.name} ...")
        out[cond.name] = evaluate_condition(matrix, cond, cache_dir, params_hook=params_hook,
                                            log=log, workers=workers)
    return out


def _f(v: float | None, digits: int = 1) -> str:
    return "n/a" if v is None else f"{v:.{digits}f}"


def _scene_extremes(res: Metrics, key: str) -> float | None:
    vals = [s[key] for s in res["scenes"].values() if s[key] is not None]
    return max(vals) if vals else None


def _of_mean(res: Metrics, key: str) -> str:
    """The scenes' mean of ``key`` with the worst scene's in brackets."""
    return f"{_f(res['pooled'][key])} ({_f(_scene_extremes(res, key))})"


def format_table(results: dict[str, Metrics]) -> str:
    """One row per condition: pooled mean +- std of RMVE and AEMV, the worst scene's mean,
    3D AEE, SA, the false-gas fraction, RMVE and AEMV of each scene's mean velocity (the
    scenes' mean, the worst scene in brackets) and the chain's most frequent flags."""
    head = (f"{'condition':<20} {'real':>4} {'RMVE/%':>12} {'worst':>6} {'AEMV/deg':>12} "
            f"{'worst':>6} {'AEE/mm/s':>9} {'SA/%':>6} {'false':>6} "
            f"{'mean V: RMVE/%':>15} {'AEMV/deg':>13}  flags (triples)")
    lines = [head, "-" * len(head)]
    for name, res in results.items():
        p = res["pooled"]
        fl = ", ".join(f"{k} {v}" for k, v in sorted(res["flags"].items(),
                                                     key=lambda kv: -kv[1]))
        lines.append(
            f"{name:<20} {'yes' if res['condition']['realistic'] else 'no':>4} "
            f"{_f(p['rmve']):>5}+-{_f(p['rmve_std']):<5} {_f(_scene_extremes(res, 'rmve')):>6} "
            f"{_f(p['aemv']):>5}+-{_f(p['aemv_std']):<5} {_f(_scene_extremes(res, 'aemv')):>6} "
            f"{_f(p['aee_3d_mm_s'], 0):>9} {_f(p['sa']):>6} {_f(p['false_gas'], 2):>6} "
            f"{_of_mean(res, 'rmve_of_mean'):>15} {_of_mean(res, 'aemv_of_mean'):>13}  {fl}")
    return "\n".join(lines)


def acceptance(results: dict[str, Metrics]) -> list[str]:
    """The realistic conditions that miss a target, one line each (empty: all met)."""
    misses = []
    for name, res in results.items():
        if not res["condition"]["realistic"]:
            continue
        p = res["pooled"]
        for key, limit in TARGET_MEAN.items():
            if p[key] is None or p[key] > limit:
                misses.append(f"{name}: mean {key.upper()} {_f(p[key])} > {limit:g}")
        for key, limit in TARGET_WORST.items():
            worst = _scene_extremes(res, key)
            if worst is None or worst > limit:
                misses.append(f"{name}: worst scene {key.upper()} {_f(worst)} > {limit:g}")
    return misses


def public(results: dict[str, Metrics]) -> dict[str, Any]:
    """The JSON document: per condition the pooled and per-scene summaries, flags and time
    (per-triple values left out: 22 conditions x 4 scenes of them make a megabyte)."""
    out: dict[str, Any] = {}
    for name, res in results.items():
        pooled = {k: v for k, v in res["pooled"].items() if k != "frames"}
        scenes = {sc: {k: v for k, v in summ.items() if k != "frames"}
                  for sc, summ in res["scenes"].items()}
        out[name] = {**res, "pooled": pooled, "scenes": scenes}
    return out
