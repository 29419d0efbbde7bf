"""Pressure projection of the Stable Fluids step (Stam 1999, paper ref. [22]): the velocity
field made divergence-free by solving the Poisson equation exactly with discrete sine
(open boundaries) or cosine (closed box) transforms on the MAC grid.
"""

from __future__ import annotations

import numba
import numpy as np
import scipy.fft

from processing.synthetic.fluid_state import FluidState


@numba.njit(cache=True)
def _divergence(u: np.ndarray, v: np.ndarray, w: np.ndarray, h: float, out: np.ndarray) -> None:
    nz, ny, nx = out.shape
    for k in range(nz):
        for j in range(ny):
            for i in range(nx):
                out[k, j, i] = (
                    u[k, j, i + 1] - u[k, j, i] + v[k, j + 1, i] - v[k, j, i]
                    + w[k + 1, j, i] - w[k, j, i]
                ) / h


@numba.njit(cache=True)
def _subtract_gradient(
    phi: np.ndarray, h: float, is_open: bool, u: np.ndarray, v: np.ndarray, w: np.ndarray
) -> None:
    """Face velocities -= grad(phi). Open: phi = 0 on the boundary faces (ghost = -phi);
    closed: boundary faces are walls and keep their (zero) normal velocity."""
    nz, ny, nx = phi.shape
    for k in range(nz):
        for j in range(ny):
            for i in range(1, nx):
                u[k, j, i] -= (phi[k, j, i] - phi[k, j, i - 1]) / h
            if is_open:
                u[k, j, 0] -= 2.0 * phi[k, j, 0] / h
                u[k, j, nx] += 2.0 * phi[k, j, nx - 1] / h
    for k in range(nz):
        for i in range(nx):
            for j in range(1, ny):
                v[k, j, i] -= (phi[k, j, i] - phi[k, j - 1, i]) / h
            if is_open:
                v[k, 0, i] -= 2.0 * phi[k, 0, i] / h
                v[k, ny, i] += 2.0 * phi[k, ny - 1, i] / h
    for j in range(ny):
        for i in range(nx):
            for k in range(1, nz):
                w[k, j, i] -= (phi[k, j, i] - phi[k - 1, j, i]) / h
            if is_open:
                w[0, j, i] -= 2.0 * phi[0, j, i] / h
                w[nz, j, i] += 2.0 * phi[nz - 1, j, i] / h


def _laplacian_eigenvalues(shape: tuple[int, int, int], h: float, is_open: bool) -> np.ndarray:
    """Eigenvalues (<= 0) of the 7-point Laplacian in the DST-II (Dirichlet on the faces) or
    DCT-II (Neumann) basis, broadcast to ``shape``."""
    lam = np.zeros(shape)
    for axis, n in enumerate(shape):
        k = np.arange(n, dtype=float)
        mode = k + 1.0 if is_open else k
        e = -(2.0 - 2.0 * np.cos(np.pi * mode / n)) / h**2
        sh = [1, 1, 1]
        sh[axis] = n
        lam = lam + e.reshape(sh)
    return lam


def divergence(state: FluidState, voxel_m: float) -> np.ndarray:
    """Discrete (MAC) divergence per cell, float64 (nz, ny, nx) in 1/s."""
    out = np.empty(state.c.shape)
    _divergence(state.u, state.v, state.w, voxel_m, out)
    return out


def project(state: FluidState, voxel_m: float, boundary: str = "open") -> None:
    """Make the velocity discretely divergence-free (in place) with an exact Poisson solve.

    Solves ``L phi = div u`` (7-point Laplacian with the boundary's conditions) by a
    type-II DST (open) or DCT (closed) and subtracts ``grad phi`` on the faces.
    """
    is_open = boundary == "open"
    div = divergence(state, voxel_m)
    lam = _laplacian_eigenvalues(div.shape, voxel_m, is_open)
    if is_open:
        spec = scipy.fft.dstn(div, type=2)
        spec /= lam
        phi = scipy.fft.idstn(spec, type=2)
    else:
        spec = scipy.fft.dctn(div, type=2)
        lam[0, 0, 0] = 1.0
        spec /= lam
        spec[0, 0, 0] = 0.0  # the mean of phi is free; the mean of div is zero in a closed box
        phi = scipy.fft.idctn(spec, type=2)
    _subtract_gradient(phi, voxel_m, is_open, state.u, state.v, state.w)
