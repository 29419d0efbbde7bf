"""Back-end registry: lazy imports, clear messages for missing optional packages."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from drivers.camera import BACKENDS, Camera, CameraBackendMissing, camera_class


@pytest.mark.parametrize("name", ["opencv", "replay_folder", "replay_mcap", "simulated"])
def test_builtin_backends_import_and_are_cameras(name: str) -> None:
    cls = camera_class(name)
    assert issubclass(cls, Camera) and cls.backend == name


def test_missing_aravis_names_what_to_install(monkeypatch: pytest.MonkeyPatch) -> None:
    # Hide PyGObject as on a machine without the gige extra.
    monkeypatch.setitem(sys.modules, "gi", None)
    monkeypatch.delitem(sys.modules, "drivers.camera.aravis", raising=False)
    with pytest.raises(CameraBackendMissing) as exc:
        camera_class("aravis")
    msg = str(exc.value)
    assert "gir1.2-aravis-0.8" in msg and "pygobject<3.51" in msg
    assert "libgirepository1.0-dev" in msg
    monkeypatch.delitem(sys.modules, "drivers.camera.aravis", raising=False)


def test_importing_the_package_does_not_import_optional_backends() -> None:
    import subprocess

    code = (
        "import sys, drivers.camera as c; c.create_camera('simulated');"
        "print('gi' in sys.modules, 'drivers.camera.aravis' in sys.modules)"
    )
    root = Path(__file__).resolve().parents[1]
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=root
    )
    assert out.stdout.split() == ["False", "False"]
    assert set(BACKENDS) == {"aravis", "opencv", "replay_folder", "replay_mcap", "simulated"}
