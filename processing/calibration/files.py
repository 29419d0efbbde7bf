"""Reading calibration images and pairing left/right files by name."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from processing.calibration.errors import ImageReadError, PairingError

#: File types read as images (case-insensitive). ``.npy`` holds raw counts as saved by numpy.
IMAGE_SUFFIXES: tuple[str, ...] = (
    ".png", ".tif", ".tiff", ".pgm", ".ppm", ".bmp", ".jpg", ".jpeg", ".npy",
)


def list_images(directory: str | os.PathLike[str]) -> list[Path]:
    """Image files directly inside ``directory``, sorted by name."""
    d = Path(directory)
    if not d.is_dir():
        raise FileNotFoundError(f"{d}: no such directory")
    return sorted(p for p in d.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)


def pair_image_files(
    left_dir: str | os.PathLike[str], right_dir: str | os.PathLike[str]
) -> list[tuple[str, Path, Path]]:
    """Pair the images of two directories by identical file name.

    Returns
    -------
    list of (name, left_path, right_path), sorted by name

    Raises
    ------
    PairingError
        When a file has no partner of the same name in the other directory (all such files
        are named), or when there is no image at all.
    """
    left = {p.name: p for p in list_images(left_dir)}
    right = {p.name: p for p in list_images(right_dir)}
    only_left = sorted(set(left) - set(right))
    only_right = sorted(set(right) - set(left))
    if only_left or only_right:
        parts = []
        if only_left:
            parts.append(f"in {left_dir} without a partner in {right_dir}: {', '.join(only_left)}")
        if only_right:
            parts.append(f"in {right_dir} without a partner in {left_dir}: "
                         f"{', '.join(only_right)}")
        raise PairingError("mismatched image pairs (left and right files pair by identical "
                           "name); " + "; ".join(parts))
    if not left:
        raise PairingError(f"no images ({', '.join(IMAGE_SUFFIXES)}) in {left_dir} and "
                           f"{right_dir}")
    return [(name, left[name], right[name]) for name in sorted(left)]


def read_image(path: str | os.PathLike[str]) -> np.ndarray:
    """Read one IR frame with its bit depth kept (8- or 16-bit, or float from ``.npy``).

    Colour images are converted to grey.

    Returns
    -------
    numpy.ndarray, shape (H, W)
    """
    p = Path(path)
    if p.suffix.lower() == ".npy":
        try:
            img = np.load(p, allow_pickle=False)
        except (ValueError, OSError) as exc:
            raise ImageReadError(f"{p}: not a readable .npy array ({exc})") from exc
    else:
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise ImageReadError(f"{p}: cannot be decoded as an image (corrupt or truncated?)")
    if img.ndim == 3 and img.shape[2] in (3, 4):
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    if img.ndim != 2 or img.size == 0:
        raise ImageReadError(f"{p}: expected a single-channel image, got shape {img.shape}")
    return img
