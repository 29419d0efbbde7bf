"""Analytic stereo scenes for the scene-flow tests: a textured fronto-parallel plane.

The plane carries a random smooth texture fixed to it (2 mm texels); it sits at depth
Z(t) = Z0 + V_Z t and slides with (V_X, V_Y) t. Each camera sees it through the pinhole
model of a rectified pair (left camera at the origin, right camera at +b along X; X right,
Y down, Z forward), so that the true disparity is d = s b / Z and the true 3D velocity is
V everywhere. Images are rendered with cv2.remap (bicubic) from the texture.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

S_PX = 780.0  # camera constant s, px (paper Sec. 4)
B_M = 0.2  # baseline b, m (paper Sec. 5.1)
SIZE = (240, 320)  # (H, W)
PP = (159.5, 119.5)  # principal point (x0, y0), px
TEXEL_M = 0.002  # texture sample spacing on the plane, m
TEX_SHAPE = (900, 1200)  # texture (rows, cols): covers 2.4 m x 1.8 m


def texture(seed: int = 0) -> np.ndarray:
    """Random smooth multi-scale texture in [0, 1], float32, shape TEX_SHAPE.

    A sum of blurred noise fields at 2-32 texels (about 1.5-25 px at 2 m): coarse-to-fine
    estimation needs structure at every pyramid level, as gas puffs have.
    """
    rng = np.random.default_rng(seed)
    t = np.zeros(TEX_SHAPE, np.float32)
    for sigma in (2.0, 4.0, 8.0, 16.0, 32.0):
        layer = cv2.GaussianBlur(rng.random(TEX_SHAPE).astype(np.float32), (0, 0), sigma)
        t += (layer - layer.mean()) / layer.std()
    return (t - t.min()) / (t.max() - t.min())


def render(tex: np.ndarray, z: float, shift_xy: tuple[float, float], cam_x: float
           ) -> np.ndarray:
    """View of the plane at depth ``z`` (m), texture shifted by ``shift_xy`` (m), from a
    camera at (cam_x, 0, 0); returns (H, W) float32 in [0, 1]."""
    h, w = SIZE
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    x_m = cam_x + (xx - PP[0]) * z / S_PX - shift_xy[0]
    y_m = (yy - PP[1]) * z / S_PX - shift_xy[1]
    map_x = (x_m / TEXEL_M + TEX_SHAPE[1] / 2).astype(np.float32)
    map_y = (y_m / TEXEL_M + TEX_SHAPE[0] / 2).astype(np.float32)
    return cv2.remap(tex, map_x, map_y, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)


@dataclass(frozen=True)
class PlaneScene:
    il0: np.ndarray
    ir0: np.ndarray
    il1: np.ndarray
    ir1: np.ndarray
    z0: float
    velocity: np.ndarray  # (3,) m/s
    dt: float

    @property
    def d(self) -> float:
        return S_PX * B_M / self.z0

    @property
    def d_change(self) -> float:
        return S_PX * B_M / (self.z0 + self.velocity[2] * self.dt) - self.d


def patch(tex: np.ndarray, radius_m: float) -> np.ndarray:
    """``tex`` kept only within ``radius_m`` of the plane's centre (0.5 elsewhere, a 3 cm
    soft edge): texture on part of the image only, as a gas cloud has."""
    h, w = TEX_SHAPE
    yy, xx = np.mgrid[0:h, 0:w]
    r = np.hypot((xx - w / 2) * TEXEL_M, (yy - h / 2) * TEXEL_M)
    window = np.clip((radius_m - r) / 0.03, 0.0, 1.0).astype(np.float32)
    return (0.5 + (tex - 0.5) * window).astype(np.float32)


def moving_plane(z0: float = 2.0, velocity: tuple[float, float, float] = (0.6, -0.3, -0.9),
                 dt: float = 1 / 30, seed: int = 0,
                 patch_radius_m: float | None = None) -> PlaneScene:
    """Both cameras at t0 and t1 for the plane at ``z0`` moving with ``velocity``
    (textured only within ``patch_radius_m`` of its centre when given, see :func:`patch`)."""
    tex = texture(seed)
    if patch_radius_m is not None:
        tex = patch(tex, patch_radius_m)
    vel = np.asarray(velocity, dtype=np.float64)
    z1 = z0 + vel[2] * dt
    s1 = (vel[0] * dt, vel[1] * dt)
    return PlaneScene(
        il0=render(tex, z0, (0.0, 0.0), 0.0),
        ir0=render(tex, z0, (0.0, 0.0), B_M),
        il1=render(tex, z1, s1, 0.0),
        ir1=render(tex, z1, s1, B_M),
        z0=z0, velocity=vel, dt=dt,
    )
