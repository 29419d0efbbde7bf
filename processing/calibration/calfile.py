"""The calibration YAML file: writing and reading a :class:`StereoCalibration`.

File layout (``format: ogiflow-stereo-calibration``, ``version: 1``); all matrices are nested
lists of floats, row-major::

    image_size: [width, height]          pixels
    K_left, K_right: 3x3                 camera matrices, pixels
    D_left, D_right: [k1, k2, p1, p2, k3, ...]   OpenCV distortion coefficients
    R: 3x3, T: [3]                       right camera from left: X_r = R X_l + T; T in metres
    rms_px                               stereo reprojection RMS over the kept views, pixels
    R1, R2: 3x3, P1, P2: 3x4, Q: 4x4     rectification (cv2.stereoRectify); P* in pixels,
                                         P2[0, 3] = -s * b
    s_px, cx_px, cy_px, b_m              rectified camera constant and principal point
                                         (pixels) and baseline (metres): paper Eq. 4
    radiometric: {left: {...}, right: {...}}   optional characteristic curves
    meta: {...}                          optional provenance (date, pattern, views, ...)

A file may also hold only ``format``, ``version`` and ``radiometric`` (written by
``ogiflow calibrate radiometric`` before any stereo calibration exists).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from processing.calibration.errors import CalibrationFileError
from processing.calibration.model import RadiometricCalibration, StereoCalibration
from processing.calibration.radiometric import CharacteristicCurve

__all__ = [
    "calibration_to_dict",
    "curve_from_dict",
    "curve_to_dict",
    "load_calibration",
    "load_radiometric",
    "save_calibration",
    "save_radiometric",
]

FORMAT_NAME = "ogiflow-stereo-calibration"
FORMAT_VERSION = 1

GEOMETRY_KEYS: tuple[str, ...] = (
    "image_size", "K_left", "D_left", "K_right", "D_right", "R", "T", "rms_px",
    "R1", "R2", "P1", "P2", "Q", "s_px", "cx_px", "cy_px", "b_m",
)
_ALLOWED_KEYS = {"format", "version", "radiometric", "meta", *GEOMETRY_KEYS}
_MATRIX_SHAPES: dict[str, tuple[int, ...]] = {
    "K_left": (3, 3), "K_right": (3, 3), "R": (3, 3), "T": (3,),
    "R1": (3, 3), "R2": (3, 3), "P1": (3, 4), "P2": (3, 4), "Q": (4, 4),
}
_DIST_LENGTHS = (4, 5, 8, 12, 14)
_CURVE_KEYS = {
    "model", "offset", "gain", "curvature", "radiance_range", "residual_rms_counts",
    "residuals_counts", "temperatures_k", "band_m", "frames_per_temperature",
}


# ---------------------------------------------------------------------------------- writing


def curve_to_dict(curve: CharacteristicCurve) -> dict[str, Any]:
    """The mapping of one characteristic curve, as a calibration file holds it."""
    d: dict[str, Any] = {
        "model": curve.model,
        "offset": float(curve.offset),
        "gain": float(curve.gain),
    }
    if curve.curvature != 0.0:
        d["curvature"] = float(curve.curvature)
    d.update(
        radiance_range=[float(v) for v in curve.radiance_range],
        residual_rms_counts=float(curve.residual_rms_counts),
        residuals_counts=[float(v) for v in curve.residuals_counts],
        temperatures_k=[float(v) for v in curve.temperatures_k],
        band_m=[float(v) for v in curve.band_m],
        frames_per_temperature=[int(v) for v in curve.frames_per_temperature],
    )
    return d


def _radiometric_to_dict(rad: RadiometricCalibration) -> dict[str, Any]:
    return {side: curve_to_dict(c) for side, c in (("left", rad.left), ("right", rad.right))
            if c is not None}


def calibration_to_dict(calib: StereoCalibration) -> dict[str, Any]:
    """The YAML mapping of a calibration (plain lists and floats)."""
    d: dict[str, Any] = {"format": FORMAT_NAME, "version": FORMAT_VERSION,
                         "image_size": [int(calib.image_size[0]), int(calib.image_size[1])]}
    for key in ("K_left", "D_left", "K_right", "D_right", "R", "T"):
        d[key] = np.asarray(getattr(calib, key), np.float64).tolist()
    d["rms_px"] = float(calib.rms_px)
    for key in ("R1", "R2", "P1", "P2", "Q"):
        d[key] = np.asarray(getattr(calib, key), np.float64).tolist()
    d.update(s_px=calib.s_px, cx_px=calib.cx_px, cy_px=calib.cy_px, b_m=calib.b_m)
    if calib.radiometric is not None:
        d["radiometric"] = _radiometric_to_dict(calib.radiometric)
    if calib.meta:
        d["meta"] = _plain(calib.meta)
    return d


def _plain(obj: Any) -> Any:
    """numpy scalars/arrays inside ``meta`` to plain YAML types."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


_HEADER = (
    "# ogiflow stereo calibration. Units: pixels for K*, P*, s_px, cx_px, cy_px, rms_px;\n"
    "# metres for T and b_m; X_right = R X_left + T. radiometric curves: counts = offset +\n"
    "# gain * L (+ curvature * L^2), L = in-band radiance in W m^-2 sr^-1.\n"
)


def _write_mapping(path: str | os.PathLike[str], data: dict[str, Any]) -> None:
    """Write atomically: a crash mid-write never leaves a truncated calibration behind."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = _HEADER + yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=100)
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def save_calibration(path: str | os.PathLike[str], calib: StereoCalibration) -> None:
    """Write ``calib`` to a YAML file (atomically, replacing an existing file)."""
    _write_mapping(path, calibration_to_dict(calib))


def save_radiometric(path: str | os.PathLike[str], radiometric: RadiometricCalibration) -> None:
    """Put the characteristic curves into ``path``.

    An existing calibration file keeps its geometry (validated first, so a broken file is
    reported rather than overwritten); its ``radiometric`` section is replaced. Otherwise a
    radiometric-only file is written.
    """
    path = Path(path)
    if path.exists():
        data = _read_mapping(path)
        if any(k in data for k in GEOMETRY_KEYS):
            _parse_calibration(data, path)
    else:
        data = {"format": FORMAT_NAME, "version": FORMAT_VERSION}
    data["radiometric"] = _radiometric_to_dict(radiometric)
    _write_mapping(path, data)


# ---------------------------------------------------------------------------------- reading


def _read_mapping(path: Path) -> dict[str, Any]:
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise CalibrationFileError(f"{path}: not a text (YAML) file") from exc
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise CalibrationFileError(f"{path}: not valid YAML: {exc}") from exc
    if not isinstance(data, dict):
        raise CalibrationFileError(f"{path}: expected a mapping at the top level")
    fmt = data.get("format")
    if fmt != FORMAT_NAME:
        raise CalibrationFileError(f"{path}: key 'format' must be {FORMAT_NAME!r}, got {fmt!r}")
    version = data.get("version")
    if not isinstance(version, int) or isinstance(version, bool) or not 1 <= version <= (
            FORMAT_VERSION):
        raise CalibrationFileError(f"{path}: key 'version' must be an integer 1..{FORMAT_VERSION}"
                                   f" (this ogiflow reads up to {FORMAT_VERSION}), got {version!r}")
    unknown = sorted(set(map(str, data)) - _ALLOWED_KEYS)
    if unknown:
        raise CalibrationFileError(f"{path}: unknown key(s) {', '.join(unknown)}")
    return data


def _array(data: dict[str, Any], key: str, path: Path, shape: tuple[int, ...] | None = None
           ) -> np.ndarray:
    if key not in data:
        raise CalibrationFileError(f"{path}: missing key '{key}'")
    try:
        arr = np.asarray(data[key], dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise CalibrationFileError(f"{path}: key '{key}' is not a numeric array") from exc
    if shape is not None and arr.shape != shape:
        raise CalibrationFileError(f"{path}: key '{key}' must have shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise CalibrationFileError(f"{path}: key '{key}' holds non-finite values")
    return arr


def _number(data: dict[str, Any], key: str, path: Path) -> float:
    arr = _array(data, key, path, ())
    return float(arr)


def curve_from_dict(d: Any, where: str, path: Path | str) -> CharacteristicCurve:
    """Inverse of :func:`curve_to_dict`; :class:`CalibrationFileError` naming ``path`` and
    the entry ``where`` for a wrong mapping."""
    if not isinstance(d, dict):
        raise CalibrationFileError(f"{path}: '{where}' must be a mapping")
    unknown = sorted(set(map(str, d)) - _CURVE_KEYS)
    if unknown:
        raise CalibrationFileError(f"{path}: unknown key(s) in '{where}': {', '.join(unknown)}")
    model = d.get("model", "linear")
    if model not in ("linear", "quadratic"):
        raise CalibrationFileError(f"{path}: '{where}.model' must be linear or quadratic, got "
                                   f"{model!r}")
    if model == "quadratic" and "curvature" not in d:
        raise CalibrationFileError(f"{path}: missing key '{where}.curvature' (model quadratic)")
    vals: dict[str, Any] = {}
    for key in ("offset", "gain", "curvature"):
        if key in d:
            vals[key] = _number(d, key, path)
        elif key != "curvature":
            raise CalibrationFileError(f"{path}: missing key '{where}.{key}'")
    try:
        return CharacteristicCurve(
            offset=vals["offset"], gain=vals["gain"], curvature=vals.get("curvature", 0.0),
            radiance_range=tuple(float(v) for v in d.get("radiance_range", (0.0, 0.0))),
            residual_rms_counts=float(d.get("residual_rms_counts", 0.0)),
            residuals_counts=tuple(float(v) for v in d.get("residuals_counts", ())),
            temperatures_k=tuple(float(v) for v in d.get("temperatures_k", ())),
            band_m=tuple(float(v) for v in d.get("band_m", (3.2e-6, 3.4e-6))),
            frames_per_temperature=tuple(int(v) for v in d.get("frames_per_temperature", ())),
        )
    except (TypeError, ValueError) as exc:
        raise CalibrationFileError(f"{path}: '{where}': {exc}") from exc


def _parse_radiometric(data: dict[str, Any], path: Path) -> RadiometricCalibration | None:
    if "radiometric" not in data or data["radiometric"] is None:
        return None
    section = data["radiometric"]
    if not isinstance(section, dict):
        raise CalibrationFileError(f"{path}: 'radiometric' must be a mapping with left/right")
    unknown = sorted(set(map(str, section)) - {"left", "right"})
    if unknown:
        raise CalibrationFileError(f"{path}: unknown key(s) in 'radiometric': "
                                   f"{', '.join(unknown)}")
    return RadiometricCalibration(
        left=curve_from_dict(section["left"], "radiometric.left", path) if "left" in section
        else None,
        right=curve_from_dict(section["right"], "radiometric.right", path) if "right" in section
        else None,
    )


def _parse_calibration(data: dict[str, Any], path: Path) -> StereoCalibration:
    if "K_left" not in data and "radiometric" in data:
        raise CalibrationFileError(f"{path}: holds only a radiometric calibration (missing key "
                                   "'K_left'); run `ogiflow calibrate stereo --out` on it first")
    size = data.get("image_size")
    if (not isinstance(size, (list, tuple)) or len(size) != 2
            or not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in size)):
        raise CalibrationFileError(f"{path}: key 'image_size' must be [width, height] in "
                                   f"positive integers, got {size!r}")
    arrays = {k: _array(data, k, path, shape) for k, shape in _MATRIX_SHAPES.items()}
    for key in ("D_left", "D_right"):
        arrays[key] = _array(data, key, path)
        if arrays[key].ndim != 1 or arrays[key].size not in _DIST_LENGTHS:
            raise CalibrationFileError(f"{path}: key '{key}' must be a list of "
                                       f"{'/'.join(map(str, _DIST_LENGTHS))} coefficients, got "
                                       f"shape {arrays[key].shape}")
    R = arrays["R"]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise CalibrationFileError(f"{path}: key 'R' is not a rotation matrix")
    meta = data.get("meta") or {}
    if not isinstance(meta, dict):
        raise CalibrationFileError(f"{path}: key 'meta' must be a mapping")
    rms = _number(data, "rms_px", path)
    if rms < 0:
        raise CalibrationFileError(f"{path}: key 'rms_px' must be >= 0, got {rms}")
    calib = StereoCalibration(
        image_size=(int(size[0]), int(size[1])), rms_px=rms,
        radiometric=_parse_radiometric(data, path),
        meta=dict(meta), **arrays,
    )
    if calib.s_px <= 0:
        raise CalibrationFileError(f"{path}: key 'P1' gives a camera constant s <= 0")
    # The scalar keys are for people reading the file; P1/P2 are authoritative. A mismatch
    # means a hand edit of one and not the other: refuse rather than guess.
    for key in ("s_px", "cx_px", "cy_px", "b_m"):
        stored = _number(data, key, path)
        derived = getattr(calib, key)
        if abs(stored - derived) > 1e-6 * max(1.0, abs(derived)):
            raise CalibrationFileError(f"{path}: key '{key}' = {stored} disagrees with P1/P2 "
                                       f"({derived})")
    if calib.b_m <= 0:
        raise CalibrationFileError(f"{path}: key 'P2' gives a baseline b <= 0; the right "
                                   "camera must be to the right of the left one")
    return calib


def load_calibration(path: str | os.PathLike[str]) -> StereoCalibration:
    """Read and validate a calibration file.

    Raises
    ------
    CalibrationFileError
        Wrong format or version, unknown, missing or malformed key (named in the message),
        or a radiometric-only file.
    OSError
        The file cannot be read.
    """
    p = Path(path)
    return _parse_calibration(_read_mapping(p), p)


def load_radiometric(path: str | os.PathLike[str]) -> RadiometricCalibration | None:
    """Read only the ``radiometric`` section of a calibration file (None when absent)."""
    p = Path(path)
    return _parse_radiometric(_read_mapping(p), p)
