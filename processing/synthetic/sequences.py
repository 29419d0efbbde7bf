"""Synthetic stereo OGI sequences: presets, a frame-by-frame scene, and sequence generation.

Presets
-------
``table2_1``, ``table2_2``, ``table2_3`` resemble the paper's Table 2 (Sec. 5.1): a 100^3 grid of
4 mm voxels centred about 2 m in front of the cameras, 1 ms steps, 11 frames, a buoyant methane
jet whose main direction differs per sequence (1: upward with small X/Z parts, 2: upward and to
the right, 3: upward, to the left and towards the cameras), mean |V*| about 2.7-3.3 m/s. Each is
a turbulent jet (6 cm wide, 4-5 m/s, leaving as ~40 % methane by volume at 4 g/s) inside a slow
ambient co-flow (the preset's "wind", 1.1-1.5 m/s, mostly upward); the co-flow sets the main
direction, the jet and its seeded turbulence the spread of |V*| (Table 2's sigma, ~1 m/s).
Measured characteristics (ogiflow simulate prints them; paper's Table 2 in brackets):
|V*avg| 3.21 (3.27), 2.71 (2.67), 2.65 (2.68) m/s; angles (83.9, 173.7, 91.4) (86.7, 176.0,
92.3), (69.6, 159.3, 93.6) (71.0, 161.0, 89.3), (102.8, 158.0, 107.7) (101.3, 160.4, 105.8)
deg; sigma 1.18 (1.38), 1.15 (0.97), 0.89 (1.25) m/s; N 6006 (8088), 6908 (7491), 6725 (8023)
px.
``field`` imitates the appliance's cameras: 30 Hz frames (simulation sub-steps inside), a plume
about 5.5 m away on 3 cm voxels, a configurable baseline and the anemometer's wind.

The fluid is first spun up (larger steps allowed) so the plume exists, then frames are recorded.
Frame ``i`` holds the images of the state at ``t_i`` and the ground-truth velocity that carries
that gas to frame ``i + 1`` (see :mod:`processing.synthetic.storage`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from processing.synthetic.fluid import FluidParams, FluidSimulation, GasSource
from processing.synthetic.render import (
    CountsModel,
    MovingObject,
    Radiometry,
    StereoCamera,
    Volume,
    background_radiance,
    band_radiance_derivative,
    column_integrals,
    ground_truth,
    radiance_image,
    ray_directions,
    shift_image,
    to_counts,
)
from processing.synthetic.storage import FORMAT, SyntheticFrame

#: The presets that ``ogiflow simulate`` writes by default.
TABLE2_PRESETS: tuple[str, ...] = ("table2_1", "table2_2", "table2_3")


@dataclass(frozen=True)
class RenderOptions:
    """Non-ideal camera effects; all off by default (the paper's ideal conditions, Sec. 5.1).

    Parameters
    ----------
    noise_netd_k : float
        Temporal noise per pixel as a noise-equivalent temperature difference in K at the
        background temperature (Gaussian; e.g. 0.03), 0 = none.
    jitter_px : float
        Standard deviation of a random sub-pixel translation of each camera's frame, px.
    radiometric_mismatch : bool
        Give the right camera a 4 % higher gain and a 150-count higher offset.
    lens_k1, lens_k2 : float
        Radial distortion of both lenses (see :class:`StereoCamera`).
    moving_object : MovingObject or None
        A disk of another temperature moving behind the gas.
    """

    noise_netd_k: float = 0.0
    jitter_px: float = 0.0
    radiometric_mismatch: bool = False
    lens_k1: float = 0.0
    lens_k2: float = 0.0
    moving_object: MovingObject | None = None

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first bad option."""
        if self.noise_netd_k < 0 or self.jitter_px < 0:
            raise ValueError("noise_netd_k and jitter_px must be >= 0")

    def to_json(self) -> dict[str, Any]:
        """JSON-able form for ``meta.json``."""
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class SequenceConfig:
    """Everything that defines a synthetic sequence (reproducible from this and the seed).

    Parameters
    ----------
    name : str
    fluid : FluidParams
        Recording-time fluid parameters (``dt_s`` is the step while recording).
    volume_origin_m : (3,)
        Corner of the grid in the left camera frame, m.
    n_frames : int
    substeps : int
        Fluid steps per frame (frame interval = ``substeps * fluid.dt_s``).
    spinup_steps : int
    spinup_dt_s : float
        Steps run before the first frame, with their own (possibly larger) step.
    seed : int
    camera, radiometry, counts_left, counts_right, options
        Rendering (see :mod:`processing.synthetic.render`).
    necl_ppm_m : float
        Detection limit for the ground-truth gas mask, ppm*m.
    """

    name: str
    fluid: FluidParams
    volume_origin_m: tuple[float, float, float]
    n_frames: int = 11
    substeps: int = 1
    spinup_steps: int = 50
    spinup_dt_s: float = 0.002
    seed: int = 0
    camera: StereoCamera = field(default_factory=StereoCamera)
    radiometry: Radiometry = field(default_factory=Radiometry)
    counts_left: CountsModel = field(default_factory=CountsModel)
    counts_right: CountsModel = field(default_factory=CountsModel)
    options: RenderOptions = field(default_factory=RenderOptions)
    necl_ppm_m: float = 100.0

    @property
    def frame_interval_s(self) -> float:
        """Time between frames, s."""
        return self.substeps * self.fluid.dt_s

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first bad parameter."""
        self.fluid.validate()
        self.camera.validate()
        self.options.validate()
        if self.n_frames < 1 or self.substeps < 1 or self.spinup_steps < 0:
            raise ValueError("n_frames and substeps must be >= 1, spinup_steps >= 0")
        if not self.spinup_dt_s > 0:
            raise ValueError("spinup_dt_s must be > 0")
        if self.volume_origin_m[2] <= 0:
            raise ValueError("the volume must lie in front of the cameras (origin Z > 0)")

    def effective_camera(self) -> StereoCamera:
        """The camera with the options applied (lens distortion)."""
        opts = self.options
        return replace(self.camera, k1=opts.lens_k1 or self.camera.k1,
                       k2=opts.lens_k2 or self.camera.k2)

    def effective_counts(self) -> tuple[CountsModel, CountsModel]:
        """(left, right) counts models with the options applied (radiometric mismatch)."""
        right = self.counts_right
        if self.options.radiometric_mismatch:
            right = CountsModel(gain=right.gain * 1.04, offset=right.offset + 150.0)
        return self.counts_left, right

    def meta(self) -> dict[str, Any]:
        """The ``meta.json`` object of this sequence (format ``ogiflow-synthetic/1``); camera
        and counts models are the effective ones (options applied)."""
        cam = self.effective_camera()
        counts_left, counts_right = self.effective_counts()
        fl = self.fluid
        rad = self.radiometry
        return {
            "format": FORMAT,
            "name": self.name,
            "seed": int(self.seed),
            "n_frames": int(self.n_frames),
            "frame_interval_s": float(self.frame_interval_s),
            "camera": {
                "width": cam.width, "height": cam.height, "s_px": cam.s_px,
                "cx_px": cam.cx, "cy_px": cam.cy, "b_m": cam.b_m, "k1": cam.k1, "k2": cam.k2,
            },
            "counts_model": {
                "left": dataclasses.asdict(counts_left),
                "right": dataclasses.asdict(counts_right),
            },
            "radiometry": {
                "t_bg_k": rad.t_bg_k, "t_gas_k": rad.t_gas_k,
                "alpha_per_ppm_m": rad.alpha_per_ppm_m, "band_um": list(rad.band_um),
                "gas_density_kg_m3": rad.gas_density_kg_m3,
            },
            "necl_ppm_m": self.necl_ppm_m,
            "release_rate_g_s": float(sum(s.release_rate_g_s for s in fl.sources)),
            "wind_m_s": [float(x) for x in fl.wind_m_s],
            "simulation": {
                "method": "stable fluids (Stam 1999), MAC grid, exact DST/DCT projection",
                "grid_zyx": list(fl.shape),
                "voxel_m": fl.voxel_m,
                "dt_s": fl.dt_s,
                "substeps_per_frame": self.substeps,
                "spinup_steps": self.spinup_steps,
                "spinup_dt_s": self.spinup_dt_s,
                "boundary": fl.boundary,
                "volume_origin_m": list(self.volume_origin_m),
                "concentration_unit": "kg/m^3",
                "sources": [dataclasses.asdict(s) for s in fl.sources],
            },
            "options": self.options.to_json(),
            "ground_truth": (
                "gt_velocity[i]: velocity carrying frame i's gas to frame i+1, path-averaged "
                "and concentration-weighted along the left camera's rays (m/s, left frame)"
            ),
        }


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
        self.counts_left, self.counts_right = config.effective_counts()
        self.volume = Volume(config.volume_origin_m, config.fluid.voxel_m, config.fluid.shape)
        self.dirs = ray_directions(self.camera)
        self.sim = FluidSimulation(config.fluid, seed=config.seed)
        self.rng = np.random.default_rng([config.seed, 1])  # camera effects: own stream
        self.frame_index = 0
        if spin_up and config.spinup_steps:
            self.spin_up(config.spinup_steps, config.spinup_dt_s)

    def spin_up(self, steps: int, dt_s: float) -> None:
        """Advance the fluid without recording (step ``dt_s``)."""
        rec = self.sim.params
        self.sim.params = replace(rec, dt_s=dt_s)
        try:
            for _ in range(steps):
                self.sim.step()
        finally:
            self.sim.params = rec

    def set_wind(self, wind_m_s: np.ndarray | tuple[float, float, float]) -> None:
        """Change the ambient wind (left camera frame, m/s) from the next step on."""
        self.sim.set_wind(wind_m_s)

    def _render(self, column_ppm_m: np.ndarray, camera_x_m: float, t_s: float,
                model: CountsModel) -> tuple[np.ndarray, np.ndarray]:
        opts = self.config.options
        rad = self.config.radiometry
        bg = background_radiance(self.camera, rad, self.dirs, camera_x_m, t_s, opts.moving_object)
        img = radiance_image(column_ppm_m, bg, rad)
        shift = np.zeros(2)
        if opts.jitter_px > 0:
            shift = self.rng.normal(0.0, opts.jitter_px, 2)
            img = shift_image(img, (float(shift[0]), float(shift[1])))
        if opts.noise_netd_k > 0:
            sigma = band_radiance_derivative(rad.t_bg_k, rad.band_um) * opts.noise_netd_k
            img = img + self.rng.normal(0.0, sigma, img.shape)
        return to_counts(img, model), shift

    def next_frame(self) -> SyntheticFrame:
        """Render the current state, then advance the fluid to the next frame's time."""
        cfg = self.config
        st = self.sim.state
        to_ppm = 1e6 / cfg.radiometry.gas_density_kg_m3
        c_ppm = st.c * to_ppm
        t_s = self.frame_index * cfg.frame_interval_s
        # Velocity that carries this frame's gas to the next frame: mean over the sub-steps
        # (the state's arrays are replaced, not modified, by a step, so c_ppm stays this frame's).
        vel = np.zeros((3, *st.c.shape))
        for _ in range(cfg.substeps):
            self.sim.step()
            vel += self.sim.state.cell_velocity()
        vel /= cfg.substeps
        col_l, zsum, vsum = column_integrals(c_ppm, self.volume, self.dirs, 0.0, velocity=vel)
        col_r, _, _ = column_integrals(c_ppm, self.volume, self.dirs, self.camera.b_m)
        left, jl = self._render(col_l, 0.0, t_s, self.counts_left)
        right, jr = self._render(col_r, self.camera.b_m, t_s, self.counts_right)
        gt = ground_truth(col_l, zsum, vsum, self.dirs, cfg.necl_ppm_m)
        frame = SyntheticFrame(
            index=self.frame_index, t_s=t_s, left=left, right=right,
            gt_velocity=gt.velocity, gt_position=gt.position, gt_mask=gt.mask,
            column_density_ppm_m=gt.column_density_ppm_m,
            jitter_left_px=jl, jitter_right_px=jr,
        )
        self.frame_index += 1
        return frame


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


# --------------------------------------------------------------------------------------------
# presets

_TABLE2_EXTENT_M = 0.4  # 100 voxels of 4 mm


def _table2(
    name: str,
    seed: int,
    source_xyz: tuple[float, float, float],
    exit_velocity: tuple[float, float, float],
    wind: tuple[float, float, float],
    release_rate_g_s: float,
    **overrides: Any,
) -> SequenceConfig:
    cam = StereoCamera()
    # Centre the volume between the cameras, 2 m ahead; raise it by 12 cm so that its top face,
    # where the rising gas leaves the simulation, lies above the images' field of view (gas
    # vanishing at a face that the cameras see would make a motionless edge).
    centre = (cam.b_m / 2.0, -0.12, 2.0)
    origin = tuple(c - _TABLE2_EXTENT_M / 2.0 for c in centre)
    src = GasSource(position_m=source_xyz, radius_m=0.030, release_rate_g_s=release_rate_g_s,
                    exit_velocity_m_s=exit_velocity, turbulence=0.3, release_fluctuation=0.5)
    fluid = FluidParams(shape=(100, 100, 100), voxel_m=0.004, dt_s=0.001, wind_m_s=wind,
                        boundary="open", viscosity_m2_s=0.0, diffusivity_m2_s=0.0,
                        sources=(src,))
    cfg = SequenceConfig(name=name, fluid=fluid, volume_origin_m=origin, n_frames=11,
                         substeps=1, spinup_steps=60, spinup_dt_s=0.003, seed=seed, camera=cam)
    return replace(cfg, **overrides) if overrides else cfg


def preset_table2_1(**overrides: Any) -> SequenceConfig:
    """Sequence 1 of Table 2: mostly upward, small X and Z components (|V*| ~ 3.3 m/s)."""
    return _table2("table2_1", 101, (0.19, 0.36, 0.21), (0.3, -5.0, -0.15), (0.1, -1.5, -0.1),
                   4.0, **overrides)


def preset_table2_2(**overrides: Any) -> SequenceConfig:
    """Sequence 2 of Table 2: upward and to the right (theta_X ~ 71 deg, |V*| ~ 2.7 m/s)."""
    return _table2("table2_2", 202, (0.12, 0.36, 0.20), (1.4, -4.2, 0.05), (0.4, -1.1, 0.0),
                   4.0, **overrides)


def preset_table2_3(**overrides: Any) -> SequenceConfig:
    """Sequence 3 of Table 2: upward, left and towards the cameras (|V*| ~ 2.7 m/s)."""
    return _table2("table2_3", 303, (0.26, 0.36, 0.28), (-0.8, -4.8, -1.4), (-0.2, -1.35, -0.4),
                   4.0, **overrides)


def preset_field(
    n_frames: int = 90,
    wind_m_s: tuple[float, float, float] = (1.5, 0.0, 0.0),
    b_m: float = 0.3,
    distance_m: float = 5.5,
    release_rate_g_s: float = 3.0,
    seed: int = 7,
    voxel_m: float = 0.03,
    **overrides: Any,
) -> SequenceConfig:
    """The appliance's simulated cameras: 30 Hz, plume ~5.5 m away, wind from the anemometer.

    Grid 96 x 64 x 48 (X, Y, Z) of 3 cm (2.88 x 1.92 x 1.44 m, wider and taller than both
    cameras' views at 5.5 m, so gas leaves the simulation outside the images), two 1/60 s steps
    per frame. The source sits low and upstream of the wind so the plume crosses the view; at
    5.5 m one pixel is ~7 mm, so a wind of 1-3 m/s moves the gas ~5-14 px per frame.
    ``voxel_m`` trades detail for speed while keeping the same physical volume (0.06 m: 8x
    fewer cells, for live simulated cameras on a slow machine).
    """
    cam = StereoCamera(b_m=b_m)
    if not 0.005 <= voxel_m <= 0.2:
        raise ValueError(f"voxel_m must be within 0.005..0.2 m, got {voxel_m}")
    ext = np.array([2.88, 1.92, 1.44])
    h = float(voxel_m)
    nx, ny, nz = (max(8, round(e / h)) for e in ext)
    ext = np.array([nx, ny, nz]) * h
    centre = np.array([b_m / 2.0, 0.0, distance_m])
    origin = tuple(float(v) for v in centre - ext / 2.0)
    w = np.asarray(wind_m_s, dtype=float)
    horiz = np.array([w[0], 0.0, w[2]])
    norm = float(np.linalg.norm(horiz))
    upstream = -horiz / norm if norm > 1e-6 else np.zeros(3)
    pos = ext / 2.0 + 0.25 * ext * upstream
    pos[1] = ext[1] - 0.45  # ~0.5 m below the optical axis, inside the view
    src = GasSource(position_m=tuple(float(v) for v in pos), radius_m=max(0.045, 0.75 * h),
                    release_rate_g_s=release_rate_g_s, exit_velocity_m_s=(0.0, -1.0, 0.0),
                    turbulence=0.5, release_fluctuation=0.4)
    # two steps per frame keep the CFL number near 1 at 3 cm and 3 m/s (semi-Lagrangian is
    # stable beyond, only more diffusive)
    fluid = FluidParams(shape=(nz, ny, nx), voxel_m=h, dt_s=1.0 / 60.0,
                        wind_m_s=tuple(float(v) for v in w), boundary="open",
                        viscosity_m2_s=0.0, diffusivity_m2_s=0.0, sources=(src,))
    cfg = SequenceConfig(name="field", fluid=fluid, volume_origin_m=origin,
                         n_frames=n_frames, substeps=2, spinup_steps=120,
                         spinup_dt_s=1.0 / 60.0, seed=seed, camera=cam, necl_ppm_m=100.0)
    return replace(cfg, **overrides) if overrides else cfg


PRESETS: dict[str, Callable[..., SequenceConfig]] = {
    "table2_1": preset_table2_1,
    "table2_2": preset_table2_2,
    "table2_3": preset_table2_3,
    "field": preset_field,
}


def preset(name: str, **overrides: Any) -> SequenceConfig:
    """Build a preset by name (``table2_1|2|3``, ``field``) with field overrides."""
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; choose from {', '.join(PRESETS)}")
    return PRESETS[name](**overrides)
