"""Locating a point in the cells of the simulated volume, for trilinear sampling.

The advection (:mod:`advection`) and the renderer (:mod:`render`) both sample the volume's
fields at fractional index coordinates; this is the one place that clamps the point into
the array and splits it into a cell index and the fraction within the cell.
"""

from __future__ import annotations

import numba


@numba.njit(cache=True, inline="always")
def cell_and_fraction(f: float, n: int) -> tuple[int, float]:
    """Cell index in [0, n - 2] and fraction in [0, 1] of index coordinate ``f`` along an
    axis of ``n`` samples, clamped to the array."""
    f = min(max(f, 0.0), n - 1.0)
    i = min(int(f), n - 2)
    return i, f - i
