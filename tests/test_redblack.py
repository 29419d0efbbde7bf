"""The compact red-black SOR solves the same system as a direct sparse solve."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from processing.solvers import redblack


def _system(h: int, w: int, seed: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    f = lambda lo, hi: rng.uniform(lo, hi, (h, w)).astype(np.float32)  # noqa: E731
    a11, a22 = f(0.0, 2.0), f(0.0, 2.0)
    # |a12| <= sqrt(a11 a22) keeps every data block positive semi-definite.
    a12 = (np.sqrt(a11 * a22) * f(-0.9, 0.9)).astype(np.float32)
    wx1, wy1, wx2, wy2 = f(0.1, 1.0), f(0.1, 1.0), f(0.1, 1.0), f(0.1, 1.0)
    for wx in (wx1, wx2):
        wx[:, -1] = 0.0
    for wy in (wy1, wy2):
        wy[-1, :] = 0.0
    return dict(
        a11=a11, a12=a12, a22=a22, r1=f(-1, 1), r2=f(-1, 1), wx1=wx1, wy1=wy1, wx2=wx2, wy2=wy2
    )


def _pack(s: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The compact red and black coefficient arrays of a full-grid system (the module
    docstring's layout), assembled in numpy as the test's reference."""
    h, w = s["a11"].shape
    red, black = redblack.empty_system(h, w)
    planes = {}
    for k, (wx, wy) in enumerate(((s["wx1"], s["wy1"]), (s["wx2"], s["wy2"]))):
        left = np.zeros_like(wx)
        left[:, 1:] = wx[:, :-1]
        up = np.zeros_like(wy)
        up[1:, :] = wy[:-1, :]
        first = redblack.W1 if k == 0 else redblack.W2
        planes.update({first: left, first + 1: wx, first + 2: up, first + 3: wy})
        diag = s["a11"] if k == 0 else s["a22"]
        planes[redblack.INV_D1 if k == 0 else redblack.INV_D2] = (
            np.float32(1.0) / (diag + left + wx + up + wy))
    planes.update({redblack.A12: s["a12"], redblack.R1: s["r1"], redblack.R2: s["r2"]})
    yy, xx = np.mgrid[0:h, 0:w]
    for colour, out in ((0, red), (1, black)):
        sel = ((yy + xx) & 1) == colour
        for plane, value in planes.items():
            out[plane, yy[sel] + 1, xx[sel] // 2 + 1] = value[sel]
    return red, black


def _direct(s: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    h, w = s["a11"].shape
    n = h * w
    idx = np.arange(n).reshape(h, w)
    rows, cols, vals = [], [], []

    def add(i: np.ndarray, j: np.ndarray, v: np.ndarray) -> None:
        rows.append(i.ravel())
        cols.append(j.ravel())
        vals.append(v.ravel().astype(np.float64))

    for k, (wx, wy) in enumerate(((s["wx1"], s["wy1"]), (s["wx2"], s["wy2"]))):
        off = k * n
        # Graph Laplacian of the edge weights for unknown k.
        for a, b, wgt in (
            (idx[:, :-1], idx[:, 1:], wx[:, :-1]),
            (idx[:-1, :], idx[1:, :], wy[:-1, :]),
        ):
            add(a + off, a + off, wgt)
            add(b + off, b + off, wgt)
            add(a + off, b + off, -wgt)
            add(b + off, a + off, -wgt)
    add(idx, idx, s["a11"])
    add(idx + n, idx + n, s["a22"])
    add(idx, idx + n, s["a12"])
    add(idx + n, idx, s["a12"])
    mat = sp.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(2 * n, 2 * n)
    )
    x = spla.spsolve(mat.tocsc(), np.concatenate([s["r1"].ravel(), s["r2"].ravel()]))
    return x[:n].reshape(h, w), x[n:].reshape(h, w)


@pytest.mark.parametrize(("h", "w"), [(9, 12), (10, 11), (7, 7)])
def test_sor_matches_direct_solve(h: int, w: int) -> None:
    s = _system(h, w, seed=h * 100 + w)
    red, black = _pack(s)
    cshape = redblack.compact_shape(h, w)
    x = [np.zeros(cshape, np.float32) for _ in range(4)]
    redblack.solve_sor(red, black, *x, 2000, 1.5)
    u = np.zeros((h, w), np.float32)
    v = np.zeros((h, w), np.float32)
    redblack.merge_field(x[0], x[1], u)
    redblack.merge_field(x[2], x[3], v)
    u_ref, v_ref = _direct(s)
    np.testing.assert_allclose(u, u_ref, atol=2e-4)
    np.testing.assert_allclose(v, v_ref, atol=2e-4)


def test_split_merge_round_trip() -> None:
    field = np.random.default_rng(0).random((7, 9)).astype(np.float32)
    red = np.zeros(redblack.compact_shape(7, 9), np.float32)
    black = np.zeros_like(red)
    redblack.split_field(field, red, black)
    out = np.zeros_like(field)
    redblack.merge_field(red, black, out)
    np.testing.assert_array_equal(out, field)


def _packed(h: int, w: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    return _pack(_system(h, w, seed))


@pytest.mark.parametrize(("h", "w", "n_iter"), [(9, 12, 5), (40, 33, 8), (3, 5, 12)])
def test_wavefront_iterations_equal_one_after_the_other(h: int, w: int, n_iter: int) -> None:
    # One call runs its iterations as a wavefront over the rows; one iteration per call is
    # the plain red sweep, black sweep order. Every update must see the same neighbours.
    red, black = _packed(h, w, seed=3)
    rng = np.random.default_rng(4)
    start = [rng.uniform(-1, 1, redblack.compact_shape(h, w)).astype(np.float32)
             for _ in range(4)]
    at_once = [x.copy() for x in start]
    redblack.solve_sor(red, black, *at_once, n_iter, 1.7)
    one_by_one = [x.copy() for x in start]
    for _ in range(n_iter):
        redblack.solve_sor(red, black, *one_by_one, 1, 1.7)
    for a, b in zip(at_once, one_by_one, strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-6)
    assert not np.allclose(at_once[0], start[0])


def test_shared_weights_read_the_first_unknowns_planes() -> None:
    h, w = 11, 14
    red, black = _packed(h, w, seed=5)
    copied = [red.copy(), black.copy()]
    for c in copied:
        c[redblack.W2:redblack.W2 + 4] = c[redblack.W1:redblack.W1 + 4]
    rng = np.random.default_rng(6)
    start = [rng.uniform(-1, 1, redblack.compact_shape(h, w)).astype(np.float32)
             for _ in range(4)]
    shared = [x.copy() for x in start]
    redblack.solve_sor(red, black, *shared, 6, 1.5, True)
    reference = [x.copy() for x in start]
    redblack.solve_sor(copied[0], copied[1], *reference, 6, 1.5)
    for a, b in zip(shared, reference, strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-6)
