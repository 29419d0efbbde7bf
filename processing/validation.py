"""Input checks shared by the numerical entry points.

They raise ``ValueError`` naming the problem so that a wrong image from a camera or a file
never reaches a numba kernel (where it would crash or silently produce garbage).
"""

from __future__ import annotations

import numpy as np

#: Smallest image side in pixels the variational solvers accept (the 5-tap derivative and
#: the coarsest pyramid level need a few pixels).
MIN_IMAGE_SIZE = 8


def as_float_image(image: np.ndarray, name: str, *, min_size: int = 1) -> np.ndarray:
    """Check one 2-D floating-point image and return it as C-contiguous float32.

    Parameters
    ----------
    image : ndarray, shape (H, W), float16/32/64
        The image. Integer and boolean images are rejected: their intensity scale is
        ambiguous (the solvers' parameters assume a known range such as [0, 1]).
    name : str
        Name used in error messages ("image0", "left", ...).
    min_size : int
        Smallest accepted height and width in pixels.

    Returns
    -------
    ndarray, shape (H, W), float32

    Raises
    ------
    ValueError
        Not an array, not 2-D, not floating point, too small, or containing NaN/inf.
    """
    if not isinstance(image, np.ndarray):
        raise ValueError(f"{name} must be a numpy array, got {type(image).__name__}")
    if image.ndim != 2:
        raise ValueError(f"{name} must be a 2-D image, got an array of shape {image.shape}")
    if not np.issubdtype(image.dtype, np.floating):
        raise ValueError(
            f"{name} must have a floating-point dtype (scale it to [0, 1] first), "
            f"got {image.dtype}"
        )
    if min(image.shape) < min_size:
        raise ValueError(
            f"{name} is too small: {image.shape[1]}x{image.shape[0]} px, "
            f"need at least {min_size}x{min_size}"
        )
    if not np.all(np.isfinite(image)):
        bad = int(np.count_nonzero(~np.isfinite(image)))
        raise ValueError(f"{name} contains {bad} NaN or infinite values")
    return np.ascontiguousarray(image, dtype=np.float32)


def check_same_shape(a: np.ndarray, b: np.ndarray, name_a: str, name_b: str) -> None:
    """Raise ``ValueError`` if two arrays differ in shape."""
    if a.shape != b.shape:
        raise ValueError(f"{name_a} and {name_b} differ in shape: {a.shape} vs {b.shape}")


def as_flow_field(flow: np.ndarray, shape: tuple[int, int], name: str) -> np.ndarray:
    """Check a flow field of shape (H, W, 2) matching ``shape`` and return it as float32."""
    if not isinstance(flow, np.ndarray) or flow.shape != (*shape, 2):
        got = getattr(flow, "shape", type(flow).__name__)
        raise ValueError(f"{name} must have shape {(*shape, 2)}, got {got}")
    if not np.issubdtype(flow.dtype, np.floating):
        raise ValueError(f"{name} must have a floating-point dtype, got {flow.dtype}")
    if not np.all(np.isfinite(flow)):
        raise ValueError(f"{name} contains NaN or infinite values")
    return np.ascontiguousarray(flow, dtype=np.float32)


def check_positive(value: float, name: str, *, allow_zero: bool = False) -> float:
    """Return ``value`` as float if it is finite and positive (or zero when allowed)."""
    v = float(value)
    if not np.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        rule = "non-negative" if allow_zero else "positive"
        raise ValueError(f"{name} must be a finite {rule} number, got {value!r}")
    return v
