"""Wind from a sensor's own axes into the left camera frame.

Frames (all right-handed unless stated):

- **native**: the axes in which a protocol reports u, v, w (:data:`NATIVE_AXES`).
- **sensor reference frame** (F, L, U): F points along the sensor's north mark (Gill's "N"
  spar, R.M. Young's and METEK's north mark, the direction a CSAT3B's array points away from
  its mounting block), L 90 deg to the left of F seen from above, U straight up. The
  anemometer is assumed level (U is the local vertical).
- **left camera frame** (X, Y, Z): X right in the image, Y down in the image, Z forward along
  the optical axis (OpenCV's convention), with origin at the left camera.

Wind vectors are "blowing toward": a wind component +1 m/s along an axis moves air along that
axis.

Native axes per protocol (columns: where each native axis points in F, L, U):

========================  =================================================  ==========
protocol                  native axes                                        handedness
========================  =================================================  ==========
gill, gill_uvw            +U toward the N mark, +V 90 deg anticlockwise       right
                          (seen from above), +W up
gill_polar                same U, V after polar -> U, V; W not measured      right
campbell_csat3b           +Ux wind entering the array from the front         right
                          (toward the block), +Uy from left to right
                          (seen from behind the block), +Uz up
young_81000(_uvw)         +U toward the right of the mark ("east" when the   right
                          mark points north), +V toward the mark, +W up
metek_usonic3             +x toward the mark, +y 90 deg clockwise, +z up     LEFT
========================  =================================================  ==========

These follow the manufacturers' descriptions as we read them; a site whose sensor is set up
differently (or to be sure: check with a known wind) overrides them with ``native_axes``.

Site mounting (the ``mounting`` mapping of the anemometer config), either

- ``azimuth_deg``: angle, seen from above, from the camera's optical axis (projected on the
  horizontal) to the sensor's north mark, clockwise positive (90 = the mark points to the
  camera's right); ``tilt_deg``: the camera's pitch, positive when it looks down;
  ``roll_deg``: the camera's rotation about its optical axis, positive clockwise as seen from
  behind the camera. Defaults 0.
- or ``matrix``: a full 3x3 rotation (rows X, Y, Z; columns F, L, U) taking a vector in the
  sensor reference frame to the camera frame (orthonormal, determinant +1).

and optionally ``native_axes``: a 3x3 matrix (rows F, L, U; columns the native axes),
orthonormal with determinant +1 or -1 (a left-handed sensor).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.anemometer.base import AnemometerConfigError, WindSample

_GILL = np.eye(3)
NATIVE_AXES: dict[str, np.ndarray] = {
    "gill": _GILL,
    "gill_uvw": _GILL,
    "gill_polar": _GILL,
    "campbell_csat3b": np.diag([-1.0, -1.0, 1.0]),
    "young_81000": np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),
    "young_81000_uvw": np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),
    "metek_usonic3": np.diag([1.0, -1.0, 1.0]),
}

MOUNTING_KEYS = frozenset(("azimuth_deg", "tilt_deg", "roll_deg", "matrix", "native_axes"))


def reference_to_camera(
    azimuth_deg: float, tilt_deg: float = 0.0, roll_deg: float = 0.0
) -> np.ndarray:
    """Rotation (3, 3) float64 from the sensor reference frame (F, L, U) to the camera frame.

    See the module docstring for the meaning and signs of the angles (degrees).
    """
    a = math.radians(azimuth_deg)
    t = math.radians(tilt_deg)
    r = math.radians(roll_deg)
    # Level camera frame (X0 right, Y0 down, Z0 forward): columns are F, L, U.
    level = np.array(
        [
            [math.sin(a), -math.cos(a), 0.0],
            [0.0, 0.0, -1.0],
            [math.cos(a), math.sin(a), 0.0],
        ]
    )
    # Pitch down by t about X: the optical axis dips toward +Y0.
    pitch = np.array(
        [[1.0, 0.0, 0.0], [0.0, math.cos(t), -math.sin(t)], [0.0, math.sin(t), math.cos(t)]]
    )
    # Roll clockwise (seen from behind) about Z: the camera's X turns toward the old +Y.
    roll = np.array(
        [[math.cos(r), math.sin(r), 0.0], [-math.sin(r), math.cos(r), 0.0], [0.0, 0.0, 1.0]]
    )
    return roll @ pitch @ level


def _matrix(value: Any, key: str, *, proper: bool) -> np.ndarray:
    try:
        m = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise AnemometerConfigError(f"mounting.{key} must be a 3x3 matrix of numbers") from None
    if m.shape != (3, 3) or not np.all(np.isfinite(m)):
        raise AnemometerConfigError(f"mounting.{key} must be a finite 3x3 matrix, got {value!r}")
    if not np.allclose(m @ m.T, np.eye(3), atol=1e-3):
        raise AnemometerConfigError(f"mounting.{key} is not orthonormal (M M^T != I): {value!r}")
    det = float(np.linalg.det(m))
    if proper and det < 0:
        raise AnemometerConfigError(
            f"mounting.{key} has determinant {det:+.3f}; a mounting must be a rotation (+1)"
        )
    return m


@dataclass(frozen=True)
class CameraWind:
    """A wind sample in the left camera frame.

    ``vector`` (3,) float64 m/s in X right, Y down, Z forward. ``vertical_measured`` is False
    for 2-D sensors: their vertical component was taken as 0 before the rotation.
    """

    host_ns: int
    vector: np.ndarray
    valid: bool
    vertical_measured: bool


class Mounting:
    """Native sensor axes -> left camera frame for one installed anemometer.

    Parameters
    ----------
    protocol : str
        Registry name of the protocol (selects the native axes).
    reference_to_camera : ndarray (3, 3)
        Rotation from the sensor reference frame to the camera frame.
    native_axes : ndarray (3, 3), optional
        Overrides :data:`NATIVE_AXES` for this protocol.
    """

    def __init__(
        self,
        protocol: str,
        reference_to_camera: np.ndarray,
        native_axes: np.ndarray | None = None,
    ) -> None:
        if native_axes is None:
            try:
                native_axes = NATIVE_AXES[protocol]
            except KeyError:
                raise AnemometerConfigError(
                    f"no native axes known for protocol {protocol!r}; give mounting.native_axes"
                ) from None
        self.protocol = protocol
        #: (3, 3) float64: native (u, v, w) -> camera (X, Y, Z).
        self.rotation = np.asarray(reference_to_camera, dtype=np.float64) @ np.asarray(
            native_axes, dtype=np.float64
        )

    @classmethod
    def from_config(cls, protocol: str, config: Mapping[str, Any] | None) -> Mounting:
        """Build from the ``mounting`` mapping of the config (keys: see the module docstring)."""
        config = dict(config or {})
        unknown = set(config) - MOUNTING_KEYS
        if unknown:
            raise AnemometerConfigError(
                f"unknown mounting key(s) {sorted(unknown)}; known: {sorted(MOUNTING_KEYS)}"
            )
        angles = {"azimuth_deg", "tilt_deg", "roll_deg"} & set(config)
        if "matrix" in config:
            if angles:
                raise AnemometerConfigError(
                    f"mounting: give either 'matrix' or angles, not both (got {sorted(angles)})"
                )
            ref = _matrix(config["matrix"], "matrix", proper=True)
        else:
            names = ("azimuth_deg", "tilt_deg", "roll_deg")
            try:
                values = {k: float(config.get(k, 0.0)) for k in names}
            except (TypeError, ValueError):
                raise AnemometerConfigError(
                    f"mounting angles must be numbers: {config!r}"
                ) from None
            ref = reference_to_camera(**values)
        native = None
        if "native_axes" in config:
            native = _matrix(config["native_axes"], "native_axes", proper=False)
        return cls(protocol, ref, native)

    def to_camera(self, sample: WindSample) -> CameraWind:
        """The sample's wind in the left camera frame."""
        w = sample.w
        vertical = not math.isnan(w)
        vec = self.rotation @ np.array((sample.u, sample.v, w if vertical else 0.0))
        return CameraWind(sample.host_ns, vec, sample.valid, vertical)
