"""Synthetic calibration images: a planar target rendered through a known camera model.

Used by the tests (recover a known stereo model) and by anyone who wants to check the
calibration chain end to end without a heated target. Rendering is exact with respect to
OpenCV's camera model: every output pixel is traced back through the lens distortion
(iterative undistortion to 1e-12) onto the target plane, where the pattern is evaluated
analytically at ``supersample`` x ``supersample`` points per pixel and averaged (box
anti-aliasing). The ground-truth image position of each pattern point is therefore
``cv2.projectPoints`` of :func:`pattern.object_points`.

IR appearance (:func:`ir_counts`): a heated target has low contrast on a large offset, a
radial temperature fall-off, sensor noise and may appear inverted; the result is quantised
to uint16 or uint8 counts.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from processing.calibration.model import StereoCalibration
from processing.calibration.pattern import PatternSpec, object_points
from processing.calibration.radiometric import band_radiance, celsius_to_kelvin
from processing.calibration.rectify import stereo_rectification


@dataclass(frozen=True)
class CameraRays:
    """Normalised undistorted coordinates of the sub-pixel sample points of one camera.

    Attributes
    ----------
    xy : numpy.ndarray, shape (H * n, W * n, 2), float64
        (x / z, y / z) of the ray through each sample point.
    supersample : int
        n, samples per pixel along each axis.
    image_size : tuple of int
        (width, height) in pixels.
    """

    xy: np.ndarray
    supersample: int
    image_size: tuple[int, int]


def camera_rays(
    K: np.ndarray, D: np.ndarray, image_size: tuple[int, int], supersample: int = 3
) -> CameraRays:
    """Trace the sample points of every pixel back through the lens (see :class:`CameraRays`).

    Parameters
    ----------
    K : numpy.ndarray, shape (3, 3)
        Camera matrix, pixels.
    D : numpy.ndarray, shape (4,), (5,), ...
        OpenCV distortion coefficients (k1, k2, p1, p2[, k3, ...]).
    image_size : (width, height)
        Pixels.
    supersample : int
        Samples per pixel along each axis.
    """
    w, h = image_size
    n = int(supersample)
    offsets = (np.arange(n) + 0.5) / n - 0.5
    xs = (np.arange(w)[:, None] + offsets[None, :]).ravel()
    ys = (np.arange(h)[:, None] + offsets[None, :]).ravel()
    gx, gy = np.meshgrid(xs, ys)
    pix = np.stack([gx.ravel(), gy.ravel()], axis=1).reshape(-1, 1, 2)
    # The default 5 iterations leave errors of ~0.1 px at the corners of a strongly
    # distorted lens; the renderer must be exact, so iterate to convergence.
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14)
    norm = cv2.undistortPoints(
        pix, np.asarray(K, np.float64), np.asarray(D, np.float64), None, None, None, criteria
    )
    return CameraRays(norm.reshape(h * n, w * n, 2).astype(np.float64), n, (w, h))


def _pattern_value(spec: PatternSpec, X: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Reflectance-like value of the target at plane coordinates (metres): 1 bright, 0 dark.

    A white border of one pitch surrounds the pattern; beyond it the scene is at 0.4.
    """
    s = spec.spacing_m
    out = np.full(X.shape, 0.4)
    if spec.kind == "chessboard":
        x0, x1, y0, y1 = -s, spec.cols * s, -s, spec.rows * s
        plate = (X >= x0 - s) & (X <= x1 + s) & (Y >= y0 - s) & (Y <= y1 + s)
        out[plate] = 1.0
        inside = (X >= x0) & (X < x1) & (Y >= y0) & (Y < y1)
        dark = ((np.floor(X / s) + np.floor(Y / s)) % 2) == 0
        out[inside & dark] = 0.0
        return out
    if spec.kind == "acircles":
        pitch_x, radius = 2.0 * s, 0.35 * s
        width = (2 * (spec.cols - 1) + 1) * s
    else:
        pitch_x, radius = s, 0.3 * s
        width = (spec.cols - 1) * s
    height = (spec.rows - 1) * s
    m = 1.0 * max(pitch_x, s)
    plate = (X >= -m) & (X <= width + m) & (Y >= -m) & (Y <= height + m)
    out[plate] = 1.0
    i = np.clip(np.rint(Y / s), 0, spec.rows - 1)
    shift = (i % 2) * s if spec.kind == "acircles" else 0.0
    j = np.clip(np.rint((X - shift) / pitch_x), 0, spec.cols - 1)
    cx = j * pitch_x + shift
    cy = i * s
    circle = (X - cx) ** 2 + (Y - cy) ** 2 <= radius**2
    out[plate & circle] = 0.0
    return out


def render_pattern(
    spec: PatternSpec, rays: CameraRays, rvec: np.ndarray, tvec: np.ndarray
) -> np.ndarray:
    """Render the target at pose (rvec, tvec) through the camera whose rays are given.

    Parameters
    ----------
    spec : PatternSpec
        Target geometry.
    rays : CameraRays
        From :func:`camera_rays`.
    rvec, tvec : numpy.ndarray, shape (3,)
        Target-to-camera pose as in ``cv2.projectPoints`` (Rodrigues vector, metres).

    Returns
    -------
    numpy.ndarray, shape (H, W), float64
        Values in [0, 1] (1 = bright plate).
    """
    R, _ = cv2.Rodrigues(np.asarray(rvec, np.float64))
    H = np.column_stack([R[:, 0], R[:, 1], np.asarray(tvec, np.float64).ravel()])
    Hinv = np.linalg.inv(H)
    x = rays.xy[..., 0]
    y = rays.xy[..., 1]
    X = Hinv[0, 0] * x + Hinv[0, 1] * y + Hinv[0, 2]
    Y = Hinv[1, 0] * x + Hinv[1, 1] * y + Hinv[1, 2]
    W = Hinv[2, 0] * x + Hinv[2, 1] * y + Hinv[2, 2]
    front = W > 0  # rays that hit the plane in front of the camera
    with np.errstate(divide="ignore", invalid="ignore"):
        val = _pattern_value(spec, np.where(front, X / W, 1e9), np.where(front, Y / W, 1e9))
    n = rays.supersample
    w, h = rays.image_size
    return val.reshape(h, n, w, n).mean(axis=(1, 3))


def ir_counts(
    image01: np.ndarray,
    rng: np.random.Generator,
    *,
    offset: float = 20000.0,
    contrast: float = 600.0,
    falloff: float = 0.5,
    noise: float = 15.0,
    blur_px: float = 0.6,
    inverted: bool = False,
    dtype: type = np.uint16,
) -> np.ndarray:
    """Give a rendered target the look of a heated target in a cooled MWIR camera.

    Parameters
    ----------
    image01 : numpy.ndarray, shape (H, W), float
        Rendered target, 1 = bright.
    rng : numpy.random.Generator
        Noise source.
    offset, contrast : float
        Counts of the dark level and bright-minus-dark difference at the image centre.
    falloff : float
        Fraction of the contrast lost at the image corners (radial, quadratic): uneven
        heating and vignetting.
    noise : float
        Standard deviation of additive Gaussian noise, counts.
    blur_px : float
        Gaussian optical blur sigma, pixels (0 = none).
    inverted : bool
        Swap bright and dark (polarity of the target in the IR).
    dtype : numpy dtype
        uint16 (counts as given) or uint8 (as a camera's automatic gain control would
        output it: dark level at 40, centre contrast spanning 100 grey levels, noise scaled
        alike).
    """
    img = 1.0 - image01 if inverted else image01.astype(np.float64)
    if blur_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur_px)
    h, w = img.shape
    yy, xx = np.mgrid[0:h, 0:w]
    r2 = ((xx - w / 2) / (w / 2)) ** 2 + ((yy - h / 2) / (h / 2)) ** 2
    gain = contrast * (1.0 - falloff * r2 / 2.0)
    counts = offset + gain * img + rng.normal(0.0, noise, img.shape)
    if np.dtype(dtype) == np.uint8:
        counts = 40.0 + (counts - offset) * (100.0 / contrast)
        return np.clip(np.rint(counts), 0, 255).astype(np.uint8)
    return np.clip(np.rint(counts), 0, 65535).astype(np.uint16)


def right_pose(rig: StereoCalibration, rvec: np.ndarray, tvec: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
    """Target pose (Rodrigues vector, translation in m) in the right camera of ``rig`` from
    its pose in the left camera (X_r = R X_l + T)."""
    Rl, _ = cv2.Rodrigues(np.asarray(rvec, np.float64))
    rr, _ = cv2.Rodrigues(rig.R @ Rl)
    return rr.ravel(), rig.R @ np.asarray(tvec, np.float64).ravel() + rig.T


def _inside(points: np.ndarray, image_size: tuple[int, int], margin: float) -> bool:
    w, h = image_size
    p = points.reshape(-1, 2)
    return bool(np.all((p[:, 0] >= margin) & (p[:, 0] <= w - 1 - margin)
                       & (p[:, 1] >= margin) & (p[:, 1] <= h - 1 - margin)))


def random_target_poses(
    rig: StereoCalibration,
    spec: PatternSpec,
    n: int,
    rng: np.random.Generator,
    *,
    distance_m: tuple[float, float] = (1.0, 2.0),
    max_tilt_deg: float = 40.0,
    margin_px: float = 8.0,
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Draw ``n`` target poses (in the left camera) fully visible in both cameras.

    The target is tilted up to ``max_tilt_deg`` about its own x and y axes, turned up to
    +-20 deg in plane, placed ``distance_m`` in front of the pair and moved across the
    field of view; poses whose points (and a one-pitch border) leave either image are drawn
    again.

    Returns
    -------
    list of (rvec, tvec)
        Target-to-left-camera poses, Rodrigues vector and metres.
    """

    obj = object_points(spec)
    centre = obj.mean(axis=0)
    lo, hi = obj.min(axis=0), obj.max(axis=0)
    pad = spec.spacing_m * (2.0 if spec.kind == "acircles" else 1.0)
    hull = np.array([[lo[0] - pad, lo[1] - pad, 0], [hi[0] + pad, lo[1] - pad, 0],
                     [hi[0] + pad, hi[1] + pad, 0], [lo[0] - pad, hi[1] + pad, 0]])
    poses: list[tuple[np.ndarray, np.ndarray]] = []
    tries = 0
    while len(poses) < n:
        tries += 1
        if tries > 200 * n:
            raise RuntimeError("could not place the target in both views; widen the ranges")
        tilt = np.deg2rad(rng.uniform(-max_tilt_deg, max_tilt_deg, 2))
        spin = np.deg2rad(rng.uniform(-20, 20))
        Rt = (cv2.Rodrigues(np.array([tilt[0], 0, 0]))[0]
              @ cv2.Rodrigues(np.array([0, tilt[1], 0]))[0]
              @ cv2.Rodrigues(np.array([0, 0, spin]))[0])
        z = rng.uniform(*distance_m)
        K = rig.K_left
        w, h = rig.image_size
        x = rng.uniform(-0.3, 0.3) * w / K[0, 0] * z
        y = rng.uniform(-0.3, 0.3) * h / K[1, 1] * z
        # Aim between the cameras (the right one sits at -R^T T) so both tend to see it.
        t = np.array([x - rig.T[0] / 2.0, y, z]) - Rt @ centre
        rvec = cv2.Rodrigues(Rt)[0].ravel()
        pl, _ = cv2.projectPoints(hull, rvec, t, rig.K_left, rig.D_left)
        rr, tr = right_pose(rig, rvec, t)
        pr, _ = cv2.projectPoints(hull, rr, tr, rig.K_right, rig.D_right)
        if _inside(pl, rig.image_size, margin_px) and _inside(pr, rig.image_size, margin_px):
            poses.append((rvec, t))
    return poses


def example_rig() -> StereoCalibration:
    """A 320x240 OGI-like pair: f ~ 400 px (~43 deg field of view), strong barrel
    distortion (k1 ~ -0.25), 0.25 m baseline, cameras turned ~2 deg towards each other."""
    return stereo_rectification(
        np.array([[400.0, 0.0, 162.3], [0.0, 401.0, 118.7], [0.0, 0.0, 1.0]]),
        np.array([-0.25, 0.12, 0.001, -0.0005, 0.0]),
        np.array([[405.0, 0.0, 158.1], [0.0, 405.5, 121.2], [0.0, 0.0, 1.0]]),
        np.array([-0.22, 0.09, -0.0008, 0.0006, 0.0]),
        cv2.Rodrigues(np.array([0.01, -0.03, 0.005]))[0],
        np.array([-0.25, 0.004, 0.002]),
        (320, 240), meta={"source": "example rig (rendered calibration views)"},
    )


def render_stereo_views(
    rig: StereoCalibration,
    spec: PatternSpec,
    poses: list[tuple[np.ndarray, np.ndarray]],
    rng: np.random.Generator,
    *,
    supersample: int = 2,
    inverted_every: int = 3,
    uint8_every: int = 4,
) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """Render every pose into both cameras with IR appearance (:func:`ir_counts`).

    Every ``inverted_every``-th view shows the target with inverted polarity and every
    ``uint8_every``-th view (offset by one) is 8-bit; the right camera has its own offset
    and contrast (the cameras are not radiometrically matched). 0 disables either.

    Returns
    -------
    list of (name, left, right)
        ``name`` is ``"view%02d.png"``; images (H, W), uint16 or uint8.
    """
    rays_l = camera_rays(rig.K_left, rig.D_left, rig.image_size, supersample)
    rays_r = camera_rays(rig.K_right, rig.D_right, rig.image_size, supersample)
    views = []
    for k, (rvec, tvec) in enumerate(poses):
        inverted = inverted_every > 0 and k % inverted_every == 0
        dtype = np.uint8 if uint8_every > 0 and k % uint8_every == 1 else np.uint16
        left = ir_counts(render_pattern(spec, rays_l, rvec, tvec), rng,
                         inverted=inverted, dtype=dtype)
        rr, tr = right_pose(rig, rvec, tvec)
        right = ir_counts(render_pattern(spec, rays_r, rr, tr), rng, offset=21000.0,
                          contrast=500.0, inverted=inverted, dtype=dtype)
        views.append((f"view{k:02d}.png", left, right))
    return views


def write_demo_data(out_dir: str, views: int = 14, seed: int = 0) -> None:
    """Write a rendered calibration data set laid out as the ``calibrate`` commands expect.

    ``out_dir/left/viewNN.png`` and ``out_dir/right/viewNN.png``: chessboard of 6 x 9 inner
    corners, 50 mm squares, seen through :func:`example_rig`. ``out_dir/blackbody/{left,
    right}/tNN/``: five 16-bit frames per black-body temperature 20, 35, 50, 65, 80 degC
    (left: gain 45000 counts per W m^-2 sr^-1, offset 12000 counts; right: 50000, 9000).
    """
    root = Path(out_dir)
    rig = example_rig()
    spec = PatternSpec("chessboard", 6, 9, 0.05)
    rng = np.random.default_rng(seed)
    poses = random_target_poses(rig, spec, views, rng, distance_m=(1.0, 1.8))
    for side in ("left", "right"):
        (root / side).mkdir(parents=True, exist_ok=True)
    for name, left, right in render_stereo_views(rig, spec, poses, rng):
        cv2.imwrite(str(root / "left" / name), left)
        cv2.imwrite(str(root / "right" / name), right)
    h, w = rig.image_size[1], rig.image_size[0]
    for side, gain, offset in (("left", 45000.0, 12000.0), ("right", 50000.0, 9000.0)):
        for t_c in (20, 35, 50, 65, 80):
            folder = root / "blackbody" / side / f"t{t_c}"
            folder.mkdir(parents=True, exist_ok=True)
            level = offset + gain * float(band_radiance(celsius_to_kelvin(t_c)))
            for k in range(5):
                frame = np.clip(np.rint(level + rng.normal(0.0, 15.0, (h, w))), 0, 65535)
                cv2.imwrite(str(folder / f"frame{k}.png"), frame.astype(np.uint16))


if __name__ == "__main__":
    import sys

    if len(sys.argv) != 2 or sys.argv[1].startswith("-"):
        print("usage: python -m processing.calibration.rig OUT_DIR\n"
              "writes rendered stereo views (OUT_DIR/left, OUT_DIR/right) and black-body frames "
              "(OUT_DIR/blackbody) for trying the calibrate commands", file=sys.stderr)
        raise SystemExit(2)
    write_demo_data(sys.argv[1])
    print(f"wrote {sys.argv[1]}/left, {sys.argv[1]}/right and {sys.argv[1]}/blackbody")
