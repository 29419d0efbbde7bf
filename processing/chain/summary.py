"""Per-frame summary of the 3D gas velocity over the gas region (paper Sec. 5.2, footnote 1).

Only pixels that are gas (segmentation, Eq. 9) AND valid (finite velocity with d > 0 and
d + d' > 0, Eq. 4) enter the mean. The directional angles are those of the paper's footnote 1:
the inverse cosine of each component of the normalised mean vector, in degrees, i.e. the
angles between the mean velocity and the camera axes X (right), Y (down), Z (forward).

A summary never holds a non-finite number. When no pixel qualifies (no gas, or no valid
velocity inside it) or the mean vector is exactly zero (no direction), the affected fields are
``None`` and ``valid`` is False; a recorder or live view prints "no gas" instead of a number.
An exactly zero mean vector keeps its mean and speed (0) but has no direction: angles None,
``valid`` False.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np


@dataclass(frozen=True)
class GasSummary:
    """Summary of one frame.

    Attributes
    ----------
    valid : bool
        True when at least one gas pixel had a valid velocity and the mean vector is
        non-zero; then every field below is a finite float.
    pixel_count : int
        Gas pixels with a valid velocity (the pixels averaged), >= 0.
    gas_pixel_count : int
        All gas pixels of the segmentation (valid velocity or not).
    mean_velocity : tuple of 3 float or None
        Mean (V_X, V_Y, V_Z) in m/s, left camera frame (X right, Y down, Z forward); None
        when pixel_count is 0.
    speed : float or None
        |mean velocity| in m/s.
    angles_deg : tuple of 3 float or None
        (theta_X, theta_Y, theta_Z) = arccos(V / |V|) in degrees, each in [0, 180].
    c_usf : float or None
        Quality coefficient c_USF of the frame (Eq. 8), passed through; None when not given
        or not finite.
    flags : tuple of str
        What the chain detected in this frame that makes the number weaker or invalid
        (:data:`FLAGS`); empty when nothing was detected.
    """

    valid: bool
    pixel_count: int
    gas_pixel_count: int
    mean_velocity: tuple[float, float, float] | None
    speed: float | None
    angles_deg: tuple[float, float, float] | None
    c_usf: float | None
    flags: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, object]:
        """Plain dict (JSON-ready: tuples become lists by ``json``, None becomes null)."""
        return asdict(self)


#: Flags a summary can carry, with what they tell an operator.
FLAGS: dict[str, str] = {
    "no_gas": "no gas segmented (no number)",
    "jitter_corrected": "camera jitter was measured on the static background and removed",
    "registration_rejected": "the background has no static texture to measure jitter on "
                             "(sky, uniform wall): jitter, if any, is in the velocity (V_Z "
                             "most of all)",
    "low_contrast": "the gas signal is within a few times the camera noise: the velocity is "
                    "uncertain, its depth component V_Z most of all (the data no longer fix "
                    "the disparity change's offset, which keeps its earlier value)",
    "object_motion_rejected": "moving image regions outside the gas depth band or without "
                              "stereo consistency (objects, not gas) were excluded",
    "implausible_speed": "the mean gas speed exceeded max_gas_speed_m_s (a wrong disparity, "
                         "e.g. from two frames of different moments paired): not a "
                         "measurement, and the next triple starts cold",
    "offset_levelled": "a camera's whole picture stepped between two frames (a flat-field "
                       "shutter, a non-uniformity correction, a drift of its offset) and the "
                       "step was levelled out of the differential image: informational, the "
                       "velocity reads as without it",
    "scene_change": "the whole picture changed at once (camera bumped, a jump in the "
                    "scene, a garbled frame): this triple started cold, its velocity is not "
                    "gas motion and it has no emission rate",
}


def directional_angles(vector: np.ndarray) -> tuple[float, float, float] | None:
    """Directional angles of footnote 1: arccos of each component of v / |v|, in degrees.

    Parameters
    ----------
    vector : array-like, shape (3,)
        A finite 3D vector.

    Returns
    -------
    (float, float, float) or None
        Angles to X, Y, Z in degrees; None for the zero vector (no direction).
    """
    v = np.asarray(vector, dtype=np.float64)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"vector must be 3 finite numbers, got {vector!r}")
    norm = float(np.linalg.norm(v))
    if norm == 0.0:
        return None
    cosines = np.clip(v / norm, -1.0, 1.0)
    a = np.degrees(np.arccos(cosines))
    return float(a[0]), float(a[1]), float(a[2])


def summarize_frame(
    velocity: np.ndarray,
    valid: np.ndarray,
    gas_mask: np.ndarray,
    c_usf: float | None = None,
    flags: tuple[str, ...] = (),
) -> GasSummary:
    """Mean 3D gas velocity, its magnitude and directional angles over gas & valid pixels.

    Parameters
    ----------
    velocity : ndarray, shape (H, W, 3), float
        3D velocity V (Eq. 4) in m/s per pixel. Values at invalid pixels are ignored (they
        may be NaN or inf).
    valid : ndarray, shape (H, W), bool
        True where V is defined (d > 0 and d + d' > 0).
    gas_mask : ndarray, shape (H, W), bool
        Gas region Omega_g from the segmentation.
    c_usf : float or None
        c_USF of the frame (Eq. 8), reported unchanged when finite.
    flags : tuple of str
        Keys of :data:`FLAGS` detected by the chain; ``no_gas`` is added here when no pixel
        qualifies.

    Returns
    -------
    GasSummary

    Raises
    ------
    ValueError
        Wrong shapes or dtypes (masks must be boolean).
    """
    if not isinstance(velocity, np.ndarray) or velocity.ndim != 3 or velocity.shape[2] != 3:
        got = getattr(velocity, "shape", type(velocity).__name__)
        raise ValueError(f"velocity must have shape (H, W, 3), got {got}")
    if not np.issubdtype(velocity.dtype, np.floating):
        raise ValueError(f"velocity must be floating point, got {velocity.dtype}")
    shape = velocity.shape[:2]
    for name, m in (("valid", valid), ("gas_mask", gas_mask)):
        if not isinstance(m, np.ndarray) or m.shape != shape:
            got = getattr(m, "shape", type(m).__name__)
            raise ValueError(f"{name} must have shape {shape}, got {got}")
        if m.dtype != np.bool_:
            raise ValueError(f"{name} must be a boolean mask, got {m.dtype}")
    unknown = [f for f in flags if f not in FLAGS]
    if unknown:
        raise ValueError(f"unknown summary flag(s) {unknown}; known: {', '.join(FLAGS)}")
    c = None
    if c_usf is not None:
        cf = float(c_usf)
        c = cf if math.isfinite(cf) else None

    # A 'valid' pixel whose velocity is nevertheless non-finite is not averaged either:
    # nothing non-finite may reach a summary.
    # (Tested at the gas pixels only: over the whole (H, W, 3) field the test was 2 % of a
    # live worker's time, measured.)
    cand = np.flatnonzero(gas_mask & valid)
    v = velocity.reshape(-1, 3)[cand]
    finite = np.isfinite(v)
    if not finite.all():  # (the row test alone took 0.7 ms on a 19,000-pixel plume)
        v = v[finite.all(axis=1)]
    n = len(v)
    n_gas = int(np.count_nonzero(gas_mask))
    if n == 0:
        return GasSummary(False, 0, n_gas, None, None, None, c,
                          tuple(dict.fromkeys((*flags, "no_gas"))))
    mean = v.astype(np.float64).mean(axis=0)
    angles = directional_angles(mean)
    vx, vy, vz = (float(x) for x in mean)
    speed = float(np.linalg.norm(mean))
    # An exactly zero mean has a speed (0) but no direction: flagged, angles None.
    return GasSummary(angles is not None, n, n_gas, (vx, vy, vz), speed, angles, c,
                      tuple(flags))
