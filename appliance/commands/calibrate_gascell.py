"""``ogiflow calibrate gascell``: fit the gas's band-averaged absorption coefficient.

The emission rate turns transmittance into column density with alpha_g (Eq. 1); this fits
it from frames of a gas cell in front of a black body (processing.emission.gascell).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from appliance import cli
from appliance.commands.calibrate import _parse_floats, temperature_folders

DEFAULT_OUT = "gas.yaml"

_HELP = """\
Fit the band-averaged absorption coefficient alpha_g (natural log, per ppm*m) of a gas from
frames of a sealed gas cell in front of a black body, with one camera whose radiometric
characteristic curve is known (`ogiflow calibrate radiometric`).

Frames: --empty DIR holds frames through the empty (or nitrogen-filled) cell; --filled DIR
holds ONE SUBFOLDER PER FILL, taken in natural sort order and matched one-to-one to the
column densities of --columns (concentration x cell length, ppm*m). The black body should
fill the central ROI. The gas temperature is the cell's (--gas-temperature); the black body
must be clearly warmer or colder than it (10 K or more).

Prints the transmittance and alpha of each fill and the fit, and writes a gas file for the
appliance's configuration (emission.gas_file).
"""


def register(root: argparse._SubParsersAction) -> None:
    """Add ``calibrate gascell``."""
    group = cli.command_group(
        root, "calibrate", "calibrate the stereo OGI pair (geometry, radiometry)")
    p = group.add_parser("gascell", help="absorption coefficient of the gas from a gas cell",
                         description=_HELP,
                         formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--calibration", required=True, type=Path, metavar="FILE",
                   help="calibration YAML with the radiometric curves")
    p.add_argument("--camera", choices=("left", "right"), default="left",
                   help="camera that took the frames (default left)")
    p.add_argument("--empty", required=True, type=Path, metavar="DIR",
                   help="frames through the empty cell")
    p.add_argument("--filled", required=True, type=Path, metavar="DIR",
                   help="one subfolder of frames per fill")
    p.add_argument("--columns", required=True, metavar="CL1,CL2,...",
                   help="column density of each fill in ppm*m, in subfolder order")
    p.add_argument("--gas-temperature", required=True, type=float, metavar="C",
                   help="temperature of the gas in the cell, degrees Celsius")
    p.add_argument("--gas", default="methane",
                   help="gas name (methane, ethane, propane, butane; default methane)")
    p.add_argument("--molar-mass", type=float, default=None, metavar="KG_MOL",
                   help="molar mass in kg/mol (needed for a gas not in the list)")
    p.add_argument("--roi", type=float, default=0.25, metavar="F",
                   help="side of the central region averaged, fraction of the image side")
    p.add_argument("--out", type=Path, default=Path(DEFAULT_OUT), metavar="FILE",
                   help=f"gas file to write (default: {DEFAULT_OUT})")
    p.set_defaults(func=run)


def _mean_radiance(directory: Path, curve: object, roi: float) -> float:
    # Imported when the command runs: the CLI imports every command module for its parser.
    from processing.calibration import roi_means
    from processing.calibration.files import list_images, read_image
    from processing.calibration.radiometric import apply_characteristic_curve

    files = list_images(directory)
    if not files:
        raise ValueError(f"{directory}: no frames")
    try:
        counts = roi_means([read_image(f) for f in files], roi)
    except ValueError as exc:
        raise ValueError(f"{directory}: {exc}") from exc
    return float(apply_characteristic_curve(np.asarray([[counts.mean()]]), curve)[0, 0])


def run(args: argparse.Namespace) -> int:
    """Read the frames, fit alpha_g, report and write the gas file."""
    # Imported when the command runs: the CLI imports every command module for its parser.
    from processing.calibration import band_radiance, load_radiometric
    from processing.calibration.radiometric import celsius_to_kelvin
    from processing.emission.gas import MOLAR_MASS_KG_MOL, GasProperties, save_gas
    from processing.emission.gascell import fit_alpha

    molar = args.molar_mass if args.molar_mass is not None else MOLAR_MASS_KG_MOL.get(args.gas)
    if molar is None:
        raise ValueError(f"--gas {args.gas!r}: unknown gas; give --molar-mass "
                         f"(known: {', '.join(MOLAR_MASS_KG_MOL)})")
    radiometric = load_radiometric(args.calibration)
    if radiometric is None:
        raise ValueError(f"{args.calibration}: no radiometric section; run "
                         "`ogiflow calibrate radiometric` first")
    curve = getattr(radiometric, args.camera)
    if curve is None:
        raise ValueError(f"{args.calibration}: no characteristic curve for the {args.camera} "
                         "camera")
    columns = _parse_floats(args.columns, "--columns")
    folders = temperature_folders(args.filled, len(columns))
    l_empty = _mean_radiance(args.empty, curve, args.roi)
    l_filled = [_mean_radiance(f, curve, args.roi) for f in folders]
    t_gas_k = float(celsius_to_kelvin(args.gas_temperature))
    l_gas = float(band_radiance(t_gas_k, curve.band_m))
    fit = fit_alpha(columns, l_filled, l_empty, l_gas)
    print(f"empty cell: L0 = {l_empty:.6g} W m^-2 sr^-1; gas at {args.gas_temperature:g} degC: "
          f"Lg = {l_gas:.6g}")
    print(f"  {'fill':<16} {'CL (ppm m)':>11} {'L':>12} {'tau':>8} {'alpha':>11}")
    for folder, cl, L, tau, a in zip(folders, columns, l_filled, fit.transmittances,
                                     fit.per_fill_alpha, strict=True):
        print(f"  {folder.name:<16} {cl:11.1f} {L:12.6g} {tau:8.5f} {a:11.4e}")
    print(f"alpha_g = {fit.alpha_per_ppm_m:.5e} per ppm*m (natural log); residual RMS "
          f"{fit.residual_rms:.2e} in optical depth")
    spread = max(fit.per_fill_alpha) / min(fit.per_fill_alpha) - 1.0
    if len(columns) > 1 and spread > 0.1:
        print(f"note: the per-fill alphas differ by {100 * spread:.0f} % (band saturation at "
              "large column densities): calibrate over the range the site will see")
    gas = GasProperties(args.gas, float(molar), fit.alpha_per_ppm_m,
                        source=f"gas cell, {len(columns)} fill(s), {args.camera} camera, "
                               f"{args.calibration.name}")
    save_gas(args.out, gas)
    print(f"wrote {args.out}")
    return cli.EXIT_OK
