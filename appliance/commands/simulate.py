"""``ogiflow simulate``: generate synthetic stereo OGI sequences with ground truth.

Writes one directory per sequence in the ``ogiflow-synthetic/1`` format (see
:mod:`processing.synthetic.storage`); by default the three Table-2-like sequences.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from appliance.cli import CommandError
from appliance.progress import ProgressBar

#: The calibration file written beside each sequence's frames.
CALIBRATION_NAME = "calibration.yaml"

_PRESET_HELP = (
    "preset to generate (repeatable): table2 (= table2_1, table2_2, table2_3; the default), "
    "table2_1, table2_2, table2_3, field, no_release (the field site without gas: noise, "
    "jitter, a warm person walking to and fro, background drift, plant wall; for false-alarm "
    "tests)"
)


def register(root: argparse._SubParsersAction) -> None:
    """Add the ``simulate`` subcommand."""
    p = root.add_parser(
        "simulate",
        help="generate synthetic stereo gas sequences with ground truth",
        description=(
            "Simulate a buoyant gas release (Stable Fluids), render it into a left and a right "
            "OGI camera (Eq. 1) and write raw uint16 frames with the left camera's ground truth "
            "(3D velocity V*, 3D position, gas mask, column density) to OUT/<preset>/, with the "
            "matching calibration file (calibration.yaml: geometry, lens distortion, both "
            "cameras' characteristic curves). "
            "Without --preset, the three sequences resembling the paper's Table 2 are written."
        ),
    )
    p.add_argument("--out", required=True, type=Path, help="output directory")
    p.add_argument("--preset", action="append", metavar="NAME", help=_PRESET_HELP)
    p.add_argument("--frames", type=int, help="number of frames (default: the preset's)")
    p.add_argument("--seed", type=int, help="random seed (default: the preset's fixed seed)")
    p.add_argument("--wind", type=float, nargs=3, metavar=("X", "Y", "Z"),
                   help="ambient wind in the left camera frame (X right, Y down, Z forward), m/s")
    p.add_argument("--baseline", type=float, metavar="M",
                   help="stereo baseline b in m (default 0.2; field preset 0.3)")
    p.add_argument("--release-rate", type=float, metavar="G_S", help="mean release rate in g/s")
    p.add_argument("--distance", type=float, metavar="M",
                   help="distance of the plume from the cameras in m (field preset only; "
                        "default 5.5)")
    p.add_argument("--volume-depth", type=float, metavar="M",
                   help="depth of the simulated volume along Z in m, field preset only "
                        "(default 1.44; at most 12): it grows downwind, the source stays. A "
                        "wind with a Z component otherwise carries the gas out through the "
                        "volume's far or near face inside the view, where it vanishes in "
                        "mid-image (simulate says so when it does); e.g. 2.88 for a plume "
                        "45 deg out of the image plane. Costs time in proportion")
    p.add_argument("--name", metavar="NAME",
                   help="name of the sequence folder (one preset only; default: the preset's)")
    p.add_argument("--necl", type=float, metavar="PPM_M",
                   help="detection limit for the ground-truth gas mask, ppm*m (default 100)")
    p.add_argument("--grid-scale", type=float, default=1.0, metavar="F",
                   help="scale the number of cells per axis by F, keeping the physical volume "
                        "(default 1; e.g. 0.5 for a quick coarse look)")
    p.add_argument("--spinup-steps", type=int, metavar="N",
                   help="simulation steps before the first frame (default: the preset's)")
    p.add_argument("--release-schedule", metavar="ON:OFF[,ON:OFF...]",
                   help="switch the release on and off: intervals in s from the first frame, "
                        "e.g. 1:9,15:20; the sequence's length is the schedule's period "
                        "(default: always on)")
    noise = p.add_argument_group("non-ideal camera effects (off by default, as in Sec. 5.1; "
                                 "no_release has its own)")
    noise.add_argument("--noise", type=float, default=None, metavar="NETD_K",
                       help="temporal noise as a NETD in K, e.g. 0.03 (default 0: none)")
    noise.add_argument("--jitter", type=float, default=None, metavar="PX",
                       help="std. dev. of a random per-frame shift of each camera, px (default 0)")
    noise.add_argument("--radiometric-mismatch", action="store_true",
                       help="right camera with 4%% more gain and 150 counts more offset")
    noise.add_argument("--gain-mismatch", type=float, default=0.0, metavar="FRACTION",
                       help="right camera's relative gain excess, e.g. 0.02-0.08, with 150 "
                            "counts more offset (overrides the 4%% of --radiometric-mismatch)")
    noise.add_argument("--lens-k1", type=float, default=0.0, metavar="K1",
                       help="radial lens distortion k1 of both cameras (default 0)")
    noise.add_argument("--moving-object", action="store_true",
                       help="a warm disk moving behind the gas")
    scene = p.add_argument_group("scene")
    scene.add_argument("--background", choices=("uniform", "plant", "sky"), default=None,
                       help="what lies behind the gas: a uniform black body (default, the "
                            "paper's scenes), a textured wall of plant equipment 12 m away, "
                            "or clear sky")
    scene.add_argument("--gas-temperature", type=float, metavar="K",
                       help="gas temperature in K (default 285 against a 300 K background; "
                            "e.g. 297 for a low-contrast scene)")
    p.add_argument("--force", action="store_true",
                   help="overwrite sequences that already exist in OUT")
    p.set_defaults(func=run)


def _expand_presets(names: list[str] | None) -> list[str]:
    # Imported when the command runs: the CLI imports every command module for its parser.
    from processing.synthetic.sequences import PRESETS, TABLE2_PRESETS

    out: list[str] = []
    for name in names or ["table2"]:
        expanded = list(TABLE2_PRESETS) if name == "table2" else [name]
        for n in expanded:
            if n not in PRESETS:
                raise ValueError(
                    f"unknown preset {n!r}; choose from table2, {', '.join(PRESETS)}"
                )
            if n not in out:
                out.append(n)
    return out


def _build_config(name: str, args: argparse.Namespace) -> Any:
    """The scene of preset ``name`` with the command line's changes (ValueError: out of
    range), validated."""
    cfg = _preset_scene(name, args)
    cfg = _run_settings(cfg, args)
    cfg = replace(cfg, options=_render_options(cfg.options, args))
    if args.release_schedule:
        if not cfg.fluid.sources:
            raise ValueError(f"--release-schedule: preset {name} releases no gas")
        cfg = replace(cfg, release_schedule=_schedule(args.release_schedule,
                                                      cfg.n_frames * cfg.frame_interval_s))
    cfg.validate()
    return cfg


def _preset_scene(name: str, args: argparse.Namespace) -> Any:
    """The preset with the scene's geometry, wind, release and grid from the command line
    (the field preset takes them as its own parameters, the others as replaced fields)."""
    # Imported when the command runs: the CLI imports every command module for its parser.
    from processing.synthetic.sequences import preset

    kwargs: dict[str, Any] = {}
    if name == "field":
        if args.wind is not None:
            kwargs["wind_m_s"] = tuple(args.wind)
        if args.baseline is not None:
            kwargs["b_m"] = args.baseline
        if args.release_rate is not None:
            kwargs["release_rate_g_s"] = args.release_rate
        if args.distance is not None:
            if not 1.0 <= args.distance <= 100.0:
                raise ValueError(f"--distance must be within 1..100 m, got {args.distance}")
            kwargs["distance_m"] = args.distance
        if args.volume_depth is not None:
            if not 1.44 <= args.volume_depth <= 12.0:
                raise ValueError(f"--volume-depth must be within 1.44..12 m, got "
                                 f"{args.volume_depth}")
            kwargs["depth_m"] = args.volume_depth
    elif args.distance is not None or args.volume_depth is not None:
        raise ValueError("--distance and --volume-depth apply to the field preset only")
    cfg = preset(name, **kwargs)
    if args.name is not None:
        cfg = replace(cfg, name=args.name)
    fluid = cfg.fluid
    if name != "field":
        if args.wind is not None:
            fluid = replace(fluid, wind_m_s=tuple(args.wind))
        if args.release_rate is not None:
            fluid = replace(fluid, sources=tuple(
                replace(s, release_rate_g_s=args.release_rate) for s in fluid.sources))
        if args.baseline is not None:
            cfg = replace(cfg, camera=replace(cfg.camera, b_m=args.baseline))
    if args.grid_scale != 1.0:
        if not 0.05 <= args.grid_scale <= 4.0:
            raise ValueError(f"--grid-scale must be within 0.05..4, got {args.grid_scale}")
        shape = tuple(max(8, round(n * args.grid_scale)) for n in fluid.shape)
        voxel = fluid.voxel_m * fluid.shape[2] / shape[2]
        fluid = replace(fluid, shape=shape, voxel_m=voxel)
    return replace(cfg, fluid=fluid)


def _run_settings(cfg: Any, args: argparse.Namespace) -> Any:
    """Frames, seed, spin-up, NECL, gas temperature and background from the command line."""
    if args.frames is not None:
        if args.frames < 1:
            raise ValueError(f"--frames must be >= 1, got {args.frames}")
        cfg = replace(cfg, n_frames=args.frames)
    if args.seed is not None:
        cfg = replace(cfg, seed=args.seed)
    if args.spinup_steps is not None:
        if args.spinup_steps < 0:
            raise ValueError(f"--spinup-steps must be >= 0, got {args.spinup_steps}")
        cfg = replace(cfg, spinup_steps=args.spinup_steps)
    if args.necl is not None:
        if args.necl <= 0:
            raise ValueError(f"--necl must be > 0, got {args.necl}")
        cfg = replace(cfg, necl_ppm_m=args.necl)
    if args.gas_temperature is not None:
        if not 150.0 <= args.gas_temperature <= 400.0:
            raise ValueError(f"--gas-temperature must be within 150..400 K, got "
                             f"{args.gas_temperature}")
        cfg = replace(cfg, radiometry=replace(cfg.radiometry, t_gas_k=args.gas_temperature))
    if args.background is not None:
        cfg = replace(cfg, background=replace(cfg.background, kind=args.background))
    return replace(cfg, background=replace(cfg.background, seed=cfg.seed))


def _render_options(base: Any, args: argparse.Namespace) -> Any:
    """The camera effects: the command line's over the preset's own (``base``: its
    no_release and moving object, else none)."""
    # Imported when the command runs: the CLI imports every command module for its parser.
    from processing.synthetic.imaging import MovingObject
    from processing.synthetic.sequences import RenderOptions

    return RenderOptions(
        noise_netd_k=base.noise_netd_k if args.noise is None else args.noise,
        jitter_px=base.jitter_px if args.jitter is None else args.jitter,
        radiometric_mismatch=args.radiometric_mismatch,
        gain_mismatch=args.gain_mismatch,
        lens_k1=args.lens_k1,
        moving_object=base.moving_object or (MovingObject() if args.moving_object else None),
    )


def _schedule(text: str, period_s: float) -> Any:
    """``ON:OFF[,ON:OFF...]`` (s) as a release schedule over the sequence's length."""
    # Imported when the command runs: the CLI imports every command module for its parser.
    from processing.synthetic.schedule import ReleaseSchedule

    try:
        pairs = [[float(v) for v in part.split(":")] for part in text.split(",")]
    except ValueError:
        raise ValueError(f"--release-schedule: expected ON:OFF[,ON:OFF...] in s, got "
                         f"{text!r}") from None
    if any(len(p) != 2 for p in pairs):
        raise ValueError(f"--release-schedule: expected ON:OFF[,ON:OFF...] in s, got {text!r}")
    try:
        return ReleaseSchedule.from_lists(pairs, period_s)
    except ValueError as exc:
        raise ValueError(f"--release-schedule: {exc} (the sequence lasts {period_s:g} s)"
                         ) from None


def run(args: argparse.Namespace) -> int:
    """Generate the requested sequences; print one summary line per sequence."""
    # Imported when the command runs: the CLI imports every command module for its parser.
    from processing.calibration import save_calibration
    from processing.synthetic.config import synthetic_calibration
    from processing.synthetic.sequences import (
        frame_characteristics,
        generate_sequence,
        sequence_characteristics,
    )
    from processing.synthetic.storage import META_NAME, write_meta, write_sequence
    from processing.synthetic.volume_exit import sequence_plume_exit

    names = _expand_presets(args.preset)
    if args.name is not None and len(names) != 1:
        raise ValueError("--name needs exactly one preset")
    configs = [_build_config(n, args) for n in names]
    out: Path = args.out
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} exists and is not a directory")
    for cfg in configs:
        target = out / cfg.name
        if (target / META_NAME).exists() and not args.force:
            raise ValueError(f"{target} already holds a sequence; use --force to overwrite")
    total_start = time.perf_counter()
    for cfg in configs:
        target = out / cfg.name
        per_frame: list[dict[str, Any]] = []

        def frames(cfg: Any = cfg, per_frame: list[dict[str, Any]] = per_frame) -> Any:
            bar = ProgressBar(cfg.name, sys.stderr, unit="frames")
            for f in generate_sequence(cfg, progress=bar):
                per_frame.append(frame_characteristics(f))
                yield f

        start = time.perf_counter()
        try:
            write_sequence(target, cfg.meta(), frames())
        except OSError as exc:
            raise CommandError(f"writing {target} failed: {exc}") from exc
        stats = sequence_characteristics(per_frame)
        meta = cfg.meta()
        meta["statistics"] = stats
        write_meta(target, meta)
        # The calibration a field system would have (curves, lens distortion): evaluating
        # with it shows what a site's calibration removes.
        save_calibration(target / CALIBRATION_NAME, synthetic_calibration(cfg))
        ang = ", ".join(f"{a:.1f}" for a in stats["angles_deg"])
        print(
            f"{cfg.name}: {cfg.n_frames} frames -> {target}"
            f"  |V*avg| {stats['speed_avg_m_s']:.2f} m/s"
            f"  angles (X, Y, Z) ({ang}) deg  sd|V*| {stats['speed_std_m_s']:.2f} m/s"
            f"  N {stats['n_px']:.0f} px  ({time.perf_counter() - start:.1f} s)"
        )
        leave = sequence_plume_exit(meta)
        if leave is not None and leave.vanishes_in_view:
            print(f"{cfg.name}: note: the plume leaves the simulated volume through its "
                  f"{leave.describe()}: its gas vanishes in mid-image (use --volume-depth "
                  "for a plume that leaves through the side of the view)")
    print(f"total {time.perf_counter() - total_start:.1f} s for {len(configs)} sequence(s)")
    return 0
