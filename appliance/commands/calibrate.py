"""``ogiflow calibrate stereo`` and ``ogiflow calibrate radiometric``: calibrate the OGI pair.

A measurement engineer runs these on site: ``stereo`` with image pairs of a heated
calibration target, ``radiometric`` with frames of a black body at known temperatures. Both
write (or update) one calibration YAML that the appliance loads (see
:mod:`processing.calibration.calfile` for the format).
"""

from __future__ import annotations

import argparse
import dataclasses
import re
from pathlib import Path

import numpy as np

from appliance import cli

DEFAULT_OUT = "calibration.yaml"

_STEREO_HELP = """\
Calibrate the stereo pair from images of a planar target.

Images: DIR/left/ and DIR/right/ hold one image per view; a left and a right image belong
together when their file names are identical (e.g. left/view01.png + right/view01.png).
8- or 16-bit PNG/TIFF/PGM (or .npy raw counts). The target may appear bright-on-dark or
inverted and with low, uneven contrast (heated targets): both polarities and a local
contrast equalisation are tried.

Pattern size (OpenCV's convention):
  chessboard  --rows/--cols count INNER CORNERS (where four squares meet): a board of
              10 x 7 squares has --cols 9 --rows 6; --spacing is the square side.
              Prefer one odd and one even count.
  circles     --rows/--cols count circles; --spacing is the centre distance.
  acircles    asymmetric grid: --cols circles per row, --rows rows (odd, e.g. OpenCV's
              4 x 11 board: --cols 4 --rows 11); --spacing is HALF the centre distance
              within a row (= the distance between neighbouring rows).

Prints the RMS reprojection error of every view (pixels), the views dropped as outliers
and why, the camera matrices, the baseline b and the rectified camera constant s, and
writes the calibration YAML.
"""

_RADIOMETRIC_HELP = """\
Fit each camera's characteristic curve (counts = offset + gain * L) against the in-band
radiance L of a black body (Planck's law integrated over 3.2-3.4 um, W m^-2 sr^-1).

Frames: --left DIR and --right DIR each hold one SUBFOLDER PER TEMPERATURE. Subfolders are
taken in natural sort order (t30 < t50 < t100; 5 < 40 < 120) and matched one-to-one, in
that order, to the values of --temperatures; the mapping is printed. Each subfolder holds
several frames (8- or 16-bit images or .npy) of the black body filling the central part of
the image; the mean over the central ROI of each frame is one sample.

The curves are added to --out when that file exists (its geometry is kept, an earlier
radiometric section is replaced); otherwise a radiometric-only file is written.
"""


def register(root: argparse._SubParsersAction) -> None:
    """Add ``calibrate stereo`` and ``calibrate radiometric``."""
    group = cli.command_group(
        root, "calibrate", "calibrate the stereo OGI pair (geometry, radiometry)")

    p = group.add_parser(
        "stereo", help="stereo calibration from image pairs of a (heated) target",
        description=_STEREO_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--images", required=True, type=Path, metavar="DIR",
                   help="folder with left/ and right/ subfolders of paired images")
    p.add_argument("--pattern", required=True, choices=("chessboard", "circles", "acircles"),
                   help="target type")
    p.add_argument("--rows", required=True, type=int, metavar="R",
                   help="inner corners (chessboard) or circles along a column")
    p.add_argument("--cols", required=True, type=int, metavar="C",
                   help="inner corners (chessboard) or circles along a row")
    p.add_argument("--spacing", required=True, type=float, metavar="MM",
                   help="square side / circle spacing in millimetres (see above)")
    p.add_argument("--out", type=Path, default=Path(DEFAULT_OUT), metavar="FILE",
                   help=f"calibration YAML to write (default: {DEFAULT_OUT}); a radiometric "
                        "section already in it is kept")
    p.add_argument("--alpha", type=float, default=0.0,
                   help="rectification scaling: 0 = only valid pixels (default), 1 = all "
                        "source pixels")
    p.add_argument("--min-views", type=int, default=6, metavar="N",
                   help="fewest usable views (default 6; 12-20 recommended)")
    p.add_argument("--outlier-k", type=float, default=3.0, metavar="K",
                   help="drop views with RMS > median + K * 1.4826 * MAD (default 3) ...")
    p.add_argument("--outlier-floor", type=float, default=0.5, metavar="PX",
                   help="... and RMS > PX pixels (default 0.5)")
    p.add_argument("--max-rms", type=float, default=1.0, metavar="PX",
                   help="refuse a calibration with a final RMS above PX pixels (default 1.0)")
    p.add_argument("--free-k3", action="store_true",
                   help="also estimate the 6th-order radial distortion k3 (needs many views)")
    p.set_defaults(func=run_stereo)

    r = group.add_parser(
        "radiometric", help="characteristic curves of both cameras from black-body frames",
        description=_RADIOMETRIC_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    r.add_argument("--left", required=True, type=Path, metavar="DIR",
                   help="left camera: one subfolder of frames per temperature")
    r.add_argument("--right", required=True, type=Path, metavar="DIR",
                   help="right camera: one subfolder of frames per temperature")
    r.add_argument("--temperatures", required=True, metavar="T1,T2,...",
                   help="black-body temperatures in degrees Celsius, in subfolder order")
    r.add_argument("--out", type=Path, default=Path(DEFAULT_OUT), metavar="FILE",
                   help=f"calibration YAML to add the curves to (default: {DEFAULT_OUT})")
    r.add_argument("--roi", type=float, default=0.25, metavar="F",
                   help="side of the central region averaged, as a fraction of the image side "
                        "(default 0.25)")
    r.add_argument("--quadratic", action="store_true",
                   help="fit counts = offset + gain L + curvature L^2 (needs >= 3 temperatures)")
    r.add_argument("--emissivity", type=float, default=1.0,
                   help="black-body emissivity in the band (default 1.0)")
    r.add_argument("--band", default="3.2,3.4", metavar="LO,HI",
                   help="camera band in micrometres (default 3.2,3.4)")
    r.set_defaults(func=run_radiometric)


# ------------------------------------------------------------------------------- stereo


def _fmt_matrix(m: object, indent: str = "    ") -> str:
    arr = np.atleast_2d(np.asarray(m, dtype=float))
    return "\n".join(indent + "  ".join(f"{v:12.5f}" for v in row) for row in arr)


def run_stereo(args: argparse.Namespace) -> int:
    """Detect, calibrate, report and write the calibration."""
    # Imported when the command runs: the CLI imports every command module for its parser.
    from processing.calibration import (
        PatternSpec,
        calibrate_stereo_images,
        load_radiometric,
        save_calibration,
    )
    from processing.calibration.files import pair_image_files, read_image

    spec = PatternSpec(args.pattern, args.rows, args.cols, args.spacing / 1000.0)
    for sub in ("left", "right"):
        if not (args.images / sub).is_dir():
            raise ValueError(f"{args.images / sub}: no such directory (expected DIR/left and "
                             "DIR/right)")
    if args.min_views < 3:
        raise ValueError(f"--min-views must be >= 3, got {args.min_views}")
    # Read an existing --out first: a broken file is reported before minutes of work.
    radiometric = load_radiometric(args.out) if args.out.exists() else None
    pairs = pair_image_files(args.images / "left", args.images / "right")
    views = [(name, read_image(lp), read_image(rp)) for name, lp, rp in pairs]
    print(f"{len(views)} image pairs in {args.images}; target: {args.pattern} "
          f"{args.rows} x {args.cols}, spacing {args.spacing:g} mm")

    def report(name: str, left: str | None, right: str | None) -> None:
        print(f"  {name}: left {left or 'NOT FOUND'}, right {right or 'NOT FOUND'}", flush=True)

    print("detecting the target (contrast variant that showed it):", flush=True)
    result = calibrate_stereo_images(
        spec, views, on_view=report, outlier_k=args.outlier_k, outlier_floor_px=args.outlier_floor,
        min_views=args.min_views, fix_k3=not args.free_k3, alpha=args.alpha,
        max_rms_px=args.max_rms)
    calib = result.calibration
    if result.not_found:
        print(f"target not found (view skipped): {', '.join(result.not_found)}")
    print("RMS reprojection error per view (pixels):")
    print(f"  {'view':<24} {'left':>7} {'right':>7}  status")
    for v in result.views:
        status = "kept" if v.kept else f"DROPPED ({v.reason})"
        print(f"  {v.name:<24} {v.rms_left_px:7.3f} {v.rms_right_px:7.3f}  {status}")
    dropped = result.dropped
    print(f"dropped as outliers: {', '.join(v.name for v in dropped) if dropped else 'none'}")
    print(f"views used: {sum(v.kept for v in result.views)}; stereo RMS {calib.rms_px:.3f} px "
          f"(left alone {result.rms_left_px:.3f} px, right alone {result.rms_right_px:.3f} px)")
    print(f"K_left (px):\n{_fmt_matrix(calib.K_left)}")
    print(f"D_left (k1 k2 p1 p2 k3):\n{_fmt_matrix(calib.D_left)}")
    print(f"K_right (px):\n{_fmt_matrix(calib.K_right)}")
    print(f"D_right (k1 k2 p1 p2 k3):\n{_fmt_matrix(calib.D_right)}")
    tx, ty, tz = (float(v) for v in calib.T)
    norm_t = (tx * tx + ty * ty + tz * tz) ** 0.5
    print(f"T (m): [{tx:.5f}, {ty:.5f}, {tz:.5f}]; baseline |T| = {norm_t:.5f} m")
    print(f"rectified: s = {calib.s_px:.3f} px, principal point = ({calib.cx_px:.2f}, "
          f"{calib.cy_px:.2f}) px, b = {calib.b_m:.5f} m")
    if radiometric is not None:
        calib = dataclasses.replace(calib, radiometric=radiometric)
        print(f"kept the radiometric section already in {args.out}")
    save_calibration(args.out, calib)
    print(f"wrote {args.out}")
    return cli.EXIT_OK


# -------------------------------------------------------------------------- radiometric


def _natural_key(name: str) -> list[object]:
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


def temperature_folders(directory: Path, n: int) -> list[Path]:
    """The ``n`` subfolders of ``directory`` in natural sort order (one per temperature)."""
    if not directory.is_dir():
        raise ValueError(f"{directory}: no such directory")
    subs = sorted((p for p in directory.iterdir() if p.is_dir()),
                  key=lambda p: _natural_key(p.name))
    if len(subs) != n:
        raise ValueError(f"{directory} has {len(subs)} subfolder(s) "
                         f"({', '.join(p.name for p in subs) or 'none'}) but {n} temperatures "
                         "were given; one subfolder of frames per temperature is expected")
    return subs


def _parse_floats(text: str, what: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError as exc:
        raise ValueError(f"{what}: expected comma-separated numbers, got {text!r}") from exc
    if not values:
        raise ValueError(f"{what}: no values in {text!r}")
    return values


def run_radiometric(args: argparse.Namespace) -> int:
    """Fit and report both cameras' characteristic curves and write them."""
    # Imported when the command runs: the CLI imports every command module for its parser.
    from processing.calibration import (
        RadiometricCalibration,
        band_radiance,
        fit_characteristic_curve,
        roi_means,
        save_radiometric,
    )
    from processing.calibration.files import list_images, read_image
    from processing.calibration.radiometric import celsius_to_kelvin

    temps_c = _parse_floats(args.temperatures, "--temperatures")
    band_um = _parse_floats(args.band, "--band")
    if len(band_um) != 2:
        raise ValueError(f"--band: expected LO,HI in micrometres, got {args.band!r}")
    band_m = (band_um[0] * 1e-6, band_um[1] * 1e-6)
    temps_k = [float(t) for t in celsius_to_kelvin(temps_c)]
    radiances = band_radiance(np.asarray(temps_k), band_m, args.emissivity)
    curves = {}
    for side, directory in (("left", args.left), ("right", args.right)):
        folders = temperature_folders(directory, len(temps_c))
        samples = []
        print(f"{side} camera ({directory}):")
        print(f"  {'folder':<16} {'T (degC)':>9} {'L (W m^-2 sr^-1)':>17} {'frames':>6} "
              f"{'mean counts':>12}")
        for folder, t_c, L in zip(folders, temps_c, radiances, strict=True):
            files = list_images(folder)
            if not files:
                raise ValueError(f"{folder}: no frames")
            try:
                means = roi_means([read_image(f) for f in files], args.roi)
            except ValueError as exc:
                raise ValueError(f"{folder}: {exc}") from exc
            samples.append(means)
            print(f"  {folder.name:<16} {t_c:9.2f} {L:17.6g} {len(files):6d} "
                  f"{means.mean():12.2f}")
        try:
            curve = fit_characteristic_curve(temps_k, samples, quadratic=args.quadratic,
                                             band_m=band_m, emissivity=args.emissivity)
        except ValueError as exc:
            raise ValueError(f"{side} camera: {exc}") from exc
        curves[side] = curve
        extra = f" + {curve.curvature:.6g} L^2" if args.quadratic else ""
        print(f"  counts = {curve.offset:.3f} + {curve.gain:.6g} L{extra}   "
              f"(RMS residual {curve.residual_rms_counts:.3f} counts; per temperature: "
              + ", ".join(f"{r:+.2f}" for r in curve.residuals_counts) + ")")
    save_radiometric(args.out, RadiometricCalibration(left=curves["left"], right=curves["right"]))
    print(f"wrote the radiometric section of {args.out}")
    return cli.EXIT_OK
