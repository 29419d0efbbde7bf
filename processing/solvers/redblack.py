"""Compact red-black SOR for linear systems with two unknowns per pixel.

Both variational solvers of the method reduce, at each lagged fixed-point iteration, to a
sparse linear system of the same shape: at every pixel i a symmetric 2x2 data block
coupling two unknowns (x1, x2) = (u, v) for the optical flow (paper Eq. 5) or (d, d') for
the joint disparity estimation (paper Eq. 6), plus a diffusion (smoothness) term per
unknown with non-negative edge weights to the four neighbours::

    (A11_i + sum_j w1_ij) x1_i + A12_i x2_i - sum_j w1_ij x1_j = r1_i
    A12_i x1_i + (A22_i + sum_j w2_ij) x2_i - sum_j w2_ij x2_j = r2_i

It is solved with successive over-relaxation in red-black (checkerboard) order. Pixel
(y, x) is red when x + y is even. Instead of striding over the full grid (stride-2 loops
do not vectorise; docs/design.md: 75 ms against 25-30 ms for the whole flow), each
colour is stored *compactly*: row y of colour c holds its W/2 pixels contiguously, so the
inner loop over a row reads contiguous memory with fixed neighbour offsets. The compact
arrays carry a one-pixel halo of zeros so that neighbour indices never need bounds checks
(image borders get zero weights: Neumann boundary conditions).

Layout: a colour's coefficients are one float32 array ``coef`` of shape (13, H+2, W2+2)
with W2 = ceil(W/2); planes ``INV_D1, A12, INV_D2, R1, R2`` then the four edge weights of
unknown 1 (left, right, up, down) and the four of unknown 2. The diagonals are stored
inverted, 1 / (A11 + sum w1) and 1 / (A22 + sum w2), so a sweep needs no division.
"""

from __future__ import annotations

import numba
import numpy as np

# Planes of a colour's coefficient array. Numba reads module-level ints as compile-time
# constants, so the kernels index with these names at no cost.
INV_D1, A12, INV_D2, R1, R2 = 0, 1, 2, 3, 4
#: First of the four edge-weight planes of unknown 1 (left, right, up, down follow).
W1 = 5
W1_LEFT, W1_RIGHT, W1_UP, W1_DOWN = 5, 6, 7, 8
#: First of the four edge-weight planes of unknown 2.
W2 = 9
W2_LEFT, W2_RIGHT, W2_UP, W2_DOWN = 9, 10, 11, 12
N_PLANES = 13


@numba.njit(cache=True, error_model="numpy")
def compact_shape(height: int, width: int) -> tuple[int, int]:
    """Shape (H+2, W2+2) of one colour's compact array, halo included."""
    return height + 2, (width + 1) // 2 + 2


@numba.njit(cache=True, error_model="numpy")
def empty_system(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Allocate the red and black coefficient arrays, shape (13, H+2, W2+2) each."""
    shape = (N_PLANES, height + 2, (width + 1) // 2 + 2)
    return np.zeros(shape, np.float32), np.zeros(shape, np.float32)


@numba.njit(cache=True, error_model="numpy")
def row_pixels(colour: int, y: int, width: int) -> int:
    """How many pixels of ``colour`` row ``y`` of a W-wide image has: they are x = x0,
    x0 + 2, ... with x0 = (colour + y) & 1 (the row's column parity, ``off`` in
    :func:`_sweep_row`), at compact columns 1..count; a column beyond holds no pixel."""
    return (width - ((colour + y) & 1) + 1) // 2


@numba.njit(cache=True, error_model="numpy")
def clear_outside(a: np.ndarray, colour: int, width: int) -> None:
    """Zero the entries of a compact array (H+2, W2+2) that hold no pixel: the halo and, for
    odd W, the padding entry of the rows where ``colour`` has one pixel fewer.

    The kernels write every pixel's entry before reading it and read the others only
    through zero edge weights; zeros there keep them from carrying anything in.
    """
    hh, ww = a.shape
    n = ww - 2
    a[0, :] = 0.0
    a[hh - 1, :] = 0.0
    for yc in range(1, hh - 1):
        a[yc, 0] = 0.0
        a[yc, ww - 1] = 0.0
        count = row_pixels(colour, yc - 1, width)
        for xc in range(count + 1, n + 1):
            a[yc, xc] = 0.0


@numba.njit(cache=True, error_model="numpy")
def clear_outside_planes(planes: np.ndarray, colours: np.ndarray, width: int) -> None:
    """:func:`clear_outside` on every plane k of ``planes`` (P, H+2, W2+2) with
    ``colours[k]`` 0 or 1; a plane of colour -1 is left as it is. One call on the
    buffer's planes, not on a workspace's tuple of 30 arrays, whose unboxing every carve
    paid (0.41 -> 0.35 ms of a warm triple over its 11-15 level sizes, measured; the rest
    is the clearing itself, a few entries on every row of every plane)."""
    for k in range(planes.shape[0]):
        if colours[k] >= 0:
            clear_outside(planes[k], colours[k], width)


@numba.njit(cache=True, error_model="numpy")
def split_field(field: np.ndarray, red: np.ndarray, black: np.ndarray) -> None:
    """Scatter a full-grid field (H, W) into compact red/black arrays (H+2, W2+2), in place."""
    h, w = field.shape
    red[:] = 0.0
    black[:] = 0.0
    for y in range(h):
        src = field[y]
        # Row views: the even columns go to one colour's row, the odd ones to the other's.
        even = (red if (y & 1) == 0 else black)[y + 1, 1:]
        odd = (black if (y & 1) == 0 else red)[y + 1, 1:]
        for j in range(w >> 1):
            even[j] = src[2 * j]
            odd[j] = src[2 * j + 1]
        if w & 1:
            even[w >> 1] = src[w - 1]


@numba.njit(cache=True, error_model="numpy")
def merge_field(red: np.ndarray, black: np.ndarray, out: np.ndarray) -> None:
    """Gather compact red/black arrays back into a full-grid field ``out`` (H, W), in place."""
    h, w = out.shape
    for y in range(h):
        dst = out[y]
        even = (red if (y & 1) == 0 else black)[y + 1, 1:]
        odd = (black if (y & 1) == 0 else red)[y + 1, 1:]
        for j in range(w >> 1):
            dst[2 * j] = even[j]
            dst[2 * j + 1] = odd[j]
        if w & 1:
            dst[w - 1] = even[w >> 1]


@numba.njit(cache=True, error_model="numpy")
def _sweep_row(
    coef: np.ndarray,
    x1: np.ndarray,
    x2: np.ndarray,
    x1o: np.ndarray,
    x2o: np.ndarray,
    yc: int,
    colour: int,
    w2: int,
    omega: np.float32,
) -> None:
    """One over-relaxed Gauss-Seidel update of the pixels of one colour in compact row ``yc``.

    A pixel's four neighbours all have the other colour (arrays ``x1o``, ``x2o``): up and
    down sit at the same compact column; left and right at columns ``xc - 1 + off`` and
    ``xc + off``, where ``off`` is the colour's column parity in that row. Taking 1-D row
    views with those offsets folded in leaves an inner loop over one index with no
    offsets and no bounds logic, which LLVM vectorises (about 5x faster than indexing the
    3-D arrays directly). ``w2`` is the first edge-weight plane of unknown 2: :data:`W2`,
    or :data:`W1` when both unknowns share one penaliser (the flow, Eq. 5), which saves
    four planes of memory traffic per sweep.
    """
    n = coef.shape[2] - 2
    off = (yc - 1 + colour) & 1
    e = n + 1
    inv1 = coef[INV_D1, yc, 1:e]
    a12 = coef[A12, yc, 1:e]
    inv2 = coef[INV_D2, yc, 1:e]
    r1 = coef[R1, yc, 1:e]
    r2 = coef[R2, yc, 1:e]
    w1l = coef[W1_LEFT, yc, 1:e]
    w1r = coef[W1_RIGHT, yc, 1:e]
    w1u = coef[W1_UP, yc, 1:e]
    w1d = coef[W1_DOWN, yc, 1:e]
    w2l = coef[w2, yc, 1:e]
    w2r = coef[w2 + 1, yc, 1:e]
    w2u = coef[w2 + 2, yc, 1:e]
    w2d = coef[w2 + 3, yc, 1:e]
    u = x1[yc, 1:e]
    v = x2[yc, 1:e]
    ul = x1o[yc, off:off + n]
    ur = x1o[yc, off + 1:off + 1 + n]
    uu = x1o[yc - 1, 1:e]
    ud = x1o[yc + 1, 1:e]
    vl = x2o[yc, off:off + n]
    vr = x2o[yc, off + 1:off + 1 + n]
    vu = x2o[yc - 1, 1:e]
    vd = x2o[yc + 1, 1:e]
    for i in range(n):
        s1 = w1l[i] * ul[i] + w1r[i] * ur[i] + w1u[i] * uu[i] + w1d[i] * ud[i]
        o1 = u[i]
        n1 = o1 + omega * ((r1[i] - a12[i] * v[i] + s1) * inv1[i] - o1)
        u[i] = n1
        s2 = w2l[i] * vl[i] + w2r[i] * vr[i] + w2u[i] * vu[i] + w2d[i] * vd[i]
        o2 = v[i]
        v[i] = o2 + omega * ((r2[i] - a12[i] * n1 + s2) * inv2[i] - o2)


@numba.njit(cache=True, error_model="numpy")
def solve_sor(
    red: np.ndarray,
    black: np.ndarray,
    x1r: np.ndarray,
    x1b: np.ndarray,
    x2r: np.ndarray,
    x2b: np.ndarray,
    n_iter: int,
    omega: float,
    shared_weights: bool = False,
) -> None:
    """Run ``n_iter`` red-black SOR iterations on the compact system, updating x in place.

    The iterations run as one wavefront over the rows (temporal blocking): at each step
    the red half-sweep of iteration k updates row ``y - 2k`` and the black one row
    ``y - 2k - 1``. Every update then sees exactly the neighbour values it sees when the
    iterations run one after the other (a red row needs the black rows above, at and
    below it from the previous iteration, a black row the red ones of this iteration), so
    the result is the same to the bit; but the 2 n_iter + 2 rows in flight stay in the
    core's cache instead of streaming all 13 coefficient planes from memory once per
    half-sweep (measured at 320x240: 0.17 ms per iteration, memory-bound, before).

    Parameters
    ----------
    red, black : ndarray, shape (13, H+2, W2+2), float32
        Coefficients (the lagged solvers' kernels, :mod:`processing.solvers.lagged`).
    x1r, x1b, x2r, x2b : ndarray, shape (H+2, W2+2), float32
        Unknowns 1 and 2 in compact red/black form (initial guess in, solution out).
    n_iter : int
        Number of iterations (one iteration = a red sweep then a black sweep).
    omega : float
        Relaxation factor in (0, 2); 1 is Gauss-Seidel.
    shared_weights : bool
        Both unknowns diffuse with the edge weights of unknown 1 (planes W1..W1+3); the
        W2 planes are then not read.
    """
    h = red.shape[1] - 2
    om = np.float32(omega)  # keep the update in float32 SIMD lanes
    w2 = W1 if shared_weights else W2
    for step in range(1, h + 2 * n_iter + 1):
        for k in range(n_iter):
            yr = step - 2 * k
            if yr < 0:
                break
            if 1 <= yr <= h:
                _sweep_row(red, x1r, x2r, x1b, x2b, yr, 0, w2, om)
            yb = yr - 1
            if 1 <= yb <= h:
                _sweep_row(black, x1b, x2b, x1r, x2r, yb, 1, w2, om)
