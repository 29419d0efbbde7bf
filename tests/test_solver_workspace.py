"""The solvers' workspace: one buffer per thread that every level size reuses.

Whatever an earlier, larger level left in that buffer must not reach a solution: the
kernels write every pixel's entry before reading it, and carving a workspace zeroes the
rest. Checked by filling the buffer with NaN first: a single stale value read through a
zero weight would turn the result into NaN.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

import cv2
import numpy as np
import pytest

from processing.flow.brox import brox_optical_flow
from processing.solvers import variational
from processing.stereo.joint import joint_disparity


def _smooth(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    a = cv2.GaussianBlur(rng.random(shape).astype(np.float32), (0, 0), 2.0)
    return (a - a.min()) / (a.max() - a.min())


def _shifted(a: np.ndarray, dx: float, dy: float) -> np.ndarray:
    m = np.float32([[1, 0, dx], [0, 1, dy]])
    return cv2.warpAffine(a, m, a.shape[::-1], flags=cv2.INTER_CUBIC,
                          borderMode=cv2.BORDER_REFLECT)


def _in_thread(fn: Callable[[], object]) -> object:
    """``fn`` in a new thread: a thread's first workspace starts from a zeroed buffer."""
    out: list[object] = []
    t = threading.Thread(target=lambda: out.append(fn()))
    t.start()
    t.join()
    return out[0]


def _poisoned(fn: Callable[[], object]) -> Callable[[], object]:
    """``fn`` after a larger level filled every plane of the thread's buffer with NaN."""
    def run() -> object:
        ws = variational.workspace((64, 80))
        for a in (ws.inputs, *ws.coefs, ws.s2):
            a.fill(np.nan)
        for pair in (ws.x1, ws.x2, ws.x1_0, ws.x2_0, ws.a11, ws.a22, ws.psi1, ws.psi2):
            for a in pair:
                a.fill(np.nan)
        return fn()
    return run


@pytest.mark.parametrize("shape", [(41, 53), (40, 52), (33, 60)])
def test_a_flow_after_stale_nan_levels_is_the_flow_from_fresh_memory(shape: tuple[int, int]
                                                                      ) -> None:
    rng = np.random.default_rng(3)
    i0 = _smooth(rng, shape)
    i1 = _shifted(i0, 0.8, -0.4)

    def solve() -> np.ndarray:
        return brox_optical_flow(i0, i1, min_level_size=8)

    fresh = _in_thread(solve)
    stale = _in_thread(_poisoned(solve))
    assert np.isfinite(fresh).all()
    np.testing.assert_array_equal(stale, fresh)
    # the flow moved: the test solved something
    assert abs(float(np.median(fresh[..., 0])) - 0.8) < 0.2


def test_a_disparity_after_stale_nan_levels_is_the_disparity_from_fresh_memory() -> None:
    rng = np.random.default_rng(5)
    shape = (39, 57)
    il0 = _smooth(rng, shape)
    ir0 = _shifted(il0, -3.0, 0.0)
    il1 = _shifted(il0, 0.5, 0.0)
    ir1 = _shifted(il0, -2.7, 0.0)
    flow = np.zeros((*shape, 2), np.float32)
    flow[..., 0] = 0.5

    def solve() -> tuple[np.ndarray, np.ndarray]:
        return joint_disparity(il0, ir0, il1, ir1, flow, d0=2.0, min_level_size=8)

    fresh = _in_thread(solve)
    stale = _in_thread(_poisoned(solve))
    for f, s in zip(fresh, stale, strict=True):
        assert np.isfinite(f).all()
        np.testing.assert_array_equal(s, f)
    assert abs(float(np.median(fresh[0])) - 3.0) < 0.5


def test_every_level_size_of_a_thread_shares_one_buffer() -> None:
    def sizes() -> tuple[bool, bool]:
        big = variational.workspace((64, 80))
        small = variational.workspace((17, 23))
        again = variational.workspace((17, 23))
        return np.shares_memory(big.inputs, small.inputs), again is small

    assert _in_thread(sizes) == (True, True)


def _masks_by_definition(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Edge masks pixel by pixel: pixel (y, x) is entry (y + 1, x // 2 + 1) of colour
    (x + y) & 1; 1 where the neighbour lies inside the image, 0 everywhere else."""
    shape = (4, height + 2, (width + 1) // 2 + 2)
    masks = np.zeros((2, *shape), np.float32)
    for y in range(height):
        for x in range(width):
            m = masks[(x + y) & 1]
            m[:, y + 1, x // 2 + 1] = (x > 0, x < width - 1, y > 0, y < height - 1)
    return masks[0], masks[1]


@pytest.mark.parametrize("height", [1, 2, 3, 9, 40, 41])
@pytest.mark.parametrize("width", [1, 2, 3, 9, 52, 53])
def test_edge_weights_are_the_mean_psi_inside_and_zero_across_borders_and_padding(
        height: int, width: int) -> None:
    """Every entry of the four weight planes is written: psi' means times the edge masks
    of their definition, whatever the planes held before."""
    from processing.solvers import redblack
    from processing.solvers.lagged import edge_weights

    rng = np.random.default_rng(height * 100 + width)
    shape = redblack.compact_shape(height, width)
    psi = [rng.uniform(0.5, 2.0, shape).astype(np.float32) for _ in range(2)]
    masks = _masks_by_definition(height, width)
    for c in range(2):
        coef = np.full((redblack.N_PLANES, *shape), np.nan, np.float32)
        edge_weights(psi[c], psi[1 - c], width, 0.3, c, coef, redblack.W1)
        own, other = psi[c], psi[1 - c]
        half = np.float32(0.15)
        for yc in range(1, height + 1):
            off = (yc - 1 + c) & 1
            n = shape[1] - 2
            neighbours = (other[yc, off:off + n], other[yc, off + 1:off + 1 + n],
                          other[yc - 1, 1:n + 1], other[yc + 1, 1:n + 1])
            for k, q in enumerate(neighbours):
                want = half * (own[yc, 1:n + 1] + q) * masks[c][k, yc, 1:n + 1]
                np.testing.assert_array_equal(coef[redblack.W1 + k, yc, 1:n + 1], want)
