"""Middlebury ``.flo`` optical-flow files (Baker et al., IJCV 2011).

Layout, little-endian: the 4 bytes "PIEH" (the float 202021.25), int32 width, int32 height,
then width*height pairs of float32 (u, v), row-major. Components above 1e9 mark pixels
whose flow is unknown.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

_MAGIC = b"PIEH"
#: Components with an absolute value above this are "unknown" in Middlebury ground truth.
UNKNOWN_THRESHOLD = 1e9
_MAX_SIDE = 100_000


def read_flo(path: str | Path) -> np.ndarray:
    """Read a ``.flo`` file.

    Returns
    -------
    ndarray, shape (H, W, 2), float32
        (u, v) in px; unknown entries are kept as stored (see :func:`known_mask`).

    Raises
    ------
    ValueError
        Wrong magic, implausible size, or a file shorter than its header announces.
    """
    path = Path(path)
    data = path.read_bytes()
    if len(data) < 12:
        raise ValueError(f"{path}: too short for a .flo header ({len(data)} bytes)")
    if data[:4] != _MAGIC:
        raise ValueError(f"{path}: not a .flo file (magic {data[:4]!r}, expected {_MAGIC!r})")
    width, height = (int(x) for x in np.frombuffer(data, "<i4", count=2, offset=4))
    if not (0 < width <= _MAX_SIDE and 0 < height <= _MAX_SIDE):
        raise ValueError(f"{path}: implausible size {width}x{height} in the .flo header")
    expected = 12 + 8 * width * height
    if len(data) != expected:
        raise ValueError(
            f"{path}: {len(data)} bytes but the header announces {width}x{height} "
            f"({expected} bytes)"
        )
    flow = np.frombuffer(data, "<f4", offset=12).reshape(height, width, 2)
    return flow.astype(np.float32)


def write_flo(path: str | Path, flow: np.ndarray) -> None:
    """Write ``flow`` (H, W, 2) as a ``.flo`` file."""
    flow = np.asarray(flow)
    if flow.ndim != 3 or flow.shape[2] != 2:
        raise ValueError(f"flow must have shape (H, W, 2), got {flow.shape}")
    h, w = flow.shape[:2]
    with open(path, "wb") as f:
        f.write(_MAGIC)
        f.write(np.array([w, h], "<i4").tobytes())
        f.write(np.ascontiguousarray(flow, "<f4").tobytes())


def known_mask(flow: np.ndarray) -> np.ndarray:
    """Boolean mask (H, W): True where both components are known (|c| <= 1e9, finite)."""
    return np.all(np.isfinite(flow) & (np.abs(flow) <= UNKNOWN_THRESHOLD), axis=-1)
