"""Cameras: one interface (:class:`Camera`, :class:`Frame`), back ends chosen by name.

>>> from drivers.camera import create_camera
>>> cam = create_camera("simulated", side="left")  # doctest: +SKIP
"""

from drivers.camera.base import (
    PIXEL_FORMATS,
    Camera,
    CameraBackendMissing,
    CameraDisconnected,
    CameraError,
    CameraStats,
    CameraTimeout,
    Capture,
    EndOfStream,
    Frame,
    State,
)
from drivers.camera.registry import BACKENDS, camera_class, create_camera

__all__ = [
    "BACKENDS",
    "PIXEL_FORMATS",
    "Camera",
    "CameraBackendMissing",
    "CameraDisconnected",
    "CameraError",
    "CameraStats",
    "CameraTimeout",
    "Capture",
    "EndOfStream",
    "Frame",
    "State",
    "camera_class",
    "create_camera",
]
