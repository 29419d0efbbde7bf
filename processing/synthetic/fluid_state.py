"""The fields of the simulated gas volume on its MAC grid (shapes and units: :mod:`fluid`).

Face velocities u (nz, ny, nx + 1), v (nz, ny + 1, nx), w (nz + 1, ny, nx) in m/s and the
cell concentration c (nz, ny, nx) in kg/m^3, float64.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class FluidState:
    """The fields advanced by :func:`step` (see module docstring for shapes and units)."""

    u: np.ndarray
    v: np.ndarray
    w: np.ndarray
    c: np.ndarray
    t_s: float = 0.0

    def cell_velocity(self) -> np.ndarray:
        """Cell-centred velocity, float64 (3, nz, ny, nx), components (X, Y, Z) in m/s."""
        return np.stack(
            (
                0.5 * (self.u[:, :, 1:] + self.u[:, :, :-1]),
                0.5 * (self.v[:, 1:, :] + self.v[:, :-1, :]),
                0.5 * (self.w[1:, :, :] + self.w[:-1, :, :]),
            )
        )

    def total_mass_kg(self, voxel_m: float) -> float:
        """Total gas mass in the volume in kg."""
        return float(self.c.sum() * voxel_m**3)
