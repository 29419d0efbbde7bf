"""Benchmark of the synthetic data generator (target: three sequences < 5 min).

Run from the repository root::

    .venv/bin/python benchmarks/bench_synthetic.py [--out DIR] [--skip-field]

Prints, after a warm-up that compiles the numba kernels:

- the median time of one fluid step on the 100^3 grid and of one stereo render with ground
  truth (medians of 5 runs),
- the wall time to generate and write the three Table-2 sequences (what ``ogiflow simulate``
  does by default), per sequence and in total, with their Table-2 characteristics,
- the time per frame of the ``field`` preset (the appliance's simulated cameras) at 3 cm and
  6 cm voxels.
The machine is shared: compare the total with the sum of the parts measured in the same run.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

from processing.synthetic.fluid import FluidSimulation
from processing.synthetic.render import Volume, column_integrals, ray_directions
from processing.synthetic.sequences import (
    TABLE2_PRESETS,
    SyntheticStereoScene,
    frame_characteristics,
    generate_sequence,
    preset,
    sequence_characteristics,
)
from processing.synthetic.storage import write_sequence


def _median_time(fn, runs: int = 5) -> float:
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, help="where to write (default: a temporary directory)")
    ap.add_argument("--skip-field", action="store_true", help="skip the field-preset timing")
    args = ap.parse_args()

    # warm-up: compile (or load cached) kernels on a small grid
    small = preset("table2_1", n_frames=1, spinup_steps=2)
    from dataclasses import replace

    small = replace(small, fluid=replace(small.fluid, shape=(16, 16, 16), voxel_m=0.025))
    list(generate_sequence(small))

    cfg = preset("table2_1")
    sim = FluidSimulation(cfg.fluid, seed=0)
    for _ in range(3):
        sim.step()
    t_step = _median_time(sim.step)
    vol = Volume(cfg.volume_origin_m, cfg.fluid.voxel_m, cfg.fluid.shape)
    dirs = ray_directions(cfg.camera)
    c = sim.state.c * 1e6 / cfg.radiometry.gas_density_kg_m3
    vel = sim.state.cell_velocity()

    def render() -> None:  # what one frame costs: left with ground truth, right
        column_integrals(c, vol, dirs, 0.0, velocity=vel)
        column_integrals(c, vol, dirs, cfg.camera.b_m)

    t_render = _median_time(render)
    print(f"fluid step 100^3 (median of 5): {t_step * 1e3:.0f} ms")
    print(f"stereo render + ground truth 320x240 (median of 5): {t_render * 1e3:.0f} ms")
    n_steps = cfg.spinup_steps + cfg.n_frames * cfg.substeps
    expected = 3 * (n_steps * t_step + cfg.n_frames * t_render)
    print(f"expected per 3 sequences from the parts: {expected:.1f} s "
          f"({n_steps} steps + {cfg.n_frames} renders each)")

    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp)
        total0 = time.perf_counter()
        for name in TABLE2_PRESETS:
            cfg = preset(name)
            per_frame = []

            def frames(cfg=cfg, per_frame=per_frame):
                for f in generate_sequence(cfg):
                    per_frame.append(frame_characteristics(f))
                    yield f

            t0 = time.perf_counter()
            write_sequence(out / name, cfg.meta(), frames())
            st = sequence_characteristics(per_frame)
            print(
                f"{name}: {time.perf_counter() - t0:.1f} s  |V*avg| {st['speed_avg_m_s']:.2f} m/s"
                f"  angles {np.round(st['angles_deg'], 1).tolist()} deg"
                f"  sd|V*| {st['speed_std_m_s']:.2f} m/s  N {st['n_px']:.0f} px"
            )
        total = time.perf_counter() - total0
        print(f"three Table-2 sequences generated and written in {total:.1f} s "
              f"(target < 300 s; {total / expected:.2f} x the sum of the parts)")

    if not args.skip_field:
        for voxel in (0.03, 0.06):
            scene = SyntheticStereoScene(preset("field", voxel_m=voxel))
            scene.next_frame()
            t_frame = _median_time(scene.next_frame)
            print(f"field preset, {voxel * 100:.0f} cm voxels {scene.config.fluid.shape}: "
                  f"{t_frame * 1e3:.0f} ms per 30 Hz frame (median of 5) "
                  f"-> {1.0 / t_frame:.1f} frames/s on one core")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
