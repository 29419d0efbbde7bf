"""Camera back ends by name: ``"module:Class"`` strings, imported only when chosen.

An optional back end (Aravis needs PyGObject and system libraries) costs nothing when it is
not used and fails with a message naming what to install when it is (python-can's
``BACKENDS`` table is the model).
"""

from __future__ import annotations

import importlib
import inspect
from typing import Any

from drivers.camera.base import Camera, CameraBackendMissing

#: Back-end name (the ``backend:`` key of a camera in the config) -> "module:Class".
BACKENDS: dict[str, str] = {
    "aravis": "drivers.camera.aravis:AravisCamera",
    "opencv": "drivers.camera.opencv:OpenCVCamera",
    "replay_folder": "drivers.camera.replay_folder:FolderReplayCamera",
    "replay_mcap": "drivers.camera.replay_mcap:McapReplayCamera",
    "simulated": "drivers.camera.simulated:SimulatedCamera",
}

#: What to install when a back end's import fails.
INSTALL_HINTS: dict[str, str] = {
    "aravis": (
        "the Aravis back end needs the Debian packages gir1.2-aravis-0.8 (library and "
        "typelib) and, to build PyGObject, libgirepository1.0-dev libcairo2-dev pkg-config, "
        "then the Python extra: pip install 'ogiflow[gige]' (pygobject<3.51); "
        "tools/install.sh --dev installs all of it"
    ),
}


def camera_class(name: str) -> type[Camera]:
    """Import and return the camera class registered as ``name``.

    Raises
    ------
    ValueError
        ``name`` is not a registered back end (the message lists them).
    CameraBackendMissing
        The back end's optional dependencies are not installed (the message says what to
        install; the original ImportError is chained).
    """
    try:
        target = BACKENDS[name]
    except KeyError:
        raise ValueError(
            f"unknown camera back end {name!r}; available: {', '.join(sorted(BACKENDS))}"
        ) from None
    module_name, class_name = target.split(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        if isinstance(exc, CameraBackendMissing):
            raise
        hint = INSTALL_HINTS.get(name, "install its dependencies")
        raise CameraBackendMissing(
            f"camera back end {name!r} is unavailable ({exc}); {hint}"
        ) from exc
    cls = getattr(module, class_name)
    if not (isinstance(cls, type) and issubclass(cls, Camera)):
        raise TypeError(f"{target} is not a Camera subclass")
    return cls


def create_camera(name: str, **options: Any) -> Camera:
    """Create (not open) a camera of back end ``name`` with keyword ``options``.

    Unknown option names raise ``ValueError`` naming them and the accepted ones, so a typo
    in the config fails at start-up rather than being ignored.
    """
    cls = camera_class(name)
    params = inspect.signature(cls.__init__).parameters
    accepted = {p for p in params if p != "self"}
    unknown = sorted(set(options) - accepted)
    if unknown:
        raise ValueError(
            f"camera back end {name!r} has no option(s) {', '.join(unknown)}; "
            f"accepted: {', '.join(sorted(accepted))}"
        )
    return cls(**options)
