"""The apparent-motion analysis (benchmarks/apparent_motion.py) on images whose motion is known."""

from __future__ import annotations

import cv2
import numpy as np

from benchmarks import apparent_motion as am


def _moving_pair(shift: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """A smooth random pattern and the same pattern moved by ``shift`` = (u, v) px."""
    rng = np.random.default_rng(3)
    d0 = cv2.GaussianBlur(rng.normal(0, 1, (96, 128)).astype(np.float32), (0, 0), 2.5)
    m = np.float32([[1, 0, shift[0]], [0, 1, shift[1]]])
    d1 = cv2.warpAffine(d0, m, (128, 96), flags=cv2.INTER_CUBIC,
                        borderMode=cv2.BORDER_REPLICATE)
    return d0, d1


def test_a_flow_one_fifth_short_is_found_short_by_the_data() -> None:
    d0, d1 = _moving_pair((3.0, 1.0))
    true = np.broadcast_to(np.float32([3.0, 1.0]), (96, 128, 2))
    short = true / 1.2
    mask = np.zeros((96, 128), bool)
    mask[16:80, 16:112] = True
    scale, scan = am.best_scale(d0, d1, short, mask)
    assert scale == 1.2
    assert am.warp_residual(d0, d1, true, mask) < 0.1 * scan[am.SCALES.index(1.0)]
    assert abs(am.along_ratio(short, true, mask) - 1 / 1.2) < 1e-6


def test_the_right_flow_is_best_unscaled() -> None:
    d0, d1 = _moving_pair((-2.0, 2.5))
    flow = np.broadcast_to(np.float32([-2.0, 2.5]), (96, 128, 2))
    mask = np.ones((96, 128), bool)
    mask[:12], mask[-12:], mask[:, :12], mask[:, -12:] = False, False, False, False
    assert am.best_scale(d0, d1, flow, mask)[0] == 1.0
