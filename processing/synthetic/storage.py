"""On-disk format of synthetic stereo OGI sequences: ``ogiflow-synthetic/1``.

This format is a contract: the simulated-camera back end, the evaluation (``ogiflow eval
sceneflow``) and users' scripts read it. A sequence is one directory::

    <name>/
      meta.json
      frame_00000.npz
      frame_00001.npz
      ...

``meta.json`` (UTF-8 JSON object)::

    {"format": "ogiflow-synthetic/1",
     "name": str, "seed": int, "n_frames": int,
     "frame_interval_s": float,                 # time between consecutive frames
     "camera": {"width": int, "height": int, "s_px": float, "cx_px": float, "cy_px": float,
                "b_m": float, "k1": float, "k2": float},
     "counts_model": {"left": {"gain": float, "offset": float}, "right": {...}},
     "radiometry": {"t_bg_k", "t_gas_k", "alpha_per_ppm_m", "band_um", "gas_density_kg_m3"},
     "necl_ppm_m": float,                       # detection limit used for gt_mask
     "release_rate_g_s": float,                 # mean release rate of the source(s), total
     "wind_m_s": [x, y, z],                     # ambient wind, left camera frame, m/s
     "simulation": {...},                       # grid, voxel size, step, sources, spin-up
     "options": {"noise_netd_k", "jitter_px", "radiometric_mismatch", "lens_k1", "lens_k2",
                 "moving_object"},
     "ground_truth": "...",                     # one-line statement of the GT semantics
     "statistics": {...}}                       # optional: Table-2 characteristics of the GT

Geometry is the one of :mod:`processing.synthetic.render`: left camera frame X right, Y down,
Z forward; the right camera at X = +b; disparity ``d = x_L - x_R = s b / Z > 0``.

``frame_NNNNN.npz`` (numpy ``savez_compressed``), H x W images:

=======================  ===========  ====================================================
key                      dtype/shape  meaning
=======================  ===========  ====================================================
left, right              uint16 (H,W) raw counts of each camera at ``t_s``
t_s                      float64 ()   time of the frame, s (0 at the first frame)
gt_velocity              float32      path-averaged concentration-weighted velocity V*
                         (H,W,3)      (X, Y, Z) in m/s, left camera frame; NaN: no gas
gt_position              float32      concentration-weighted mean position on the ray, m;
                         (H,W,3)      NaN: no gas
gt_mask                  bool (H,W)   column density >= ``necl_ppm_m``
column_density_ppm_m     float32      integral of the concentration along the ray, ppm*m
                         (H,W)
jitter_left_px,          float64 (2,) (dx, dy) shift applied to that camera's image
jitter_right_px                       (zeros unless the jitter option is on)
gt_flux_moment_kg_s      float32      optional: integral of c V Z dl along the left ray,
                         (H,W,3)      c in kg/m^3 (so kg/s); 0 where no gas. The exact
                                      mass flux through a curtain of viewing rays is
                                      sum_i (M_i . n) |e_perp,i| / s
                                      (:mod:`processing.emission.truth`)
gt_release_rate_g_s      float64 ()   optional: mean release rate of the source(s) between
                                      this frame and the next, g/s
=======================  ===========  ====================================================

The two optional keys (the emission-rate ground truth) may be missing in older sequences;
readers treat their absence as "no truth" (None).

Ground-truth timing: ``gt_velocity`` of frame ``i`` is the velocity that carries the gas of
frame ``i`` to frame ``i + 1`` (the fluid velocity averaged over the simulation steps between
the two frames, weighted with frame ``i``'s concentration). ``gt_position`` and ``gt_mask`` are
those of frame ``i``. For Eq. 4 on raw frames (t0, t1, t2) = (i, i+1, i+2), whose differential
images are formed from the motion i -> i+1 -> i+2, the matching reference is
``0.5 * (gt_velocity[i] + gt_velocity[i+1])`` on ``gt_mask[i]``; over a 1 ms interval the two
differ little, so ``gt_velocity[i]`` alone is a close alternative.
:func:`processing.synthetic.reference.triplet_reference` computes it, and
:func:`processing.synthetic.reference.eq4_reference` gives the matching (u, v, d, d').
"""

from __future__ import annotations

import json
import math
import os
import zipfile
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

FORMAT = "ogiflow-synthetic/1"
META_NAME = "meta.json"

_REQUIRED_META = (
    "format", "name", "seed", "n_frames", "frame_interval_s", "camera", "counts_model",
    "release_rate_g_s", "wind_m_s", "simulation", "options",
)
_REQUIRED_CAMERA = ("width", "height", "s_px", "cx_px", "cy_px", "b_m")


class SequenceFormatError(ValueError):
    """A sequence directory or frame file is missing, truncated or does not follow the format."""


@dataclass
class SyntheticFrame:
    """One stereo frame with its left-camera ground truth (shapes in the module docstring)."""

    index: int
    t_s: float
    left: np.ndarray
    right: np.ndarray
    gt_velocity: np.ndarray
    gt_position: np.ndarray
    gt_mask: np.ndarray
    column_density_ppm_m: np.ndarray
    jitter_left_px: np.ndarray
    jitter_right_px: np.ndarray
    flux_moment_kg_s: np.ndarray | None = None
    release_rate_g_s: float | None = None

    def arrays(self) -> dict[str, np.ndarray]:
        """The npz payload of this frame."""
        extra: dict[str, np.ndarray] = {}
        if self.flux_moment_kg_s is not None:
            extra["gt_flux_moment_kg_s"] = np.asarray(self.flux_moment_kg_s, np.float32)
        if self.release_rate_g_s is not None:
            extra["gt_release_rate_g_s"] = np.float64(self.release_rate_g_s)
        return extra | {
            "left": self.left,
            "right": self.right,
            "t_s": np.float64(self.t_s),
            "gt_velocity": self.gt_velocity,
            "gt_position": self.gt_position,
            "gt_mask": self.gt_mask,
            "column_density_ppm_m": self.column_density_ppm_m,
            "jitter_left_px": np.asarray(self.jitter_left_px, dtype=np.float64),
            "jitter_right_px": np.asarray(self.jitter_right_px, dtype=np.float64),
        }


def frame_path(directory: str | os.PathLike[str], index: int) -> Path:
    """Path of frame ``index`` inside a sequence directory."""
    return Path(directory) / f"frame_{index:05d}.npz"


def validate_meta(meta: dict[str, Any]) -> None:
    """Raise :class:`SequenceFormatError` naming the first missing or bad field of ``meta``."""
    if not isinstance(meta, dict):
        raise SequenceFormatError("meta.json must hold a JSON object")
    for key in _REQUIRED_META:
        if key not in meta:
            raise SequenceFormatError(f"meta.json lacks the field {key!r}")
    if meta["format"] != FORMAT:
        raise SequenceFormatError(f"meta.json format is {meta['format']!r}, expected {FORMAT!r}")
    cam = meta["camera"]
    if not isinstance(cam, dict) or any(k not in cam for k in _REQUIRED_CAMERA):
        raise SequenceFormatError(f"meta.json camera must have the fields {_REQUIRED_CAMERA}")
    n = meta["n_frames"]
    if not isinstance(n, int) or n < 1:
        raise SequenceFormatError(f"meta.json n_frames must be a positive integer, got {n!r}")
    fi = meta["frame_interval_s"]
    if not isinstance(fi, (int, float)) or not math.isfinite(fi) or fi <= 0:
        raise SequenceFormatError(f"meta.json frame_interval_s must be > 0, got {fi!r}")
    cm = meta["counts_model"]
    for side in ("left", "right"):
        if not isinstance(cm, dict) or side not in cm or any(
            k not in cm[side] for k in ("gain", "offset")
        ):
            raise SequenceFormatError(f"meta.json counts_model.{side} needs gain and offset")
    wind = meta["wind_m_s"]
    if not isinstance(wind, list) or len(wind) != 3:
        raise SequenceFormatError(f"meta.json wind_m_s must be [x, y, z], got {wind!r}")


def write_sequence(
    directory: str | os.PathLike[str],
    meta: dict[str, Any],
    frames: Iterable[SyntheticFrame],
) -> Path:
    """Write a sequence: ``meta.json`` then one ``frame_NNNNN.npz`` per frame.

    ``meta["n_frames"]`` must equal the number of frames. Each file is written to a temporary
    name and renamed, so a reader never sees a half-written frame; ``meta.json`` is written
    last, so a directory without it is an unfinished sequence.

    Returns
    -------
    Path of the directory.
    """
    meta = dict(meta)
    meta.setdefault("format", FORMAT)
    validate_meta(meta)
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    stale = out / META_NAME
    if stale.exists():
        stale.unlink()
    count = 0
    for frame in frames:
        if frame.index != count:
            raise ValueError(f"frames must come in order: got index {frame.index}, want {count}")
        path = frame_path(out, count)
        tmp = path.with_name(path.name + ".part")
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, **frame.arrays())
        os.replace(tmp, path)
        count += 1
    if count != meta["n_frames"]:
        raise ValueError(f"meta says n_frames={meta['n_frames']} but {count} frames were given")
    for old in out.glob("frame_*.npz"):  # frames of an older, longer sequence written here
        if old.stem[6:].isdigit() and int(old.stem[6:]) >= count:
            old.unlink()
    write_meta(out, meta)
    return out


def write_meta(directory: str | os.PathLike[str], meta: dict[str, Any]) -> None:
    """(Re)write ``meta.json`` atomically after checking it (e.g. to add statistics)."""
    validate_meta(meta)
    out = Path(directory)
    tmp = out / (META_NAME + ".part")
    tmp.write_text(json.dumps(meta, indent=2) + "\n", encoding="utf-8")
    os.replace(tmp, out / META_NAME)


def read_sequence_meta(directory: str | os.PathLike[str]) -> dict[str, Any]:
    """Read and check ``meta.json`` of a sequence directory.

    Raises
    ------
    SequenceFormatError
        Missing directory or file, invalid JSON, or a missing/bad field (the message names it).
    """
    path = Path(directory) / META_NAME
    if not Path(directory).is_dir():
        raise SequenceFormatError(f"{directory}: not a sequence directory")
    if not path.is_file():
        raise SequenceFormatError(f"{path}: missing (not an ogiflow synthetic sequence?)")
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise SequenceFormatError(f"{path}: not valid JSON ({exc})") from exc
    try:
        validate_meta(meta)
    except SequenceFormatError as exc:
        raise SequenceFormatError(f"{path}: {exc}") from exc
    return meta


def _expect(arr: np.ndarray, key: str, dtype: Any, shape: tuple[int, ...], path: Path) -> None:
    if arr.dtype != np.dtype(dtype) or arr.shape != shape:
        raise SequenceFormatError(
            f"{path}: {key} is {arr.dtype}{list(arr.shape)}, "
            f"expected {np.dtype(dtype)}{list(shape)}"
        )


def read_frame(
    directory: str | os.PathLike[str], index: int, meta: dict[str, Any] | None = None
) -> SyntheticFrame:
    """Read frame ``index`` of a sequence and check every array's dtype and shape.

    Raises
    ------
    IndexError
        ``index`` outside ``[0, n_frames)``.
    SequenceFormatError
        Missing, truncated or corrupt file, or an array with a wrong key, dtype or shape.
    """
    meta = read_sequence_meta(directory) if meta is None else meta
    if not 0 <= index < meta["n_frames"]:
        raise IndexError(f"frame {index} outside 0..{meta['n_frames'] - 1}")
    path = frame_path(directory, index)
    if not path.is_file():
        raise SequenceFormatError(f"{path}: missing")
    h, w = int(meta["camera"]["height"]), int(meta["camera"]["width"])
    try:
        with np.load(path, allow_pickle=False) as npz:
            data = {k: npz[k] for k in npz.files}
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as exc:
        raise SequenceFormatError(f"{path}: unreadable or truncated ({exc})") from exc
    required = ("left", "right", "t_s", "gt_velocity", "gt_position", "gt_mask",
                "column_density_ppm_m")
    for key in required:
        if key not in data:
            raise SequenceFormatError(f"{path}: lacks the array {key!r}")
    _expect(data["left"], "left", np.uint16, (h, w), path)
    _expect(data["right"], "right", np.uint16, (h, w), path)
    _expect(data["gt_velocity"], "gt_velocity", np.float32, (h, w, 3), path)
    _expect(data["gt_position"], "gt_position", np.float32, (h, w, 3), path)
    _expect(data["gt_mask"], "gt_mask", np.bool_, (h, w), path)
    _expect(data["column_density_ppm_m"], "column_density_ppm_m", np.float32, (h, w), path)
    if data["t_s"].shape != ():
        raise SequenceFormatError(f"{path}: t_s must be a scalar")
    zero = np.zeros(2)
    moment = data.get("gt_flux_moment_kg_s")
    if moment is not None:
        _expect(moment, "gt_flux_moment_kg_s", np.float32, (h, w, 3), path)
    release = data.get("gt_release_rate_g_s")
    return SyntheticFrame(
        index=index,
        t_s=float(data["t_s"]),
        left=data["left"],
        right=data["right"],
        gt_velocity=data["gt_velocity"],
        gt_position=data["gt_position"],
        gt_mask=data["gt_mask"],
        column_density_ppm_m=data["column_density_ppm_m"],
        jitter_left_px=data.get("jitter_left_px", zero),
        jitter_right_px=data.get("jitter_right_px", zero),
        flux_moment_kg_s=moment,
        release_rate_g_s=None if release is None else float(release),
    )


def iter_frames(directory: str | os.PathLike[str]) -> Iterator[SyntheticFrame]:
    """Yield every frame of a sequence in order (meta is read and checked once)."""
    meta = read_sequence_meta(directory)
    for i in range(meta["n_frames"]):
        yield read_frame(directory, i, meta)


def list_sequences(root: str | os.PathLike[str]) -> list[Path]:
    """Sequence directories (those holding a ``meta.json``) directly below ``root``, sorted."""
    base = Path(root)
    if not base.is_dir():
        raise SequenceFormatError(f"{root}: not a directory")
    return sorted(p for p in base.iterdir() if (p / META_NAME).is_file())
