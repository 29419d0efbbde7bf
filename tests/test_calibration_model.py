"""The calibration YAML: round trip, validation naming the key, radiometric merging."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import yaml

from processing.calibration import (
    CalibrationFileError,
    CharacteristicCurve,
    RadiometricCalibration,
    ideal_calibration,
    load_calibration,
    load_radiometric,
    save_calibration,
    save_radiometric,
    stereo_rectification,
)
from processing.calibration.rig import example_rig

CURVE_L = CharacteristicCurve(offset=12000.0, gain=45000.0, residual_rms_counts=0.4,
                              temperatures_k=(293.15, 323.15), residuals_counts=(0.1, -0.1),
                              radiance_range=(0.03, 0.08), frames_per_temperature=(5, 5))
CURVE_R = CharacteristicCurve(offset=11000.0, gain=47000.0, curvature=-2.0e4)


def _calib():
    rig = example_rig()
    return stereo_rectification(rig.K_left, rig.D_left, rig.K_right, rig.D_right, rig.R, rig.T,
                                rig.image_size, rms_px=0.12, meta={"note": "test"})


def test_round_trip_keeps_every_value(tmp_path: Path) -> None:
    calib = dataclasses.replace(_calib(), radiometric=RadiometricCalibration(CURVE_L, CURVE_R))
    path = tmp_path / "c.yaml"
    save_calibration(path, calib)
    raw = yaml.safe_load(path.read_text())
    for key in ("image_size", "K_left", "D_left", "K_right", "D_right", "R", "T", "rms_px",
                "R1", "R2", "P1", "P2", "Q", "s_px", "cx_px", "cy_px", "b_m", "radiometric",
                "format", "version"):
        assert key in raw, key
    back = load_calibration(path)
    for key in ("K_left", "D_left", "K_right", "D_right", "R", "T", "R1", "R2", "P1", "P2", "Q"):
        np.testing.assert_array_equal(getattr(back, key), getattr(calib, key))
    assert back.image_size == (320, 240)
    assert back.s_px == calib.s_px and back.b_m == calib.b_m
    assert back.b_m == pytest.approx(np.linalg.norm(example_rig().T), rel=1e-9)
    assert back.radiometric == calib.radiometric
    assert back.meta["note"] == "test"


def test_ideal_calibration_round_trip(tmp_path: Path) -> None:
    calib = ideal_calibration(420.0, 0.35, (320, 240))
    save_calibration(tmp_path / "i.yaml", calib)
    back = load_calibration(tmp_path / "i.yaml")
    assert (back.s_px, back.b_m, back.cx_px, back.cy_px) == (420.0, pytest.approx(0.35),
                                                             159.5, 119.5)
    assert back.radiometric is None


def _write(path: Path, data: dict) -> Path:
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize(("edit", "message"), [
    (lambda d: d.pop("K_left"), "missing key 'K_left'"),
    (lambda d: d.update(K_right=[[1, 0], [0, 1]]), "'K_right' must have shape"),
    (lambda d: d.update(D_left=[0.1, 0.2, 0.3]), "'D_left'"),
    (lambda d: d.update(T="far"), "'T' is not a numeric array"),
    (lambda d: d.update(R=[[1, 0, 0], [0, 1, 0], [0, 0, 2]]), "'R' is not a rotation"),
    (lambda d: d.update(image_size=[320]), "'image_size'"),
    (lambda d: d.update(b_m=1.0), "'b_m' = 1.0 disagrees"),
    (lambda d: d.update(rms_px=-1), "'rms_px'"),
    (lambda d: d.update(baseline=0.3), "unknown key"),
    (lambda d: d.update(meta=[1, 2]), "'meta'"),
    (lambda d: d.update(format="opencv"), "'format'"),
    (lambda d: d.update(version=99), "'version'"),
    (lambda d: d.update(radiometric={"left": {"gain": 1.0}}), "'radiometric.left.offset'"),
    (lambda d: d.update(radiometric={"left": {"offset": 1.0, "gain": -1.0}}), "gain"),
    (lambda d: d.update(radiometric={"middle": {}}), "unknown key"),
])
def test_load_names_the_bad_key(tmp_path: Path, edit, message) -> None:
    save_calibration(tmp_path / "ok.yaml", _calib())
    data = yaml.safe_load((tmp_path / "ok.yaml").read_text())
    edit(data)
    path = _write(tmp_path / "bad.yaml", data)
    with pytest.raises(CalibrationFileError, match=message) as exc:
        load_calibration(path)
    assert str(path) in str(exc.value)


def test_load_rejects_non_yaml_and_non_mapping(tmp_path: Path) -> None:
    (tmp_path / "a.yaml").write_text("K_left: [1, 2\n")
    with pytest.raises(CalibrationFileError, match="not valid YAML"):
        load_calibration(tmp_path / "a.yaml")
    (tmp_path / "b.yaml").write_text("- 1\n- 2\n")
    with pytest.raises(CalibrationFileError, match="mapping"):
        load_calibration(tmp_path / "b.yaml")
    (tmp_path / "c.yaml").write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(CalibrationFileError):
        load_calibration(tmp_path / "c.yaml")
    with pytest.raises(OSError):
        load_calibration(tmp_path / "missing.yaml")


def test_radiometric_only_file_then_geometry(tmp_path: Path) -> None:
    path = tmp_path / "cal.yaml"
    save_radiometric(path, RadiometricCalibration(left=CURVE_L, right=None))
    assert load_radiometric(path) == RadiometricCalibration(left=CURVE_L, right=None)
    with pytest.raises(CalibrationFileError, match="only a radiometric"):
        load_calibration(path)


def test_save_radiometric_keeps_geometry(tmp_path: Path) -> None:
    path = tmp_path / "cal.yaml"
    calib = _calib()
    save_calibration(path, calib)
    save_radiometric(path, RadiometricCalibration(CURVE_L, CURVE_R))
    back = load_calibration(path)
    np.testing.assert_array_equal(back.P2, calib.P2)
    assert back.radiometric == RadiometricCalibration(CURVE_L, CURVE_R)
    # A second fit replaces the section.
    save_radiometric(path, RadiometricCalibration(CURVE_R, CURVE_L))
    assert load_calibration(path).radiometric == RadiometricCalibration(CURVE_R, CURVE_L)


def test_save_radiometric_refuses_to_overwrite_a_broken_file(tmp_path: Path) -> None:
    path = tmp_path / "cal.yaml"
    save_calibration(path, _calib())
    data = yaml.safe_load(path.read_text())
    data["K_left"] = [[1.0]]
    _write(path, data)
    before = path.read_text()
    with pytest.raises(CalibrationFileError, match="K_left"):
        save_radiometric(path, RadiometricCalibration(CURVE_L, CURVE_R))
    assert path.read_text() == before


def test_rectification_refuses_swapped_or_vertical_cameras() -> None:
    rig = example_rig()
    with pytest.raises(ValueError, match="swap"):
        stereo_rectification(rig.K_left, rig.D_left, rig.K_right, rig.D_right, rig.R, -rig.T,
                             rig.image_size)
    with pytest.raises(ValueError, match="horizontal"):
        stereo_rectification(rig.K_left, rig.D_left, rig.K_right, rig.D_right, rig.R,
                             np.array([0.0, -0.25, 0.0]), rig.image_size)
