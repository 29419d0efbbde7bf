"""Presets of synthetic stereo OGI sequences (paper Table 2 and the appliance's field scene).

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
px. Those were measured with a release re-drawn at every step; with the time-correlated
release (0.7 s) |V*avg| is 2.73, 2.45, 2.92 m/s, sigma 1.07, 1.04, 1.04 m/s, N 6175,
7766, 6476 px (the release over a 11 ms sequence is one draw of the slow fluctuation).
``field`` imitates the appliance's cameras: 30 Hz frames (simulation sub-steps inside), a plume
about 5.5 m away on 3 cm voxels, a configurable baseline and the anemometer's wind.
``no_release`` is the same site with no gas but noise, jitter, a walking warm object and a
drifting background (false-alarm measurements).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from processing.synthetic.config import RenderOptions, SequenceConfig
from processing.synthetic.fluid import FluidParams, GasSource
from processing.synthetic.imaging import Background, MovingObject
from processing.synthetic.render import StereoCamera

#: The presets that ``ogiflow simulate`` writes by default.
TABLE2_PRESETS: tuple[str, ...] = ("table2_1", "table2_2", "table2_3")

_TABLE2_EXTENT_M = 0.4  # 100 voxels of 4 mm
#: Frame rate of the ``field`` and ``no_release`` scenes (the appliance's cameras), Hz.
FIELD_FRAME_RATE_HZ = 30.0
#: Image sizes (W, H) of the ``field`` and ``no_release`` cameras, px. All show the same 4:3
#: field of view (the camera constant grows with the width), the one the simulated volume
#: is sized for: 320x240 (GF320 class) and 640x480 (GF620 class, 4x the pixels).
FIELD_IMAGE_SIZES: tuple[tuple[int, int], ...] = ((320, 240), (640, 480))
#: Camera constant of the 320 px wide field camera, px (the paper's, Sec. 5.1).
FIELD_CAMERA_CONSTANT_PX = 780.0


def field_camera(image_size: tuple[int, int] = (320, 240), b_m: float = 0.3) -> StereoCamera:
    """The ``field`` scene's ideal camera pair at ``image_size`` (W, H) px.

    The camera constant scales with the width, so every size sees the same field of view.

    Raises
    ------
    ValueError
        For a size outside :data:`FIELD_IMAGE_SIZES` (another field of view would show the
        simulated volume's faces, or miss the plume).
    """
    size = (int(image_size[0]), int(image_size[1]))
    if size not in FIELD_IMAGE_SIZES:
        known = ", ".join(f"{w}x{h}" for w, h in FIELD_IMAGE_SIZES)
        raise ValueError(f"the field scene renders {known} images, not {size[0]}x{size[1]}")
    return StereoCamera(width=size[0], height=size[1],
                        s_px=FIELD_CAMERA_CONSTANT_PX * size[0] / 320.0, b_m=b_m)


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
    depth_m: float = 1.44,
    image_size: tuple[int, int] = (320, 240),
    **overrides: Any,
) -> SequenceConfig:
    """The appliance's simulated cameras: 30 Hz, plume ~5.5 m away, wind from the anemometer.

    ``image_size`` (W, H) is one of :data:`FIELD_IMAGE_SIZES` (:func:`field_camera`); the
    figures below are those of 320x240, a 640x480 camera sees everything at twice the
    pixels.

    Grid 96 x 64 x 48 (X, Y, Z) of 3 cm (2.88 x 1.92 x 1.44 m, wider and taller than both
    cameras' views at 5.5 m, so gas leaves the simulation outside the images), two 1/60 s steps
    per frame. The source sits low and upstream of the wind so the plume crosses the view; at
    5.5 m one pixel is ~7 mm, so a wind of 1-3 m/s moves the gas ~5-14 px per frame.
    ``voxel_m`` trades detail for speed while keeping the same physical volume (0.06 m: 8x
    fewer cells, for live simulated cameras on a slow machine).

    That holds for X and Y. A wind with a Z component carries the gas through the volume's
    far (or near) face, and the view widens with depth, so with 1.44 m the plume vanishes in
    mid-image (:mod:`processing.synthetic.volume_exit`). ``depth_m`` (m, 1.44-12) grows the
    volume downwind along Z (both ways without a Z wind) with the source where it was, and
    the spin-up by the time the wind takes to cross the added depth (at most 8 s more); the
    cost grows with the cells. 2.88 m lets a plume 45 deg out of the image plane leave
    through the side of the view at 5.5 m.
    """
    cam = field_camera(image_size, b_m)
    if not 0.005 <= voxel_m <= 0.2:
        raise ValueError(f"voxel_m must be within 0.005..0.2 m, got {voxel_m}")
    if not 1.44 <= depth_m <= 12.0:
        raise ValueError(f"depth_m must be within 1.44..12 m, got {depth_m}")
    h = float(voxel_m)
    nx, ny, nz0 = (max(8, round(e / h)) for e in (2.88, 1.92, 1.44))
    nz = max(nz0, round(depth_m / h))
    ext0 = np.array([nx, ny, nz0]) * h  # the volume the source's place is defined in
    ext = np.array([nx, ny, nz]) * h
    w = np.asarray(wind_m_s, dtype=float)
    horiz = np.array([w[0], 0.0, w[2]])
    norm = float(np.linalg.norm(horiz))
    upstream = -horiz / norm if norm > 1e-6 else np.zeros(3)
    pos = ext0 / 2.0 + 0.25 * ext0 * upstream
    # A deeper volume grows downwind along Z only (both ways without a Z wind): the gas then
    # leaves through the sides of the views instead of vanishing through the far (or near)
    # face inside them, which no real plume does. The source keeps its place.
    extra = (nz - nz0) * h
    grow_near = extra if w[2] < 0 else (0.0 if w[2] > 0 else extra / 2.0)
    pos[2] += grow_near
    origin = tuple(float(v) for v in (np.array([b_m / 2.0, 0.0, distance_m]) - ext0 / 2.0
                                      - np.array([0.0, 0.0, grow_near])))
    pos[1] = ext[1] - 0.45  # ~0.5 m below the optical axis, inside the view
    src = GasSource(position_m=tuple(float(v) for v in pos), radius_m=max(0.045, 0.75 * h),
                    release_rate_g_s=release_rate_g_s, exit_velocity_m_s=(0.0, -1.0, 0.0),
                    turbulence=0.5, release_fluctuation=0.4)
    # two steps per frame keep the CFL number near 1 at 3 cm and 3 m/s (semi-Lagrangian is
    # stable beyond, only more diffusive)
    fluid = FluidParams(shape=(nz, ny, nx), voxel_m=h, dt_s=0.5 / FIELD_FRAME_RATE_HZ,
                        wind_m_s=tuple(float(v) for v in w), boundary="open",
                        viscosity_m2_s=0.0, diffusivity_m2_s=0.0, sources=(src,))
    # The plume needs the time to cross the deeper part of the volume before the first frame.
    spinup = 120 + (min(480, math.ceil(extra / abs(w[2]) * 60.0)) if w[2] != 0 else 0)
    cfg = SequenceConfig(name="field", fluid=fluid, volume_origin_m=origin,
                         n_frames=n_frames, substeps=2, spinup_steps=spinup,
                         spinup_dt_s=1.0 / 60.0, seed=seed, camera=cam, necl_ppm_m=100.0)
    return replace(cfg, **overrides) if overrides else cfg


#: Largest rate of the no-release scene's background drift, K/s (a sunlit wall warming
#: 1.2 K a minute), whatever the drift's period.
NO_RELEASE_DRIFT_K_PER_S = 0.02
#: Temporal noise (NETD, K) and jitter (px, standard deviation) of the no-release scene.
NO_RELEASE_NOISE_K = 0.03
NO_RELEASE_JITTER_PX = 0.3


def preset_no_release(walker_period_s: float = 20.0, drift_period_s: float = 600.0,
                      **field: Any) -> SequenceConfig:
    """The field scene with no gas and what a site shows instead: the false-alarm scene.

    ``field`` are the arguments of :func:`preset_field` (n_frames, wind, baseline,
    distance, seed, voxel, overrides). Its cameras in front of a plant wall (textured,
    12 m), with temporal noise (NETD 0.03 K), camera jitter (0.3 px), a warm object (a
    person, 0.3 m, 310 K) walking 3 m to and fro at the plume's distance every
    ``walker_period_s``, and the background's temperature drifting as a sine of
    ``drift_period_s`` whose steepest slope is :data:`NO_RELEASE_DRIFT_K_PER_S`. No source:
    the fluid is not simulated (nothing moves in it), so frames cost only their rendering.
    Loop such a scene over a multiple of both periods and it has no jump.
    """
    cfg = preset_field(**field)
    b_m = cfg.camera.b_m
    distance_m = cfg.volume_origin_m[2] + 0.5 * cfg.fluid.shape[0] * cfg.fluid.voxel_m
    seed = cfg.seed
    span_m = 3.0
    walker = MovingObject(z_m=distance_m, radius_m=0.3, center_m=(b_m / 2 - span_m / 2, 0.2),
                          velocity_m_s=(2.0 * span_m / walker_period_s, 0.0), t_k=310.0,
                          back_forth_s=walker_period_s)
    drift_k = NO_RELEASE_DRIFT_K_PER_S * drift_period_s / (2.0 * np.pi)
    cfg = replace(
        cfg, name="no_release", fluid=replace(cfg.fluid, sources=()), spinup_steps=0,
        background=Background(kind="plant", seed=seed, drift_k=drift_k,
                              drift_period_s=drift_period_s),
        options=RenderOptions(noise_netd_k=NO_RELEASE_NOISE_K, jitter_px=NO_RELEASE_JITTER_PX,
                              moving_object=walker))
    return cfg


PRESETS: dict[str, Callable[..., SequenceConfig]] = {
    "table2_1": preset_table2_1,
    "table2_2": preset_table2_2,
    "table2_3": preset_table2_3,
    "field": preset_field,
    "no_release": preset_no_release,
}


def preset(name: str, **overrides: Any) -> SequenceConfig:
    """Build a preset by name (``table2_1|2|3``, ``field``) with field overrides."""
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; choose from {', '.join(PRESETS)}")
    return PRESETS[name](**overrides)
