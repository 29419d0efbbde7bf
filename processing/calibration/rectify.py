"""Stereo rectification: from the calibrated pair to row-aligned images (paper Sec. 4.1).

After rectification both cameras share the camera constant s and the principal point row,
their image rows are epipolar lines, and a scene point at depth Z appears with disparity
d = s b / Z (paper Eq. 4). The pre-processing calls :func:`rectification_maps` once per
calibration and :func:`rectify_pair` on every stereo pair.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from processing.calibration.model import StereoCalibration


def stereo_rectification(
    K_left: np.ndarray,
    D_left: np.ndarray,
    K_right: np.ndarray,
    D_right: np.ndarray,
    R: np.ndarray,
    T: np.ndarray,
    image_size: tuple[int, int],
    *,
    alpha: float = 0.0,
    rms_px: float = 0.0,
    meta: dict[str, Any] | None = None,
) -> StereoCalibration:
    """Rectify a calibrated pair (cv2.stereoRectify) and return the complete calibration.

    Parameters
    ----------
    K_left, K_right : numpy.ndarray, shape (3, 3)
        Camera matrices, pixels.
    D_left, D_right : numpy.ndarray, shape (n,)
        Distortion coefficients.
    R : numpy.ndarray, shape (3, 3)
        Rotation left -> right camera.
    T : numpy.ndarray, shape (3,)
        Translation left -> right camera, metres.
    image_size : (width, height)
        Pixels.
    alpha : float
        0 keeps only valid pixels in the rectified images (zoomed in, default); 1 keeps every
        source pixel (black borders).
    rms_px : float
        Reprojection RMS to record, pixels.
    meta : dict, optional
        Provenance recorded in the file.

    Returns
    -------
    StereoCalibration

    Raises
    ------
    ValueError
        When the pair is not a horizontal one with the right camera on the right (the
        scene-flow chain needs positive horizontal disparities).
    """
    if not 0.0 <= alpha <= 1.0:
        raise ValueError(f"rectification alpha must be in [0, 1], got {alpha}")
    T = np.asarray(T, np.float64).reshape(3)
    if abs(T[0]) < max(abs(T[1]), abs(T[2])):
        raise ValueError(f"the cameras are not side by side (T = {T.round(4).tolist()} m): the "
                         "scene-flow chain needs a horizontal stereo pair")
    if T[0] > 0:
        raise ValueError(f"the right camera is to the left of the left camera (T_x = {T[0]:.4f} "
                         "m > 0): swap the left and right images")
    R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(
        np.asarray(K_left, np.float64), np.asarray(D_left, np.float64),
        np.asarray(K_right, np.float64), np.asarray(D_right, np.float64),
        tuple(int(v) for v in image_size), np.asarray(R, np.float64), T.reshape(3, 1),
        flags=cv2.CALIB_ZERO_DISPARITY, alpha=float(alpha),
    )
    info = dict(meta or {})
    info.setdefault("rectify_alpha", float(alpha))
    return StereoCalibration(
        image_size=(int(image_size[0]), int(image_size[1])),
        K_left=np.asarray(K_left, np.float64), D_left=np.asarray(D_left, np.float64).ravel(),
        K_right=np.asarray(K_right, np.float64), D_right=np.asarray(D_right, np.float64).ravel(),
        R=np.asarray(R, np.float64), T=T, rms_px=float(rms_px),
        R1=R1, R2=R2, P1=P1, P2=P2, Q=Q, meta=info,
    )


@dataclass(frozen=True)
class RectificationMaps:
    """Pixel maps of both cameras, computed once per calibration.

    Attributes
    ----------
    left_x, left_y, right_x, right_y : numpy.ndarray, shape (H, W), float32
        Source coordinates in the raw image of each rectified pixel (cv2.remap maps).
    valid_left, valid_right : numpy.ndarray, shape (H, W), bool
        Rectified pixels whose source lies inside the raw image.
    image_size : (int, int)
        (width, height), pixels; raw and rectified images have this size.
    """

    left_x: np.ndarray
    left_y: np.ndarray
    right_x: np.ndarray
    right_y: np.ndarray
    valid_left: np.ndarray
    valid_right: np.ndarray
    image_size: tuple[int, int]


def _valid(map_x: np.ndarray, map_y: np.ndarray, w: int, h: int) -> np.ndarray:
    return (map_x >= 0) & (map_x <= w - 1) & (map_y >= 0) & (map_y <= h - 1)


def rectification_maps(calib: StereoCalibration) -> RectificationMaps:
    """Undistort-and-rectify maps of both cameras from a calibration (R1/P1, R2/P2).

    Parameters
    ----------
    calib : StereoCalibration
        Loaded calibration (:func:`processing.calibration.load_calibration`) or
        :func:`processing.calibration.ideal_calibration`.

    Returns
    -------
    RectificationMaps
        float32 maps (exact to the float32 grid; fixed-point maps would round the source
        position to 1/32 px).
    """
    w, h = calib.image_size
    lx, ly = cv2.initUndistortRectifyMap(
        calib.K_left, calib.D_left, calib.R1, calib.P1, (w, h), cv2.CV_32FC1)
    rx, ry = cv2.initUndistortRectifyMap(
        calib.K_right, calib.D_right, calib.R2, calib.P2, (w, h), cv2.CV_32FC1)
    return RectificationMaps(
        left_x=lx, left_y=ly, right_x=rx, right_y=ry,
        valid_left=_valid(lx, ly, w, h), valid_right=_valid(rx, ry, w, h),
        image_size=(int(w), int(h)),
    )


def rectify_pair(
    left: np.ndarray,
    right: np.ndarray,
    maps: RectificationMaps,
    *,
    border_value: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Rectify one raw stereo pair (bilinear interpolation).

    Parameters
    ----------
    left, right : numpy.ndarray, shape (H, W)
        Raw (or radiometrically corrected) frames; uint8, uint16, float32 or float64.
    maps : RectificationMaps
        From :func:`rectification_maps`.
    border_value : float
        Value of rectified pixels that fall outside the raw image (see ``maps.valid_*``).

    Returns
    -------
    (left_r, right_r) : numpy.ndarray, shape (H, W), same dtype as the inputs
    """
    w, h = maps.image_size
    for name, img in (("left", left), ("right", right)):
        if img.shape[:2] != (h, w):
            raise ValueError(f"{name} image is {img.shape[1]}x{img.shape[0]} but the "
                             f"calibration is for {w}x{h}")
    return (
        cv2.remap(left, maps.left_x, maps.left_y, cv2.INTER_LINEAR,
                  borderMode=cv2.BORDER_CONSTANT, borderValue=border_value),
        cv2.remap(right, maps.right_x, maps.right_y, cv2.INTER_LINEAR,
                  borderMode=cv2.BORDER_CONSTANT, borderValue=border_value),
    )
