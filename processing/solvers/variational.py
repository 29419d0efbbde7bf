"""The solver core shared by the flow (paper Eq. 5) and the joint disparity (Eq. 6) solvers.

Both minimise a Charbonnier energy with the numerics of Brox et al. (2004): a pyramid of
the input images, coarse-to-fine refinement of the unknown fields, and at every level outer
warps, lagged fixed-point iterations and red-black SOR (:mod:`processing.solvers.redblack`,
:mod:`processing.solvers.lagged`). This module holds what the two have in common:

- :func:`check_options`: one validation of the numerical options;
- :func:`build_pyramids`: pre-smoothing and the level shapes, optionally only the finest
  ``n_levels`` (a warm start from the previous frame needs no coarse levels);
- :func:`coarse_to_fine`: the generic driver that resamples the fields from level to level
  and calls a level solver (scikit-image's ``_optical_flow_utils.coarse_to_fine`` is the
  model);
- :class:`Workspace` / :func:`workspace`: the compact red-black arrays of one level size,
  views of one buffer per thread that every level and call reuses, so that a solver call
  allocates no per-iteration memory (fresh pages were a third of the solver time before).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from typing import NamedTuple

import cv2
import numpy as np

from processing.solvers import pyramid, redblack

Fields = tuple[np.ndarray, ...]
LevelSolver = Callable[[int, Fields], Fields]

#: Per-pixel data-term inputs of the larger of the two solvers (the flow: 9).
N_INPUTS = 9


class Workspace(NamedTuple):
    """Preallocated compact red-black arrays for one level size (H, W).

    A NamedTuple, so that compiled code takes it as one argument
    (:func:`processing.solvers.lagged.lagged_iterations`). Every compact array has shape
    (H+2, W2+2), W2 = ceil(W/2) (one-pixel halo); pairs are (red, black). Contents are
    scratch: each solver call overwrites what it reads.

    Attributes
    ----------
    inputs : ndarray, shape (N_INPUTS, 2, H+2, W2+2), float32
        The per-pixel data-term inputs of one warp, split by colour.
    x1, x2, x1_0, x2_0 : (ndarray, ndarray)
        The two unknowns and their values at the warp (for the increments).
    coefs : (ndarray, ndarray), shape (13, H+2, W2+2) each
        The linear system (planes of :mod:`processing.solvers.redblack`).
    a11, a22, psi1, psi2 : (ndarray, ndarray)
        Data diagonals and the lagged smoothness weights of the two penalisers.
    s2 : ndarray
        Scratch for |grad f|^2.
    """

    shape: tuple[int, int]
    inputs: np.ndarray
    x1: tuple[np.ndarray, np.ndarray]
    x2: tuple[np.ndarray, np.ndarray]
    x1_0: tuple[np.ndarray, np.ndarray]
    x2_0: tuple[np.ndarray, np.ndarray]
    coefs: tuple[np.ndarray, np.ndarray]
    a11: tuple[np.ndarray, np.ndarray]
    a22: tuple[np.ndarray, np.ndarray]
    psi1: tuple[np.ndarray, np.ndarray]
    psi2: tuple[np.ndarray, np.ndarray]
    s2: np.ndarray


#: Compact planes of one level size in a workspace: the inputs, four pairs of unknowns,
#: two systems, four pairs of diagonals and weights, the scratch.
N_PLANES = 2 * N_INPUTS + 8 + 2 * redblack.N_PLANES + 8 + 1
#: The colour of each plane in :func:`_carve`'s order (-1: the scratch, which
#: :func:`processing.solvers.lagged.lagged_psi` zeroes whole before every use), for
#: :func:`processing.solvers.redblack.clear_outside_planes`.
_PLANE_COLOURS = np.array([*(k % 2 for k in range(2 * N_INPUTS)), *(0, 1) * 4,
                           *(0,) * redblack.N_PLANES, *(1,) * redblack.N_PLANES,
                           *(0, 1) * 4, -1], np.int8)

_local = threading.local()


def _carve(buffer: np.ndarray, height: int, width: int) -> Workspace:
    """A workspace for an (H, W) level whose arrays are C-contiguous views of ``buffer``
    (at least :data:`N_PLANES` compact planes), ready for the kernels: every entry that
    holds no pixel zeroed (:func:`processing.solvers.redblack.clear_outside`),
    whatever an earlier level left there. The kernels write every pixel's entry before
    they read it, so those entries are all that an earlier level's values could reach the
    solution through (``tests/test_solver_workspace.py``)."""
    cshape = redblack.compact_shape(height, width)
    plane = cshape[0] * cshape[1]
    planes = buffer[:N_PLANES * plane].reshape(N_PLANES, *cshape)
    at = 0

    def take(n: int) -> np.ndarray:
        nonlocal at
        at += n
        return planes[at - n:at]

    def pair() -> tuple[np.ndarray, np.ndarray]:
        return take(1)[0], take(1)[0]

    inputs = take(2 * N_INPUTS).reshape(N_INPUTS, 2, *cshape)
    x1, x2, x1_0, x2_0 = pair(), pair(), pair(), pair()
    coefs = take(redblack.N_PLANES), take(redblack.N_PLANES)
    ws = Workspace(shape=(height, width), inputs=inputs, x1=x1, x2=x2, x1_0=x1_0, x2_0=x2_0,
                   coefs=coefs, a11=pair(), a22=pair(), psi1=pair(),
                   psi2=pair(), s2=take(1)[0])
    redblack.clear_outside_planes(planes, _PLANE_COLOURS, width)
    return ws


def workspace(shape: tuple[int, int]) -> Workspace:
    """The workspace of this thread for level size ``shape`` (H, W).

    All level sizes of a thread share one buffer, grown to the largest size asked for:
    the solvers work on one level at a time, so one buffer keeps a worker's working set to
    its finest level's arrays. A workspace per size would allocate and keep a set for every
    level and every active-region box (120 bench triples ask for 119 sizes). A workspace
    is valid until this thread asks for another size.
    """
    key = (int(shape[0]), int(shape[1]))
    ws: Workspace | None = getattr(_local, "ws", None)
    if ws is not None and ws.shape == key:
        return ws
    cshape = redblack.compact_shape(*key)
    need = N_PLANES * cshape[0] * cshape[1]
    buffer: np.ndarray | None = getattr(_local, "buffer", None)
    if buffer is None or buffer.size < need:
        buffer = _local.buffer = np.zeros(need, np.float32)
    ws = _local.ws = _carve(buffer, *key)
    return ws


def check_options(*, eps: float, pyramid_factor: float, omega: float, presmooth_sigma: float,
                  n_levels: int | None, **counts: int) -> None:
    """Validate the numerical options common to both solvers.

    Raises
    ------
    ValueError
        eps <= 0, pyramid_factor outside (0, 1), omega outside (0, 2), presmooth_sigma < 0,
        n_levels not None or a positive integer, or any of ``counts`` (iteration counts,
        min_level_size) not a positive integer; the message names the option.
    """
    if not (np.isfinite(eps) and eps > 0):
        raise ValueError(f"eps must be a finite positive number, got {eps!r}")
    if not (np.isfinite(presmooth_sigma) and presmooth_sigma >= 0):
        raise ValueError(f"presmooth_sigma must be a finite non-negative number, "
                         f"got {presmooth_sigma!r}")
    if not 0.0 < pyramid_factor < 1.0:
        raise ValueError(f"pyramid_factor must be in (0, 1), got {pyramid_factor!r}")
    if not 0.0 < omega < 2.0:
        raise ValueError(f"omega must be in (0, 2), got {omega!r}")
    if n_levels is not None:
        counts = {**counts, "n_levels": n_levels}
    for name, n in counts.items():
        if isinstance(n, bool) or int(n) != n or n < 1:
            raise ValueError(f"{name} must be a positive integer, got {n!r}")


class PyramidCache:
    """Pyramids of images that several solver calls share within one chain call.

    The flow (Eq. 5) and the joint disparity (Eq. 6) both build pyramids of the left
    differential images I_L(t0), I_L(t1) with the same pre-smoothing and factor: with one
    cache passed to both, the second reuses the first's levels. Images are matched by
    identity, so a cache must not outlive the arrays it saw unchanged: make one per chain
    call.
    """

    def __init__(self) -> None:
        self._entries: list[tuple[np.ndarray, tuple[float, int, float], list[np.ndarray]]] = []

    def __len__(self) -> int:
        """The number of pyramids held."""
        return len(self._entries)

    def levels(self, image: np.ndarray, key: tuple[float, int, float],
               shapes: list[tuple[int, int]], smooth: Callable[[np.ndarray], np.ndarray]
               ) -> list[np.ndarray]:
        """The pyramid of ``image`` at ``shapes`` (finest first), built with ``smooth``
        as its pre-smoothing, or the finest part of one built before under ``key``."""
        for seen, seen_key, pyr in self._entries:
            if seen is image and seen_key == key and len(pyr) >= len(shapes):
                return pyr[:len(shapes)]
        pyr = pyramid.image_pyramid(smooth(image), shapes)
        self._entries.append((image, key, pyr))
        return pyr


def build_pyramids(images: Sequence[np.ndarray], *, pyramid_factor: float, min_level_size: int,
                   presmooth_sigma: float, n_levels: int | None,
                   cache: PyramidCache | None = None
                   ) -> tuple[list[tuple[int, int]], list[list[np.ndarray]]]:
    """Pre-smooth the images and build their pyramids, finest level first.

    Parameters
    ----------
    images : sequence of ndarray, shape (H, W), float32
        Same-shaped, validated images.
    pyramid_factor, min_level_size, presmooth_sigma
        See the solvers.
    n_levels : int or None
        Keep only the finest ``n_levels`` levels (None: down to ``min_level_size``).
    cache : PyramidCache, optional
        Pyramids already built for these very image objects are taken from it.

    Returns
    -------
    shapes : list of (int, int)
        Level shapes, finest first.
    pyramids : list of list of ndarray
        One pyramid per image, levels as in ``shapes``.
    """
    shape = images[0].shape
    shapes = pyramid.pyramid_shapes(shape, pyramid_factor, min(min_level_size, min(shape)))
    if n_levels is not None:
        shapes = shapes[:n_levels]

    def smooth(a: np.ndarray) -> np.ndarray:
        if presmooth_sigma <= 0:
            return a
        return cv2.GaussianBlur(a, (0, 0), presmooth_sigma, borderType=cv2.BORDER_REFLECT)

    if cache is None:
        return shapes, [pyramid.image_pyramid(smooth(a), shapes) for a in images]
    key = (float(pyramid_factor), int(min_level_size), float(presmooth_sigma))
    return shapes, [cache.levels(a, key, shapes, smooth) for a in images]


def coarse_to_fine(shapes: Sequence[tuple[int, int]], fields: Fields,
                   solve_level: LevelSolver) -> Fields:
    """Refine displacement fields from the coarsest level in ``shapes`` to the finest.

    Parameters
    ----------
    shapes : sequence of (int, int)
        Level shapes, finest first (:func:`build_pyramids`).
    fields : tuple of ndarray, (h, w) or (h, w, 2), float32
        Initial fields in px, at any size: each is resampled to every level with its
        values scaled to that level's pixels (a 2-D field is horizontal, e.g. a disparity;
        :func:`processing.solvers.pyramid.resize_field`).
    solve_level : callable (level, fields) -> fields
        Refines the fields at pyramid level ``level`` (0 = finest) and returns them at the
        same shape.

    Returns
    -------
    tuple of ndarray, float32
        The fields at the finest level.
    """
    for level in range(len(shapes) - 1, -1, -1):
        fields = tuple(
            f if f.shape[:2] == shapes[level]
            else pyramid.resize_field(f, shapes[level], is_motion=True)
            for f in fields
        )
        fields = solve_level(level, fields)
    return tuple(f.astype(np.float32, copy=False) for f in fields)
