"""Synthetic stereo OGI sequences: a frame-by-frame scene and sequence generation.

The fluid is first spun up (larger steps allowed) so the plume exists, then frames are recorded.
Frame ``i`` holds the images of the state at ``t_i`` and the ground-truth velocity that carries
that gas to frame ``i + 1`` (see :mod:`processing.synthetic.storage`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import replace
from typing import Any

import numpy as np

from processing.synthetic.cameras import GasFrame, StereoRenderer
from processing.synthetic.config import RenderOptions, SequenceConfig
from processing.synthetic.fluid import FluidSimulation
from processing.synthetic.presets import (
    PRESETS,
    TABLE2_PRESETS,
    preset,
    preset_field,
    preset_table2_1,
    preset_table2_2,
    preset_table2_3,
)
from processing.synthetic.render import Volume, column_integrals, ground_truth, ray_directions
from processing.synthetic.storage import SyntheticFrame

__all__ = [
    "PRESETS", "TABLE2_PRESETS", "GasFrame", "RenderOptions", "SequenceConfig",
    "SyntheticStereoScene", "frame_characteristics", "generate_sequence", "preset",
    "preset_field", "preset_table2_1", "preset_table2_2", "preset_table2_3",
    "sequence_characteristics",
]


class SyntheticStereoScene:
    """A running simulation that renders stereo frames with ground truth, one at a time.

    Used by :func:`generate_sequence` and by the appliance's simulated cameras (which may change
    the wind between frames with :meth:`set_wind`).

    Parameters
    ----------
    config : SequenceConfig
    spin_up : bool
        Run the configured spin-up immediately.
    """

    def __init__(self, config: SequenceConfig, spin_up: bool = True):
        config.validate()
        self.config = config
        self.camera = config.effective_camera()
        self.volume = Volume(config.volume_origin_m, config.fluid.voxel_m, config.fluid.shape)
        self.dirs = ray_directions(self.camera)
        self.sim = FluidSimulation(config.fluid, seed=config.seed)
        self.renderer = StereoRenderer(config)  # camera effects: own random stream
        self.frame_index = 0
        if spin_up and config.spinup_steps:
            self.spin_up(config.spinup_steps, config.spinup_dt_s)

    def spin_up(self, steps: int, dt_s: float) -> None:
        """Advance the fluid without recording (step ``dt_s``).

        The spin-up is the end of the previous cycle of a release schedule (its steps at
        negative times, taken modulo the period), so a looped scheduled scene starts from
        the gas that the end of its own cycle leaves.
        """
        rec = self.sim.params
        self.sim.params = replace(rec, dt_s=dt_s)
        try:
            for k in range(steps):
                self._step_at(-(steps - k) * dt_s)
        finally:
            self.sim.params = rec

    def _step_at(self, t_s: float) -> None:
        """One fluid step starting at scene time ``t_s`` (s; 0 = first frame), with the
        release switched by the schedule. A state without sources, gas or any velocity but
        the uniform wind is steady: no step is computed (the no-release scene)."""
        if not self.config.fluid.sources and self._steady():
            return
        schedule = self.config.release_schedule
        self.sim.release_on = schedule is None or schedule.is_on(t_s)
        self.sim.step()

    def _steady(self) -> bool:
        st, wind = self.sim.state, self.sim.wind_m_s
        return bool(not st.c.any() and np.all(st.u == wind[0]) and np.all(st.v == wind[1])
                    and np.all(st.w == wind[2]))

    def release_rate_g_s(self, t_s: float) -> float:
        """The true release rate at scene time ``t_s`` (mean over the puffing), g/s."""
        rate = float(sum(s.release_rate_g_s for s in self.config.fluid.sources))
        schedule = self.config.release_schedule
        return rate if schedule is None else rate * schedule.rate_factor(t_s)

    def set_wind(self, wind_m_s: np.ndarray | tuple[float, float, float]) -> None:
        """Change the ambient wind (left camera frame, m/s) from the next step on."""
        self.sim.set_wind(wind_m_s)

    def next_gas(self) -> GasFrame:
        """The current state's gas columns and ground truth (no camera effect), then advance
        the fluid to the next frame's time."""
        cfg = self.config
        st = self.sim.state
        to_ppm = 1e6 / cfg.radiometry.gas_density_kg_m3
        c_ppm = st.c * to_ppm
        t_s = self.frame_index * cfg.frame_interval_s
        # Velocity that carries this frame's gas to the next frame: mean over the sub-steps
        # (the state's arrays are replaced, not modified, by a step, so c_ppm stays this frame's).
        vel = np.zeros((3, *st.c.shape))
        released_kg = self.sim.released_kg
        for j in range(cfg.substeps):
            self._step_at(t_s + j * cfg.fluid.dt_s)
            vel += self.sim.state.cell_velocity()
        vel /= cfg.substeps
        release_g_s = (self.sim.released_kg - released_kg) * 1e3 / cfg.frame_interval_s
        moment = np.zeros((*self.dirs.shape[:2], 3))
        if c_ppm.any():
            col_l, zsum, vsum = column_integrals(c_ppm, self.volume, self.dirs, 0.0,
                                                 velocity=vel, moment_out=moment)
            col_r, _, _ = column_integrals(c_ppm, self.volume, self.dirs, self.camera.b_m)
        else:  # no gas anywhere: every line integral is exactly zero (no need to march)
            col_l, zsum, col_r = (np.zeros(self.dirs.shape[:2]) for _ in range(3))
            vsum = np.zeros((*self.dirs.shape[:2], 3))
        gt = ground_truth(col_l, zsum, vsum, self.dirs, cfg.necl_ppm_m)
        # The flux truth in kg/s: the moment was integrated over c in ppm.
        gt.flux_moment_kg_s = (moment / to_ppm).astype(np.float32)
        gt.release_rate_g_s = float(release_g_s)
        gas = GasFrame(index=self.frame_index, t_s=t_s, column_left=col_l, column_right=col_r,
                       truth=gt)
        self.frame_index += 1
        return gas

    def next_frame(self) -> SyntheticFrame:
        """Render the current state, then advance the fluid to the next frame's time."""
        return self.renderer.render(self.next_gas())


def generate_sequence(
    config: SequenceConfig, progress: Callable[[int, int], None] | None = None
) -> Iterator[SyntheticFrame]:
    """Yield the ``config.n_frames`` frames of a sequence (spin-up first).

    ``progress(done, total)`` is called after the spin-up (done = 0) and after each frame.
    """
    scene = SyntheticStereoScene(config)
    if progress is not None:
        progress(0, config.n_frames)
    for i in range(config.n_frames):
        frame = scene.next_frame()
        if progress is not None:
            progress(i + 1, config.n_frames)
        yield frame


def frame_characteristics(frame: SyntheticFrame) -> dict[str, Any]:
    """Table 2's per-frame characteristics of the ground truth over the gas mask.

    Returns
    -------
    dict with ``v_avg_m_s`` (3,) mean V*, ``speed_avg_m_s`` = |mean V*|, ``angles_deg`` (3,)
    directional angles arccos(V_avg / |V_avg|) (paper footnote 1), ``speed_std_m_s`` (std of
    the pixelwise |V*|), ``n_px`` (gas pixels); NaN entries when the mask is empty.
    """
    v = frame.gt_velocity[frame.gt_mask].astype(np.float64)
    if len(v) == 0:
        nan3 = [float("nan")] * 3
        return {"v_avg_m_s": nan3, "speed_avg_m_s": float("nan"), "angles_deg": nan3,
                "speed_std_m_s": float("nan"), "n_px": 0}
    avg = v.mean(axis=0)
    speed = float(np.linalg.norm(avg))
    angles = np.degrees(np.arccos(np.clip(avg / speed, -1.0, 1.0))) if speed > 0 else avg * np.nan
    return {
        "v_avg_m_s": [float(x) for x in avg],
        "speed_avg_m_s": speed,
        "angles_deg": [float(x) for x in angles],
        "speed_std_m_s": float(np.linalg.norm(v, axis=1).std()),
        "n_px": len(v),
    }


def sequence_characteristics(per_frame: list[dict[str, Any]]) -> dict[str, Any]:
    """Average :func:`frame_characteristics` over frames (the rows of the paper's Table 2)."""
    if not per_frame:
        raise ValueError("no frames to characterise")
    return {
        "speed_avg_m_s": float(np.mean([f["speed_avg_m_s"] for f in per_frame])),
        "angles_deg": [float(x) for x in np.mean([f["angles_deg"] for f in per_frame], axis=0)],
        "speed_std_m_s": float(np.mean([f["speed_std_m_s"] for f in per_frame])),
        "n_px": float(np.mean([f["n_px"] for f in per_frame])),
        "n_frames": len(per_frame),
    }
