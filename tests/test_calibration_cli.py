"""End to end: ``ogiflow calibrate stereo`` / ``radiometric`` on files written to tmp_path."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from appliance import cli
from processing.calibration import load_calibration, save_calibration
from processing.calibration.pattern import PatternSpec
from processing.calibration.radiometric import band_radiance, celsius_to_kelvin
from processing.calibration.rig import example_rig, random_target_poses, render_stereo_views

RIG = example_rig()
SPEC = PatternSpec("chessboard", 6, 9, 0.05)


@pytest.fixture(scope="module")
def image_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("calib_images")
    rng = np.random.default_rng(11)
    poses = random_target_poses(RIG, SPEC, 13, rng, distance_m=(1.0, 1.8))
    for side in ("left", "right"):
        (root / side).mkdir()
    for name, left, right in render_stereo_views(RIG, SPEC, poses, rng):
        assert cv2.imwrite(str(root / "left" / name), left)
        assert cv2.imwrite(str(root / "right" / name), right)
    return root


def test_calibrate_stereo_end_to_end(image_dir: Path, tmp_path: Path,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "calibration.yaml"
    code = cli.main(["calibrate", "stereo", "--images", str(image_dir), "--pattern",
                     "chessboard", "--rows", "6", "--cols", "9", "--spacing", "50",
                     "--out", str(out)])
    text = capsys.readouterr().out
    assert code == 0, text
    assert "RMS reprojection error per view" in text
    assert "view00.png" in text and "dropped as outliers:" in text
    assert "b = " in text and "s = " in text
    calib = load_calibration(out)
    assert calib.image_size == (320, 240)
    assert calib.K_left[0, 0] == pytest.approx(RIG.K_left[0, 0], rel=0.005)
    assert calib.K_right[0, 0] == pytest.approx(RIG.K_right[0, 0], rel=0.005)
    assert calib.b_m == pytest.approx(np.linalg.norm(RIG.T), rel=0.01)
    assert calib.rms_px < 0.3
    assert calib.meta["pattern"]["spacing_m"] == pytest.approx(0.05)


def test_calibrate_stereo_mismatched_pair_exits_2(image_dir: Path, tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    for side in ("left", "right"):
        (tmp_path / side).mkdir()
        for f in sorted((image_dir / side).iterdir())[:7]:
            (tmp_path / side / f.name).write_bytes(f.read_bytes())
    (tmp_path / "right" / "view03.png").unlink()
    code = cli.main(["calibrate", "stereo", "--images", str(tmp_path), "--pattern",
                     "chessboard", "--rows", "6", "--cols", "9", "--spacing", "50",
                     "--out", str(tmp_path / "c.yaml")])
    assert code == cli.EXIT_USAGE
    err = capsys.readouterr().err
    assert "view03.png" in err and "without a partner" in err
    assert not (tmp_path / "c.yaml").exists()


def test_calibrate_stereo_corrupt_image_exits_2(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    for side in ("left", "right"):
        (tmp_path / side).mkdir()
        (tmp_path / side / "a.png").write_bytes(b"\x89PNG truncated")
    code = cli.main(["calibrate", "stereo", "--images", str(tmp_path), "--pattern", "circles",
                     "--rows", "4", "--cols", "5", "--spacing", "30"])
    assert code == cli.EXIT_USAGE
    assert "a.png" in capsys.readouterr().err


def _write_blackbody(root: Path, temps_c: list[float], gain: float, offset: float,
                     rng: np.random.Generator) -> None:
    for i, t in enumerate(temps_c):
        folder = root / f"t{int(t)}"
        folder.mkdir(parents=True)
        level = offset + gain * band_radiance(celsius_to_kelvin(t))
        for k in range(4):
            frame = np.clip(np.rint(level + rng.normal(0, 15, (240, 320))), 0, 65535)
            assert cv2.imwrite(str(folder / f"f{i}_{k}.png"), frame.astype(np.uint16))


def test_calibrate_radiometric_adds_curves(tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    rng = np.random.default_rng(2)
    temps = [25.0, 40.0, 55.0, 70.0, 100.0]  # natural order: t25 < t40 < ... < t100
    _write_blackbody(tmp_path / "L", temps, 45000.0, 12000.0, rng)
    _write_blackbody(tmp_path / "R", temps, 50000.0, 9000.0, rng)
    out = tmp_path / "calibration.yaml"
    from processing.calibration import ideal_calibration

    save_calibration(out, ideal_calibration(400.0, 0.25))
    code = cli.main(["calibrate", "radiometric", "--left", str(tmp_path / "L"), "--right",
                     str(tmp_path / "R"), "--temperatures", ",".join(map(str, temps)),
                     "--out", str(out)])
    text = capsys.readouterr().out
    assert code == 0, text
    assert "t100" in text and "counts = " in text
    calib = load_calibration(out)  # geometry kept
    assert calib.s_px == 400.0
    rad = calib.radiometric
    assert rad is not None and rad.left is not None and rad.right is not None
    assert rad.left.gain == pytest.approx(45000.0, rel=0.01)
    assert rad.left.offset == pytest.approx(12000.0, rel=0.01)
    assert rad.right.gain == pytest.approx(50000.0, rel=0.01)
    assert rad.right.offset == pytest.approx(9000.0, rel=0.01)


def test_calibrate_radiometric_folder_count_mismatch(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    rng = np.random.default_rng(3)
    _write_blackbody(tmp_path / "L", [30.0, 60.0], 45000.0, 12000.0, rng)
    _write_blackbody(tmp_path / "R", [30.0, 60.0], 45000.0, 12000.0, rng)
    code = cli.main(["calibrate", "radiometric", "--left", str(tmp_path / "L"), "--right",
                     str(tmp_path / "R"), "--temperatures", "30,60,90",
                     "--out", str(tmp_path / "c.yaml")])
    assert code == cli.EXIT_USAGE
    assert "2 subfolder(s) (t30, t60) but 3 temperatures" in capsys.readouterr().err
    assert not (tmp_path / "c.yaml").exists()


def test_radiometric_first_then_stereo_keeps_curves(image_dir: Path, tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    from processing.calibration import CalibrationFileError, load_radiometric

    rng = np.random.default_rng(4)
    _write_blackbody(tmp_path / "L", [20.0, 60.0], 45000.0, 12000.0, rng)
    _write_blackbody(tmp_path / "R", [20.0, 60.0], 50000.0, 9000.0, rng)
    out = tmp_path / "new.yaml"
    assert cli.main(["calibrate", "radiometric", "--left", str(tmp_path / "L"), "--right",
                     str(tmp_path / "R"), "--temperatures", "20,60", "--out", str(out)]) == 0
    rad = load_radiometric(out)
    assert rad is not None and rad.right is not None
    with pytest.raises(CalibrationFileError, match="only a radiometric"):
        load_calibration(out)
    assert cli.main(["calibrate", "stereo", "--images", str(image_dir), "--pattern",
                     "chessboard", "--rows", "6", "--cols", "9", "--spacing", "50",
                     "--out", str(out)]) == 0
    assert "kept the radiometric section" in capsys.readouterr().out
    assert load_calibration(out).radiometric == rad
