"""``ogiflow calibrate gascell`` end to end on synthetic gas-cell frames."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from appliance import cli
from processing.calibration import RadiometricCalibration, save_radiometric
from processing.calibration.radiometric import CharacteristicCurve, band_radiance
from processing.emission.gas import load_gas

CURVE = CharacteristicCurve(offset=2000.0, gain=4.0e5)
ALPHA = 4.4e-5


def _write_frames(folder: Path, radiance: float, n: int = 4, seed: int = 0) -> None:
    folder.mkdir(parents=True)
    rng = np.random.default_rng(seed)
    for k in range(n):
        counts = CURVE.counts(radiance) + rng.normal(0.0, 2.0, (48, 64))
        np.save(folder / f"f{k:02d}.npy", np.round(counts).astype(np.uint16))


def test_gascell_recovers_the_coefficient(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                          ) -> None:
    cal = tmp_path / "cal.yaml"
    save_radiometric(cal, RadiometricCalibration(left=CURVE, right=CURVE))
    l_bb, l_gas = float(band_radiance(333.15)), float(band_radiance(293.15))
    _write_frames(tmp_path / "empty", l_bb)
    columns = [1000.0, 4000.0]
    for i, cl in enumerate(columns):
        tau = np.exp(-ALPHA * cl)
        _write_frames(tmp_path / "filled" / f"fill{i + 1}", l_bb * tau + l_gas * (1 - tau),
                      seed=i + 1)
    out = tmp_path / "gas.yaml"
    code = cli.main(["calibrate", "gascell", "--calibration", str(cal), "--empty",
                     str(tmp_path / "empty"), "--filled", str(tmp_path / "filled"),
                     "--columns", "1000,4000", "--gas-temperature", "20", "--out", str(out)])
    assert code == cli.EXIT_OK
    gas = load_gas(out)
    # Counts are rounded to integers with 2 counts of noise: 1 % is the expected accuracy.
    assert gas.alpha_per_ppm_m == pytest.approx(ALPHA, rel=0.01)
    assert gas.name == "methane" and gas.molar_mass_kg_mol == pytest.approx(0.01604)
    assert "alpha_g = " in capsys.readouterr().out


def test_gascell_bad_inputs_exit_2(tmp_path: Path) -> None:
    cal = tmp_path / "cal.yaml"
    save_radiometric(cal, RadiometricCalibration(left=CURVE, right=None))
    l_bb = float(band_radiance(333.15))
    _write_frames(tmp_path / "empty", l_bb)
    _write_frames(tmp_path / "filled" / "a", l_bb * 0.9)
    base = ["calibrate", "gascell", "--calibration", str(cal), "--empty", str(tmp_path / "empty"),
            "--filled", str(tmp_path / "filled"), "--gas-temperature", "20"]
    assert cli.main([*base, "--columns", "1000,2000"]) == cli.EXIT_USAGE  # 1 folder, 2 values
    assert cli.main([*base, "--columns", "1000", "--camera", "right"]) == cli.EXIT_USAGE
    assert cli.main([*base, "--columns", "1000", "--gas", "xenon"]) == cli.EXIT_USAGE
    bad = tmp_path / "bad.yaml"
    bad.write_text("format: ogiflow-gas\nversion: 1\nname: x\nalpha: 1\n")
    with pytest.raises(ValueError, match="unknown key"):
        load_gas(bad)
