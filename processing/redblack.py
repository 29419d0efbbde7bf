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
do not vectorise; DESIGN.md measured 75 ms against 25-30 ms for the whole flow), each
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

INV_D1, A12, INV_D2, R1, R2 = 0, 1, 2, 3, 4
W1 = 5  # planes 5..8: weights of unknown 1 towards left, right, up, down
W2 = 9  # planes 9..12: weights of unknown 2 towards left, right, up, down
N_PLANES = 13


@numba.njit(cache=True)
def compact_shape(height: int, width: int) -> tuple[int, int]:
    """Shape (H+2, W2+2) of one colour's compact array, halo included."""
    return height + 2, (width + 1) // 2 + 2


@numba.njit(cache=True)
def empty_system(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Allocate the red and black coefficient arrays, shape (13, H+2, W2+2) each."""
    shape = (13, height + 2, (width + 1) // 2 + 2)
    return np.zeros(shape, np.float32), np.zeros(shape, np.float32)


@numba.njit(cache=True, fastmath=True)
def _pack_colour(
    a11: np.ndarray,
    a12: np.ndarray,
    a22: np.ndarray,
    r1: np.ndarray,
    r2: np.ndarray,
    wx1: np.ndarray,
    wy1: np.ndarray,
    wx2: np.ndarray,
    wy2: np.ndarray,
    c: np.ndarray,
    colour: int,
) -> None:
    h, w = a11.shape
    for y in range(h):
        yc = y + 1
        # Index -1 wraps to the last column/row, which is zero by contract: the left
        # weight of x = 0 and the upper weight of y = 0 come out as 0 without a branch.
        for x in range((y + colour) & 1, w, 2):
            xc = x // 2 + 1
            l1 = wx1[y, x - 1]
            r1w = wx1[y, x]
            u1 = wy1[y - 1, x]
            d1 = wy1[y, x]
            l2 = wx2[y, x - 1]
            r2w = wx2[y, x]
            u2 = wy2[y - 1, x]
            d2 = wy2[y, x]
            c[0, yc, xc] = 1.0 / (a11[y, x] + l1 + r1w + u1 + d1)
            c[1, yc, xc] = a12[y, x]
            c[2, yc, xc] = 1.0 / (a22[y, x] + l2 + r2w + u2 + d2)
            c[3, yc, xc] = r1[y, x]
            c[4, yc, xc] = r2[y, x]
            c[5, yc, xc] = l1
            c[6, yc, xc] = r1w
            c[7, yc, xc] = u1
            c[8, yc, xc] = d1
            c[9, yc, xc] = l2
            c[10, yc, xc] = r2w
            c[11, yc, xc] = u2
            c[12, yc, xc] = d2


@numba.njit(cache=True)
def pack_system(
    a11: np.ndarray,
    a12: np.ndarray,
    a22: np.ndarray,
    r1: np.ndarray,
    r2: np.ndarray,
    wx1: np.ndarray,
    wy1: np.ndarray,
    wx2: np.ndarray,
    wy2: np.ndarray,
    red: np.ndarray,
    black: np.ndarray,
) -> None:
    """Scatter full-grid coefficients into the compact red and black arrays (in place).

    Parameters
    ----------
    a11, a12, a22, r1, r2 : ndarray, shape (H, W), float32
        Data block and right-hand side of every pixel.
    wx1, wx2 : ndarray, shape (H, W), float32
        Weight of the edge between (y, x) and (y, x+1) for unknown 1 and 2. The last
        column MUST be zero (there is no right neighbour).
    wy1, wy2 : ndarray, shape (H, W), float32
        Weight of the edge between (y, x) and (y+1, x). The last row MUST be zero.
    red, black : ndarray, shape (13, H+2, W2+2), float32
        Output, see the module docstring. Every diagonal A11 + sum(w1) and A22 + sum(w2)
        must be positive, which holds whenever the smoothness weights are positive.
        Entries outside the image (halo, and the last compact column when W is odd) keep
        zero weights and coefficients: they are never coupled to real pixels.
    """
    red[:] = 0.0
    black[:] = 0.0
    _pack_colour(a11, a12, a22, r1, r2, wx1, wy1, wx2, wy2, red, 0)
    _pack_colour(a11, a12, a22, r1, r2, wx1, wy1, wx2, wy2, black, 1)


@numba.njit(cache=True)
def split_field(field: np.ndarray, red: np.ndarray, black: np.ndarray) -> None:
    """Scatter a full-grid field (H, W) into compact red/black arrays (H+2, W2+2), in place."""
    h, w = field.shape
    red[:] = 0.0
    black[:] = 0.0
    for y in range(h):
        for x in range(y & 1, w, 2):
            red[y + 1, x // 2 + 1] = field[y, x]
        for x in range((y + 1) & 1, w, 2):
            black[y + 1, x // 2 + 1] = field[y, x]


@numba.njit(cache=True)
def split_new(field: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`split_field` into newly allocated compact arrays (red, black)."""
    h, w = field.shape
    red = np.zeros((h + 2, (w + 1) // 2 + 2), np.float32)
    black = np.zeros_like(red)
    split_field(field, red, black)
    return red, black


@numba.njit(cache=True)
def merge_field(red: np.ndarray, black: np.ndarray, out: np.ndarray) -> None:
    """Gather compact red/black arrays back into a full-grid field ``out`` (H, W), in place."""
    h, w = out.shape
    for y in range(h):
        for x in range(y & 1, w, 2):
            out[y, x] = red[y + 1, x // 2 + 1]
        for x in range((y + 1) & 1, w, 2):
            out[y, x] = black[y + 1, x // 2 + 1]


@numba.njit(cache=True, fastmath=True)
def _sweep(
    coef: np.ndarray,
    x1: np.ndarray,
    x2: np.ndarray,
    x1o: np.ndarray,
    x2o: np.ndarray,
    colour: int,
    omega: float,
) -> None:
    """One over-relaxed Gauss-Seidel update of every pixel of one colour.

    A pixel's four neighbours all have the other colour (arrays ``x1o``, ``x2o``): up and
    down sit at the same compact column; left and right at columns ``xc - 1 + off`` and
    ``xc + off``, where ``off`` is the colour's column parity in that row. Taking 1-D row
    views with those offsets folded in leaves an inner loop over one index with no
    offsets and no bounds logic, which LLVM vectorises (about 5x faster than indexing the
    3-D arrays directly).
    """
    h = coef.shape[1] - 2
    n = coef.shape[2] - 2
    om = np.float32(omega)  # keep the update in float32 SIMD lanes
    for yc in range(1, h + 1):
        off = (yc - 1 + colour) & 1
        e = n + 1
        inv1 = coef[0, yc, 1:e]
        a12 = coef[1, yc, 1:e]
        inv2 = coef[2, yc, 1:e]
        r1 = coef[3, yc, 1:e]
        r2 = coef[4, yc, 1:e]
        w1l = coef[5, yc, 1:e]
        w1r = coef[6, yc, 1:e]
        w1u = coef[7, yc, 1:e]
        w1d = coef[8, yc, 1:e]
        w2l = coef[9, yc, 1:e]
        w2r = coef[10, yc, 1:e]
        w2u = coef[11, yc, 1:e]
        w2d = coef[12, yc, 1:e]
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
            n1 = o1 + om * ((r1[i] - a12[i] * v[i] + s1) * inv1[i] - o1)
            u[i] = n1
            s2 = w2l[i] * vl[i] + w2r[i] * vr[i] + w2u[i] * vu[i] + w2d[i] * vd[i]
            o2 = v[i]
            v[i] = o2 + om * ((r2[i] - a12[i] * n1 + s2) * inv2[i] - o2)


@numba.njit(cache=True)
def solve_sor(
    red: np.ndarray,
    black: np.ndarray,
    x1r: np.ndarray,
    x1b: np.ndarray,
    x2r: np.ndarray,
    x2b: np.ndarray,
    n_iter: int,
    omega: float,
) -> None:
    """Run ``n_iter`` red-black SOR iterations on the compact system, updating x in place.

    Parameters
    ----------
    red, black : ndarray, shape (13, H+2, W2+2), float32
        Coefficients from :func:`pack_system`.
    x1r, x1b, x2r, x2b : ndarray, shape (H+2, W2+2), float32
        Unknowns 1 and 2 in compact red/black form (initial guess in, solution out).
    n_iter : int
        Number of iterations (one iteration = a red sweep then a black sweep).
    omega : float
        Relaxation factor in (0, 2); 1 is Gauss-Seidel.
    """
    for _ in range(n_iter):
        _sweep(red, x1r, x2r, x1b, x2b, 0, omega)
        _sweep(black, x1b, x2b, x1r, x2r, 1, omega)


# --- Working directly in the compact domain --------------------------------------------
# Assembling a system on the full grid and scattering it with pack_system costs about as
# much as ten SOR iterations (stride-2 scatter of 13 planes). The helpers below let a
# solver keep its unknowns and inputs compact for a whole warp and compute psi', edge
# weights and data terms per colour with contiguous, vectorisable row loops.


@numba.njit(cache=True)
def border_masks(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Edge-existence masks (4, H+2, W2+2) for red and black: left, right, up, down.

    1 where the pixel has that neighbour inside the image, 0 at image borders, in the
    halo and at padding entries (odd W), so that multiplying edge weights by the mask
    imposes Neumann boundary conditions and keeps padding entries decoupled.
    """
    shape = (4, height + 2, (width + 1) // 2 + 2)
    red = np.zeros(shape, np.float32)
    black = np.zeros(shape, np.float32)
    for y in range(height):
        for x in range(width):
            m = red if (x + y) % 2 == 0 else black
            yc = y + 1
            xc = x // 2 + 1
            m[0, yc, xc] = 1.0 if x > 0 else 0.0
            m[1, yc, xc] = 1.0 if x < width - 1 else 0.0
            m[2, yc, xc] = 1.0 if y > 0 else 0.0
            m[3, yc, xc] = 1.0 if y < height - 1 else 0.0
    return red, black


@numba.njit(cache=True)
def fill_neumann_ghosts(red: np.ndarray, black: np.ndarray, width: int) -> None:
    """Copy border pixels into the halo neighbours that central differences read.

    After this, a centred difference at a border pixel equals half the one-sided
    difference (zero normal derivative), and no halo value is stale.
    """
    h = red.shape[0] - 2
    for yc in range(1, h + 1):
        y = yc - 1
        # Pixel x = 0 has colour y & 1; its left neighbour is column 0 of the other colour.
        own, other = (red, black) if (y & 1) == 0 else (black, red)
        other[yc, 0] = own[yc, 1]
        # Pixel x = W-1: colour (W-1+y) & 1, compact column (W-1)//2 + 1, right neighbour
        # at that column + ((W-1) & 1) in the other colour.
        xc = (width - 1) // 2 + 1
        own, other = (red, black) if ((width - 1 + y) & 1) == 0 else (black, red)
        other[yc, xc + ((width - 1) & 1)] = own[yc, xc]
    last = h
    black[0, :] = red[1, :]
    red[0, :] = black[1, :]
    black[last + 1, :] = red[last, :]
    red[last + 1, :] = black[last, :]


@numba.njit(cache=True, fastmath=True)
def compact_gradient_sq(own: np.ndarray, other: np.ndarray, colour: int, out: np.ndarray) -> None:
    """Add |grad f|^2 at the pixels of one colour to ``out`` (centred differences).

    ``own`` and ``other`` are the compact arrays of f for this colour and the other one,
    whose halos were filled by :func:`fill_neumann_ghosts`.
    """
    h = own.shape[0] - 2
    n = own.shape[1] - 2
    e = n + 1
    for yc in range(1, h + 1):
        off = (yc - 1 + colour) & 1
        fl = other[yc, off:off + n]
        fr = other[yc, off + 1:off + 1 + n]
        fu = other[yc - 1, 1:e]
        fd = other[yc + 1, 1:e]
        o = out[yc, 1:e]
        for i in range(n):
            gx = np.float32(0.5) * (fr[i] - fl[i])
            gy = np.float32(0.5) * (fd[i] - fu[i])
            o[i] += gx * gx + gy * gy


@numba.njit(cache=True, fastmath=True)
def compact_charbonnier_prime(s2: np.ndarray, eps: float, out: np.ndarray) -> None:
    """out = 1 / sqrt(s2 + eps^2) elementwise on compact arrays (lagged psi')."""
    e2 = np.float32(eps * eps)
    h, w = s2.shape
    for y in range(h):
        a = s2[y]
        o = out[y]
        for x in range(w):
            o[x] = np.float32(1.0) / np.sqrt(a[x] + e2)


@numba.njit(cache=True)
def lagged_psi(
    fields: tuple[tuple[np.ndarray, np.ndarray], ...],
    width: int,
    eps: float,
    s2: np.ndarray,
    psi: tuple[np.ndarray, np.ndarray],
) -> None:
    """Lagged weight psi'(sum |grad f|^2) of one Charbonnier smoothness term, per colour.

    Parameters
    ----------
    fields : tuple of (red, black) pairs of compact arrays (H+2, W2+2), float32
        The fields one penaliser acts on jointly: (u, v) for the flow (Eq. 5 penalises
        |grad u|^2 + |grad v|^2 together), a single field for each of d and d' (Eq. 6 has
        one penaliser per field). Their halos are overwritten with Neumann ghost values.
    width : int
        Image width W (locates the right-border ghosts).
    eps : float
        Charbonnier epsilon.
    s2 : ndarray (H+2, W2+2), float32
        Scratch space.
    psi : (red, black) compact arrays
        Output: 1 / sqrt(sum |grad f|^2 + eps^2) at the pixels of each colour.
    """
    for f in fields:
        fill_neumann_ghosts(f[0], f[1], width)
    for c in range(2):
        s2[:] = 0.0
        for f in fields:
            compact_gradient_sq(f[c], f[1 - c], c, s2)
        compact_charbonnier_prime(s2, eps, psi[c])


@numba.njit(cache=True, fastmath=True)
def compact_edge_weights(
    psi_own: np.ndarray,
    psi_other: np.ndarray,
    mask: np.ndarray,
    scale: float,
    colour: int,
    coef: np.ndarray,
    plane: int,
) -> None:
    """Write the four edge weights of one colour into ``coef[plane:plane + 4]``.

    Weight = ``scale`` * mean of the two pixels' psi' * edge mask (Neumann borders).
    ``plane`` is :data:`W1` or :data:`W2`.
    """
    h = psi_own.shape[0] - 2
    n = psi_own.shape[1] - 2
    e = n + 1
    half = np.float32(0.5 * scale)
    for yc in range(1, h + 1):
        off = (yc - 1 + colour) & 1
        p = psi_own[yc, 1:e]
        pl = psi_other[yc, off:off + n]
        pr = psi_other[yc, off + 1:off + 1 + n]
        pu = psi_other[yc - 1, 1:e]
        pd = psi_other[yc + 1, 1:e]
        ml, mr, mu, md = mask[0, yc, 1:e], mask[1, yc, 1:e], mask[2, yc, 1:e], mask[3, yc, 1:e]
        wl = coef[plane, yc, 1:e]
        wr = coef[plane + 1, yc, 1:e]
        wu = coef[plane + 2, yc, 1:e]
        wd = coef[plane + 3, yc, 1:e]
        for i in range(n):
            wl[i] = half * (p[i] + pl[i]) * ml[i]
            wr[i] = half * (p[i] + pr[i]) * mr[i]
            wu[i] = half * (p[i] + pu[i]) * mu[i]
            wd[i] = half * (p[i] + pd[i]) * md[i]


@numba.njit(cache=True, fastmath=True)
def finish_diagonals(coef: np.ndarray, a11: np.ndarray, a22: np.ndarray) -> None:
    """Store 1 / (A11 + sum w1) and 1 / (A22 + sum w2) in the INV_D planes of ``coef``.

    ``a11``, ``a22`` are compact (H+2, W2+2). A zero diagonal (padding entries, or a
    pixel with neither data nor neighbours) gets 0, which freezes that unknown instead of
    producing inf.
    """
    h = coef.shape[1]
    w = coef.shape[2]
    for y in range(h):
        i1 = coef[0, y]
        i2 = coef[2, y]
        b11 = a11[y]
        b22 = a22[y]
        wl1, wr1, wu1, wd1 = coef[5, y], coef[6, y], coef[7, y], coef[8, y]
        wl2, wr2, wu2, wd2 = coef[9, y], coef[10, y], coef[11, y], coef[12, y]
        for x in range(w):
            d1 = b11[x] + wl1[x] + wr1[x] + wu1[x] + wd1[x]
            d2 = b22[x] + wl2[x] + wr2[x] + wu2[x] + wd2[x]
            i1[x] = np.float32(1.0) / d1 if d1 > 0 else np.float32(0.0)
            i2[x] = np.float32(1.0) / d2 if d2 > 0 else np.float32(0.0)
