"""Stereo geometric and radiometric calibration of the OGI camera pair (paper Sec. 4.1).

Public API used by the rest of ogiflow::

    calib = load_calibration("calibration.yaml")        # or ideal_calibration(s, b, size)
    maps = rectification_maps(calib)                    # once per calibration
    left_rad = apply_characteristic_curve(raw_left, calib.radiometric.left
                                          if calib.radiometric else None)
    left_r, right_r = rectify_pair(left_rad, right_rad, maps)
    # s = calib.s_px, (cx, cy) = calib.cx_px, calib.cy_px, b = calib.b_m  (paper Eq. 4)
"""

from processing.calibration.calfile import (
    load_calibration,
    load_radiometric,
    save_calibration,
    save_radiometric,
)
from processing.calibration.errors import (
    CalibrationError,
    CalibrationFileError,
    ImageReadError,
    ImageSizeError,
    PairingError,
    PatternNotFoundError,
    PoorCalibrationError,
    TooFewViewsError,
)
from processing.calibration.model import (
    RadiometricCalibration,
    StereoCalibration,
    ideal_calibration,
)
from processing.calibration.pattern import PatternSpec, detect_pattern, object_points
from processing.calibration.radiometric import (
    CharacteristicCurve,
    apply_characteristic_curve,
    band_radiance,
    fit_characteristic_curve,
    roi_means,
)
from processing.calibration.rectify import (
    RectificationMaps,
    rectification_maps,
    rectify_pair,
    stereo_rectification,
)
from processing.calibration.stereo import (
    StereoCalibrationResult,
    ViewReport,
    calibrate_stereo_images,
    calibrate_stereo_points,
)

__all__ = [
    "CalibrationError",
    "CalibrationFileError",
    "CharacteristicCurve",
    "ImageReadError",
    "ImageSizeError",
    "PairingError",
    "PatternNotFoundError",
    "PatternSpec",
    "PoorCalibrationError",
    "RadiometricCalibration",
    "RectificationMaps",
    "StereoCalibration",
    "StereoCalibrationResult",
    "TooFewViewsError",
    "ViewReport",
    "apply_characteristic_curve",
    "band_radiance",
    "calibrate_stereo_images",
    "calibrate_stereo_points",
    "detect_pattern",
    "fit_characteristic_curve",
    "ideal_calibration",
    "load_calibration",
    "load_radiometric",
    "object_points",
    "rectification_maps",
    "rectify_pair",
    "roi_means",
    "save_calibration",
    "save_radiometric",
    "stereo_rectification",
]
