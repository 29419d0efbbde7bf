"""Energy-based denoising with a Sobolev prior, solved exactly in the DCT domain (Sec. 4.1).

The paper reduces the spatial noise of differential images with an energy-based filter with
a Sobolev prior (its ref. [11]): the denoised image u minimises

    E(u) = ||u - f||^2 + lambda ||grad u||^2,

a quadratic energy whose minimiser solves the linear system (I + lambda L) u = f, with L the
5-point Neumann Laplacian (``L = D^T D`` for forward differences D with zero flux across the
image border, i.e. ``-Laplacian``). The type-II DCT diagonalises L exactly: its eigenvalues are
(2 - 2 cos(pi k / W)) + (2 - 2 cos(pi l / H)), so

    u_hat(k, l) = f_hat(k, l) / (1 + lambda * ((2 - 2 cos(pi k / W)) + (2 - 2 cos(pi l / H))))

gives the exact minimiser with two 2-D DCTs (~1 ms at 320x240) and no iteration. The filter
is linear, preserves the image mean (the k = l = 0 term is untouched) and damps a spatial
frequency by 1 / (1 + lambda * eigenvalue): lambda is in px^2 and sqrt(lambda) is roughly the
smoothing length in pixels.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy import fft

from processing.validation import as_float_image, check_positive


@lru_cache(maxsize=16)
def _denominator(shape: tuple[int, int], lam: float) -> np.ndarray:
    """1 + lambda * eigenvalues of the Neumann Laplacian on an (H, W) grid (read-only)."""
    h, w = shape
    ey = 2.0 - 2.0 * np.cos(np.pi * np.arange(h) / h)
    ex = 2.0 - 2.0 * np.cos(np.pi * np.arange(w) / w)
    den = (1.0 + lam * (ey[:, None] + ex[None, :])).astype(np.float32)
    den.setflags(write=False)
    return den


def sobolev_denoise(image: np.ndarray, lam: float) -> np.ndarray:
    """Exact minimiser of ||u - f||^2 + lam ||grad u||^2 with Neumann boundaries.

    Parameters
    ----------
    image : ndarray, shape (H, W), float
        The noisy image f (e.g. a differential image, Eq. 2). Any intensity unit.
    lam : float
        Weight lambda >= 0 of the Sobolev (H^1) prior in px^2; 0 returns a copy.

    Returns
    -------
    ndarray, shape (H, W), float32
        The denoised image u, same unit and same mean as ``image``.

    Raises
    ------
    ValueError
        Not a 2-D float image, NaN/inf, or a negative/non-finite ``lam``.
    """
    f = as_float_image(image, "image")
    lam = check_positive(lam, "lam", allow_zero=True)
    if lam == 0.0:
        return f.copy()
    f_hat = fft.dctn(f, type=2, norm="ortho", workers=1)
    f_hat /= _denominator(f.shape, lam)
    return fft.idctn(f_hat, type=2, norm="ortho", workers=1).astype(np.float32, copy=False)
