"""Semi-Lagrangian advection and implicit diffusion kernels of the Stable Fluids step
(:mod:`processing.synthetic.fluid`, steps 3 and 4; Stam 1999, paper ref. [22]).

Grid units throughout: positions in cells (volume coordinates / voxel size), arrays indexed
``[z, y, x]``, velocities on the staggered (MAC) grid of
:class:`~processing.synthetic.fluid.FluidState`.
"""

from __future__ import annotations

import numba
import numpy as np

from processing.synthetic.grid import cell_and_fraction


@numba.njit(cache=True, inline="always")
def _trilinear(a: np.ndarray, fz: float, fy: float, fx: float) -> float:
    """Trilinear sample of ``a`` at array index coordinates, clamped to the array."""
    nz, ny, nx = a.shape
    k, tz = cell_and_fraction(fz, nz)
    j, ty = cell_and_fraction(fy, ny)
    i, tx = cell_and_fraction(fx, nx)
    c00 = a[k, j, i] * (1 - tx) + a[k, j, i + 1] * tx
    c01 = a[k, j + 1, i] * (1 - tx) + a[k, j + 1, i + 1] * tx
    c10 = a[k + 1, j, i] * (1 - tx) + a[k + 1, j, i + 1] * tx
    c11 = a[k + 1, j + 1, i] * (1 - tx) + a[k + 1, j + 1, i + 1] * tx
    return (c00 * (1 - ty) + c01 * ty) * (1 - tz) + (c10 * (1 - ty) + c11 * ty) * tz


@numba.njit(cache=True, inline="always")
def _outside(px: float, py: float, pz: float, nx: int, ny: int, nz: int) -> bool:
    return px < 0.0 or py < 0.0 or pz < 0.0 or px > nx or py > ny or pz > nz


@numba.njit(cache=True, inline="always")
def _backtrace(
    u: np.ndarray, v: np.ndarray, w: np.ndarray, px: float, py: float, pz: float, s: float
) -> tuple[float, float, float]:
    """Point (grid units) that reaches (px, py, pz) after one step; ``s = dt / h``.

    Midpoint (RK2) rule: the velocity is sampled at the start and at the half-way point.
    """
    ux = _trilinear(u, pz - 0.5, py - 0.5, px)
    vy = _trilinear(v, pz - 0.5, py, px - 0.5)
    wz = _trilinear(w, pz, py - 0.5, px - 0.5)
    mx = px - 0.5 * s * ux
    my = py - 0.5 * s * vy
    mz = pz - 0.5 * s * wz
    ux = _trilinear(u, mz - 0.5, my - 0.5, mx)
    vy = _trilinear(v, mz - 0.5, my, mx - 0.5)
    wz = _trilinear(w, mz, my - 0.5, mx - 0.5)
    return px - s * ux, py - s * vy, pz - s * wz


@numba.njit(cache=True)
def advect_all(
    u: np.ndarray,
    v: np.ndarray,
    w: np.ndarray,
    s: float,
    is_open: bool,
    wind: np.ndarray,
    u_out: np.ndarray,
    v_out: np.ndarray,
    w_out: np.ndarray,
) -> None:
    """Semi-Lagrangian self-advection of the staggered velocity (u, v, w) by itself."""
    nz, ny, nx = u.shape[0], u.shape[1], u.shape[2] - 1
    for k in range(nz):
        for j in range(ny):
            for i in range(nx + 1):
                bx, by, bz = _backtrace(u, v, w, float(i), j + 0.5, k + 0.5, s)
                if is_open and _outside(bx, by, bz, nx, ny, nz):
                    u_out[k, j, i] = wind[0]
                else:
                    u_out[k, j, i] = _trilinear(u, bz - 0.5, by - 0.5, bx)
    for k in range(nz):
        for j in range(ny + 1):
            for i in range(nx):
                bx, by, bz = _backtrace(u, v, w, i + 0.5, float(j), k + 0.5, s)
                if is_open and _outside(bx, by, bz, nx, ny, nz):
                    v_out[k, j, i] = wind[1]
                else:
                    v_out[k, j, i] = _trilinear(v, bz - 0.5, by, bx - 0.5)
    for k in range(nz + 1):
        for j in range(ny):
            for i in range(nx):
                bx, by, bz = _backtrace(u, v, w, i + 0.5, j + 0.5, float(k), s)
                if is_open and _outside(bx, by, bz, nx, ny, nz):
                    w_out[k, j, i] = wind[2]
                else:
                    w_out[k, j, i] = _trilinear(w, bz, by - 0.5, bx - 0.5)


@numba.njit(cache=True)
def advect_scalar(
    q: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    w: np.ndarray,
    s: float,
    is_open: bool,
    outside_value: float,
    out: np.ndarray,
) -> None:
    """Semi-Lagrangian advection of a cell-centred scalar by the staggered velocity."""
    nz, ny, nx = q.shape
    for k in range(nz):
        for j in range(ny):
            for i in range(nx):
                bx, by, bz = _backtrace(u, v, w, i + 0.5, j + 0.5, k + 0.5, s)
                if is_open and _outside(bx, by, bz, nx, ny, nz):
                    out[k, j, i] = outside_value
                else:
                    out[k, j, i] = _trilinear(q, bz - 0.5, by - 0.5, bx - 0.5)


@numba.njit(cache=True)
def diffuse_jacobi(q0: np.ndarray, a: float, iterations: int, q: np.ndarray) -> None:
    """Jacobi sweeps of ``(1 + 6a) q - a * sum(neighbours) = q0`` (``a = k dt / h^2``).

    Missing neighbours at the array's edge take the cell's own value (zero flux).
    """
    nz, ny, nx = q0.shape
    tmp = q0.copy()
    q[:] = q0
    for _ in range(iterations):
        tmp[:] = q
        for k in range(nz):
            for j in range(ny):
                for i in range(nx):
                    c = tmp[k, j, i]
                    sn = (
                        (tmp[k, j, i - 1] if i > 0 else c)
                        + (tmp[k, j, i + 1] if i < nx - 1 else c)
                        + (tmp[k, j - 1, i] if j > 0 else c)
                        + (tmp[k, j + 1, i] if j < ny - 1 else c)
                        + (tmp[k - 1, j, i] if k > 0 else c)
                        + (tmp[k + 1, j, i] if k < nz - 1 else c)
                    )
                    q[k, j, i] = (q0[k, j, i] + a * sn) / (1.0 + 6.0 * a)
