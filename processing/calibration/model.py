"""The stereo calibration as one typed object (paper Sec. 4.1, Eq. 4), and the ideal
calibration of an already rectified pair. Its YAML file: :mod:`processing.calibration.calfile`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from processing.calibration.radiometric import CharacteristicCurve

__all__ = ["RadiometricCalibration", "StereoCalibration", "ideal_calibration"]


@dataclass(frozen=True)
class RadiometricCalibration:
    """Characteristic curves of the two cameras; ``None`` for a camera without one."""

    left: CharacteristicCurve | None = None
    right: CharacteristicCurve | None = None


@dataclass(frozen=True)
class StereoCalibration:
    """Geometric (and optionally radiometric) calibration of the stereo OGI pair.

    Attributes
    ----------
    image_size : (int, int)
        (width, height) of the raw frames, pixels.
    K_left, K_right : numpy.ndarray, shape (3, 3), float64
        Camera matrices, pixels.
    D_left, D_right : numpy.ndarray, shape (n,), float64
        OpenCV distortion coefficients (k1, k2, p1, p2, k3, ...), n in {4, 5, 8, 12, 14}.
    R : numpy.ndarray, shape (3, 3), float64
        Rotation from the left to the right camera frame (X_r = R X_l + T).
    T : numpy.ndarray, shape (3,), float64
        Translation, metres.
    rms_px : float
        Stereo reprojection RMS error of the calibration, pixels (0 for an ideal model).
    R1, R2 : numpy.ndarray, shape (3, 3)
        Rectifying rotations of the left and right camera.
    P1, P2 : numpy.ndarray, shape (3, 4)
        Projection matrices of the rectified cameras, pixels (P2[0, 3] = -s b).
    Q : numpy.ndarray, shape (4, 4)
        Disparity-to-depth matrix (cv2.reprojectImageTo3D).
    radiometric : RadiometricCalibration or None
        Characteristic curves, when calibrated.
    meta : dict
        Provenance, free form (saved as the ``meta`` mapping).
    """

    image_size: tuple[int, int]
    K_left: np.ndarray
    D_left: np.ndarray
    K_right: np.ndarray
    D_right: np.ndarray
    R: np.ndarray
    T: np.ndarray
    rms_px: float
    R1: np.ndarray
    R2: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    Q: np.ndarray
    radiometric: RadiometricCalibration | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def s_px(self) -> float:
        """Camera constant of the rectified cameras (paper's s, Eq. 4), pixels."""
        return float(self.P1[0, 0])

    @property
    def cx_px(self) -> float:
        """Principal point x of the rectified left camera, pixels."""
        return float(self.P1[0, 2])

    @property
    def cy_px(self) -> float:
        """Principal point y of the rectified cameras, pixels."""
        return float(self.P1[1, 2])

    @property
    def b_m(self) -> float:
        """Baseline of the rectified pair (paper's b, Eq. 4), metres; > 0 for a right camera
        to the right of the left one."""
        return float(-self.P2[0, 3] / self.P2[0, 0])

    @property
    def width(self) -> int:
        """Image width, pixels."""
        return int(self.image_size[0])

    @property
    def height(self) -> int:
        """Image height, pixels."""
        return int(self.image_size[1])


def ideal_calibration(
    s_px: float,
    b_m: float,
    image_size: tuple[int, int] = (320, 240),
    cx_px: float | None = None,
    cy_px: float | None = None,
) -> StereoCalibration:
    """An ideal, already rectified pair: no distortion, parallel axes, horizontal baseline.

    This is the geometry of the simulated cameras; rectifying with it is the identity.

    Parameters
    ----------
    s_px : float
        Camera constant (focal length), pixels.
    b_m : float
        Baseline, metres (> 0: right camera to the right).
    image_size : (width, height)
        Pixels.
    cx_px, cy_px : float, optional
        Principal point, pixels; default the image centre ((w - 1) / 2, (h - 1) / 2).
    """
    w, h = image_size
    if s_px <= 0 or b_m <= 0 or w <= 0 or h <= 0:
        raise ValueError(f"ideal calibration needs s > 0, b > 0 and a positive image size, got "
                         f"s={s_px} px, b={b_m} m, size={image_size}")
    cx = (w - 1) / 2.0 if cx_px is None else float(cx_px)
    cy = (h - 1) / 2.0 if cy_px is None else float(cy_px)
    K = np.array([[s_px, 0.0, cx], [0.0, s_px, cy], [0.0, 0.0, 1.0]])
    eye = np.eye(3)
    P1 = np.hstack([K, np.zeros((3, 1))])
    P2 = P1.copy()
    P2[0, 3] = -s_px * b_m
    Q = np.array([
        [1.0, 0.0, 0.0, -cx],
        [0.0, 1.0, 0.0, -cy],
        [0.0, 0.0, 0.0, s_px],
        [0.0, 0.0, 1.0 / b_m, 0.0],
    ])
    return StereoCalibration(
        image_size=(int(w), int(h)), K_left=K, D_left=np.zeros(5), K_right=K.copy(),
        D_right=np.zeros(5), R=eye, T=np.array([-b_m, 0.0, 0.0]), rms_px=0.0,
        R1=eye.copy(), R2=eye.copy(), P1=P1, P2=P2, Q=Q, meta={"source": "ideal"},
    )
