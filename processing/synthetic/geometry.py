"""Pinhole stereo geometry of the synthetic cameras, with optional radial lens distortion.

Geometry (one convention, used everywhere in ogiflow's synthetic data)
--------------------------------------------------------------------
Camera frame of the LEFT camera: X right, Y down, Z forward (metres), origin at its optical
centre. The right camera is the left one translated to X = +b (parallel image planes, same
intrinsics). A point (X, Y, Z) projects (pinhole, pixel centres at integer coordinates) to

    x_L = c_x + s X / Z,        y_L = c_y + s Y / Z,
    x_R = c_x + s (X - b) / Z,  y_R = y_L,

so the disparity ``d = x_L - x_R = s b / Z > 0`` for every point in front of the cameras. This
is the sign Eq. 4 needs (``Z = s b / d``, ``V_Z = f b (s/(d + d') - s/d)``). The paper's text
writes ``x_R = x_L + p_L`` with ``p_L = (d_L, 0)``; with our sign a matcher must look for the
right-image correspondence at ``x_L - d``. Default principal point: the image centre
``((W - 1) / 2, (H - 1) / 2)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class StereoCamera:
    """Intrinsics shared by both cameras and the baseline (defaults: paper Sec. 5.1).

    Parameters
    ----------
    width, height : int
        Image size in px.
    s_px : float
        Camera constant (focal length) s in px.
    cx_px, cy_px : float or None
        Principal point in px; None means the image centre ``((W-1)/2, (H-1)/2)``.
    b_m : float
        Baseline b in m; the right camera sits at X = +b in the left camera frame.
    k1, k2 : float
        Radial lens distortion of both cameras on normalised coordinates
        (``x_d = x_u (1 + k1 r^2 + k2 r^4)``); 0 = ideal pinhole (default).
    """

    width: int = 320
    height: int = 240
    s_px: float = 780.0
    cx_px: float | None = None
    cy_px: float | None = None
    b_m: float = 0.2
    k1: float = 0.0
    k2: float = 0.0

    @property
    def cx(self) -> float:
        """Principal point x in px."""
        return (self.width - 1) / 2.0 if self.cx_px is None else float(self.cx_px)

    @property
    def cy(self) -> float:
        """Principal point y in px."""
        return (self.height - 1) / 2.0 if self.cy_px is None else float(self.cy_px)

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first bad parameter."""
        if self.width < 2 or self.height < 2:
            raise ValueError(f"image size must be >= 2x2, got {self.width}x{self.height}")
        if not self.s_px > 0 or not self.b_m > 0:
            raise ValueError(f"s_px and b_m must be > 0, got {self.s_px}, {self.b_m}")




def _distort(xn: np.ndarray, yn: np.ndarray, k1: float, k2: float) -> tuple[np.ndarray, np.ndarray]:
    r2 = xn * xn + yn * yn
    f = 1.0 + k1 * r2 + k2 * r2 * r2
    return xn * f, yn * f


def _undistort(
    xd: np.ndarray, yd: np.ndarray, k1: float, k2: float
) -> tuple[np.ndarray, np.ndarray]:
    """Invert the radial model by fixed-point iteration (converges for moderate distortion)."""
    xu, yu = xd.copy(), yd.copy()
    for _ in range(30):
        r2 = xu * xu + yu * yu
        f = 1.0 + k1 * r2 + k2 * r2 * r2
        xu, yu = xd / f, yd / f
    return xu, yu


def project_points(camera: StereoCamera, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project points of the left camera frame into both images.

    Parameters
    ----------
    camera : StereoCamera
    xyz : (..., 3) float array
        Points (X, Y, Z) in m, left camera frame, Z > 0.

    Returns
    -------
    left, right : (..., 2) float64 arrays
        Pixel coordinates (x, y) in each image; ``left[..., 0] - right[..., 0] = s b / Z``
        when there is no lens distortion.
    """
    p = np.asarray(xyz, dtype=float)
    if p.shape[-1] != 3:
        raise ValueError(f"xyz must have a last axis of 3, got shape {p.shape}")
    if np.any(p[..., 2] <= 0):
        raise ValueError("points must lie in front of the cameras (Z > 0)")
    out = []
    for x_offset in (0.0, camera.b_m):
        xn = (p[..., 0] - x_offset) / p[..., 2]
        yn = p[..., 1] / p[..., 2]
        xd, yd = _distort(xn, yn, camera.k1, camera.k2)
        out.append(np.stack((camera.cx + camera.s_px * xd, camera.cy + camera.s_px * yd), -1))
    return out[0], out[1]


def ray_directions(camera: StereoCamera,
                   shift_px: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """Direction of each pixel's ray (x_n, y_n, 1), float64 (H, W, 3), lens distortion removed.

    A point at depth Z on the ray of pixel (x, y) is ``Z * dirs[y, x]``. ``shift_px`` = (dx,
    dy) moves the detector so that the image content is displaced by +shift (camera jitter):
    pixel (x, y) then sees what the unshifted pixel (x - dx, y - dy) sees.
    """
    camera.validate()
    ys, xs = np.mgrid[0 : camera.height, 0 : camera.width].astype(float)
    xs -= float(shift_px[0])
    ys -= float(shift_px[1])
    xd = (xs - camera.cx) / camera.s_px
    yd = (ys - camera.cy) / camera.s_px
    if camera.k1 or camera.k2:
        xd, yd = _undistort(xd, yd, camera.k1, camera.k2)
    return np.stack((xd, yd, np.ones_like(xd)), axis=-1)
