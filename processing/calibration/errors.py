"""Errors of the calibration chain: all are ``ValueError`` (bad input), each names files."""

from __future__ import annotations


class CalibrationError(ValueError):
    """Base class: the calibration input cannot give a trustworthy calibration."""


class PairingError(CalibrationError):
    """Left and right images do not pair up (a file without a partner of the same name)."""


class ImageReadError(CalibrationError):
    """An image file cannot be decoded."""


class ImageSizeError(CalibrationError):
    """Images of different sizes where one size is required."""


class PatternNotFoundError(CalibrationError):
    """The calibration pattern was found in no image."""


class TooFewViewsError(CalibrationError):
    """Fewer usable stereo views than the calibration needs."""


class PoorCalibrationError(CalibrationError):
    """The calibration converged to a reprojection error too large to trust."""


class CalibrationFileError(CalibrationError):
    """A calibration file is unreadable, of another format, or has a bad key or value."""
