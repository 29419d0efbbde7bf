"""The Sobolev denoiser equals the exact minimiser of ||u - f||^2 + lambda ||grad u||^2."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import sparse
from scipy.sparse.linalg import spsolve

from processing.preprocess.denoise import sobolev_denoise


def _neumann_forward_difference(n: int) -> sparse.csr_matrix:
    """(n-1) x n forward differences: no flux across the border (Neumann)."""
    return sparse.diags([-np.ones(n - 1), np.ones(n - 1)], [0, 1], shape=(n - 1, n)).tocsr()


def _direct_solve(f: np.ndarray, lam: float) -> np.ndarray:
    """Solve (I + lam (Dx^T Dx + Dy^T Dy)) u = f with sparse matrices (row-major pixels)."""
    h, w = f.shape
    dx = sparse.kron(sparse.identity(h), _neumann_forward_difference(w))
    dy = sparse.kron(_neumann_forward_difference(h), sparse.identity(w))
    a = sparse.identity(h * w) + lam * (dx.T @ dx + dy.T @ dy)
    return spsolve(a.tocsc(), f.ravel().astype(np.float64)).reshape(h, w)


@pytest.mark.parametrize("lam", [0.5, 2.0, 10.0])
def test_matches_direct_sparse_solve(lam: float) -> None:
    rng = np.random.default_rng(3)
    f = rng.standard_normal((17, 23))
    u = sobolev_denoise(f, lam)
    expected = _direct_solve(f, lam)
    np.testing.assert_allclose(u, expected, atol=2e-5)


def test_is_stationary_point_of_the_energy() -> None:
    rng = np.random.default_rng(4)
    f = rng.standard_normal((12, 15))
    lam = 3.0

    def energy(u: np.ndarray) -> float:
        return float(
            ((u - f) ** 2).sum()
            + lam * ((np.diff(u, axis=0) ** 2).sum() + (np.diff(u, axis=1) ** 2).sum())
        )

    u = sobolev_denoise(f, lam).astype(np.float64)
    e0 = energy(u)
    for _ in range(5):
        du = 1e-3 * rng.standard_normal(f.shape)
        assert energy(u + du) >= e0 - 1e-6


def test_mean_preserved_noise_reduced_and_zero_lambda_identity() -> None:
    rng = np.random.default_rng(5)
    f = (0.5 + 0.1 * rng.standard_normal((60, 80))).astype(np.float32)
    u = sobolev_denoise(f, 4.0)
    assert u.dtype == np.float32
    assert abs(float(u.mean()) - float(f.mean())) < 1e-5
    assert u.std() < 0.5 * f.std()
    np.testing.assert_array_equal(sobolev_denoise(f, 0.0), f)


@pytest.mark.parametrize(
    ("image", "lam", "match"),
    [
        (np.zeros((10, 10, 2), np.float32), 1.0, "2-D"),
        (np.zeros((10, 10), np.int32), 1.0, "floating-point"),
        (np.full((10, 10), np.inf, np.float32), 1.0, "NaN"),
        (np.zeros((10, 10), np.float32), -1.0, "lam"),
        (np.zeros((10, 10), np.float32), float("nan"), "lam"),
    ],
)
def test_bad_input_raises(image: np.ndarray, lam: float, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        sobolev_denoise(image, lam)
