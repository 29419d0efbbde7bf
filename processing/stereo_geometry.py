"""What the scene-flow chain needs to know about the stereo pair (paper Fig. 1, Eq. 4).

:class:`StereoGeometry` holds the rectified camera constant, principal point and baseline,
and optionally the rectification maps and radiometric curves of a calibration file; it is
built from a calibration file or from a synthetic sequence's ideal cameras.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from processing.calibration import StereoCalibration, rectification_maps
from processing.calibration.radiometric import CharacteristicCurve

Maps = tuple[np.ndarray, np.ndarray]


@dataclass(frozen=True)
class StereoGeometry:
    """What the chain needs from a stereo calibration.

    Attributes
    ----------
    camera_constant : float
        Rectified camera constant s in px (Eq. 4).
    principal_point : (float, float)
        Rectified principal point (x0, y0) of the left image in px.
    baseline : float
        Stereo baseline b in m.
    image_size : (int, int)
        (W, H) of the raw frames.
    maps_left, maps_right : (map_x, map_y) or None
        Rectification maps (float32, (H, W) each); None when the raw frames are already
        rectified (ideal or simulated cameras).
    curve_left, curve_right : CharacteristicCurve or None
        Radiometric characteristic curves; None means counts are used as they are.
    """

    camera_constant: float
    principal_point: tuple[float, float]
    baseline: float
    image_size: tuple[int, int]
    maps_left: Maps | None = None
    maps_right: Maps | None = None
    curve_left: CharacteristicCurve | None = None
    curve_right: CharacteristicCurve | None = None

    @classmethod
    def from_calibration(cls, calib: StereoCalibration, *, rectify: bool = True) -> StereoGeometry:
        """Geometry, rectification maps and curves of a loaded calibration file."""
        maps_l = maps_r = None
        if rectify:
            maps = rectification_maps(calib)
            maps_l, maps_r = (maps.left_x, maps.left_y), (maps.right_x, maps.right_y)
        radio = calib.radiometric
        return cls(
            camera_constant=float(calib.s_px),
            principal_point=(float(calib.cx_px), float(calib.cy_px)),
            baseline=float(calib.b_m),
            image_size=(int(calib.image_size[0]), int(calib.image_size[1])),
            maps_left=maps_l,
            maps_right=maps_r,
            curve_left=radio.left if radio is not None else None,
            curve_right=radio.right if radio is not None else None,
        )

    @classmethod
    def from_synthetic_camera(cls, cam: Mapping[str, Any],
                              counts: Mapping[str, Mapping[str, float]] | None = None
                              ) -> StereoGeometry:
        """Geometry of a synthetic sequence's ideal, rectified camera pair.

        ``cam`` is the ``camera`` entry of a sequence's ``meta.json`` (``s_px``, ``cx_px``,
        ``cy_px``, ``b_m``, ``width``, ``height``, optional ``k1``/``k2``); ``counts`` its
        ``counts_model`` (``left`` and ``right``, each ``gain`` and ``offset``: counts =
        offset + gain L), given as the characteristic curves a radiometric calibration of
        those cameras would hold (None: no curves, counts used as they are).

        Raises
        ------
        ValueError
            When the cameras have lens distortion: the frames then need the calibration
            file the simulator writes, not this ideal geometry.
        """
        if cam.get("k1", 0.0) or cam.get("k2", 0.0):
            raise ValueError(
                f"the synthetic cameras have lens distortion (k1={cam.get('k1')}, "
                f"k2={cam.get('k2')}); use the matching calibration file instead")
        curves = (None, None) if counts is None else tuple(
            CharacteristicCurve.from_counts_model(counts[side]) for side in ("left", "right"))
        return cls(camera_constant=float(cam["s_px"]),
                   principal_point=(float(cam["cx_px"]), float(cam["cy_px"])),
                   baseline=float(cam["b_m"]),
                   image_size=(int(cam["width"]), int(cam["height"])),
                   curve_left=curves[0], curve_right=curves[1])
