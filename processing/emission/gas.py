"""Gas properties for the emission rate: molar mass and band-averaged absorption.

The absorption coefficient alpha_g of Eq. 1's Lambert-Beer law, averaged over the camera
band, is what turns a transmittance into a column density. It is a property of the gas,
the band and the camera's spectral response, so a measurement engineer calibrates it once
with a gas cell (``ogiflow calibrate gascell``, :func:`processing.emission.gascell.fit_alpha`).

Default for methane in 3.2-3.4 um: alpha = 5.0e-5 per ppm*m (natural log). Derivation:
the v3 band of CH4 (HITRAN2020, Gordon et al., JQSRT 277 (2022) 107949) has an integrated
intensity of about 1.1e-17 cm/molecule at 296 K, roughly half of it inside 2941-3125 cm^-1
(3.2-3.4 um), i.e. a band-averaged cross-section of about 2-3e-20 cm^2; 1 ppm*m at 1 atm and
296 K is 2.5e15 molecules/cm^2, so alpha ~ 2e-20 x 2.5e15 = 5e-5. Band averaging of an
unresolved line spectrum makes the effective alpha fall with the column density (strong
lines saturate): the default holds for thin plumes (below about 10^4 ppm*m); calibrate.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import yaml

#: Universal gas constant, J/(mol K).
R_GAS = 8.314462618
#: Standard pressure, Pa.
STANDARD_PRESSURE_PA = 101325.0


@dataclass(frozen=True)
class GasProperties:
    """What the emission rate needs to know about the gas.

    Attributes
    ----------
    name : str
        Gas name (reports only).
    molar_mass_kg_mol : float
        Molar mass M in kg/mol (methane 0.01604).
    alpha_per_ppm_m : float
        Band-averaged absorption coefficient alpha_g of Eq. 1, natural log, per ppm*m.
    source : str
        Where alpha comes from (a literature value or a gas-cell calibration).
    """

    name: str
    molar_mass_kg_mol: float
    alpha_per_ppm_m: float
    source: str = ""

    def __post_init__(self) -> None:
        if not self.molar_mass_kg_mol > 0:
            raise ValueError(f"molar_mass_kg_mol must be > 0, got {self.molar_mass_kg_mol}")
        if not self.alpha_per_ppm_m > 0:
            raise ValueError(f"alpha_per_ppm_m must be > 0, got {self.alpha_per_ppm_m}")


METHANE = GasProperties(
    name="methane", molar_mass_kg_mol=0.01604, alpha_per_ppm_m=5.0e-5,
    source="HITRAN2020 v3 band average over 3.2-3.4 um (approximate; calibrate with a gas "
           "cell)")


def ppm_m_to_kg_m2(column_ppm_m: float | object, *, molar_mass_kg_mol: float,
                   temperature_k: float, pressure_pa: float = STANDARD_PRESSURE_PA) -> object:
    """Column density in ppm*m to mass column density in kg/m^2 (ideal gas).

    sigma = CL * 1e-6 * P M / (R T): 1e-6 CL is the column of pure gas in metres at the
    gas's own P and T, whose density is P M / (R T).

    Parameters
    ----------
    column_ppm_m : float or ndarray
        Column density CL in ppm*m.
    molar_mass_kg_mol : float
        Molar mass M, kg/mol.
    temperature_k : float
        Gas temperature T, K (> 0).
    pressure_pa : float
        Ambient pressure P, Pa (> 0).

    Returns
    -------
    float or ndarray
        sigma in kg/m^2, same shape as ``column_ppm_m``.
    """
    if not temperature_k > 0 or not pressure_pa > 0:
        raise ValueError(f"temperature and pressure must be > 0, got {temperature_k} K, "
                         f"{pressure_pa} Pa")
    density = pressure_pa * molar_mass_kg_mol / (R_GAS * temperature_k)
    return column_ppm_m * 1e-6 * density  # type: ignore[operator]


def g_s_to_kg_h(rate_g_s: float) -> float:
    """Mass flow rate in g/s to kg/h (x 3.6)."""
    return rate_g_s * 3.6


#: Molar masses (kg/mol) of gases an OGI camera in 3.2-3.4 um sees, for ``--gas NAME``.
MOLAR_MASS_KG_MOL = {"methane": 0.01604, "ethane": 0.03007, "propane": 0.04410,
                     "butane": 0.05812}
GAS_FILE_FORMAT = "ogiflow-gas"
GAS_FILE_VERSION = 1


def save_gas(path: str | os.PathLike[str], gas: GasProperties) -> None:
    """Write a gas file (``format: ogiflow-gas``) that the appliance's config can name."""
    data = {"format": GAS_FILE_FORMAT, "version": GAS_FILE_VERSION, "name": gas.name,
            "molar_mass_kg_mol": gas.molar_mass_kg_mol,
            "alpha_per_ppm_m": gas.alpha_per_ppm_m, "source": gas.source}
    Path(path).write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")


def load_gas(path: str | os.PathLike[str]) -> GasProperties:
    """Read a gas file written by :func:`save_gas`.

    Raises
    ------
    ValueError
        Not a gas file, a missing or unknown key, or a bad value (named in the message).
    """
    try:
        data = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        raise ValueError(f"{path}: not valid YAML: {exc}") from None
    if not isinstance(data, dict) or data.get("format") != GAS_FILE_FORMAT:
        raise ValueError(f"{path}: not an ogiflow gas file (format: {GAS_FILE_FORMAT})")
    if data.get("version") != GAS_FILE_VERSION:
        raise ValueError(f"{path}: unsupported version {data.get('version')!r}")
    keys = {"format", "version", "name", "molar_mass_kg_mol", "alpha_per_ppm_m", "source"}
    unknown = sorted(set(data) - keys)
    if unknown:
        raise ValueError(f"{path}: unknown key(s) {', '.join(unknown)}")
    try:
        return GasProperties(name=str(data["name"]),
                             molar_mass_kg_mol=float(data["molar_mass_kg_mol"]),
                             alpha_per_ppm_m=float(data["alpha_per_ppm_m"]),
                             source=str(data.get("source", "")))
    except KeyError as exc:
        raise ValueError(f"{path}: missing key {exc.args[0]}") from None
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{path}: {exc}") from None
