"""The d' two views' own flows imply (benchmarks/view_flows.py), on known flows."""

from __future__ import annotations

import numpy as np

from benchmarks.view_flows import implied_change


def _left_and_right(offset: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A horizontal flow that varies along the rows, the same motion seen by a right view
    12 px to the left (x_R = x_L - 12), there ``offset`` px per frame slower."""
    h, w = 30, 80
    xx = np.tile(np.arange(w, dtype=np.float32), (h, 1))
    u_left = 1.0 + 0.02 * xx
    d = np.full((h, w), 12.0, np.float32)
    u_right = 1.0 + 0.02 * (xx + 12.0) - offset
    return u_left, u_right, d


def test_one_motion_seen_by_both_views_implies_no_change() -> None:
    u_left, u_right, d = _left_and_right(0.0)
    implied = implied_change(u_left, u_right, d)
    np.testing.assert_allclose(implied[:, 12:], 0.0, atol=1e-5)


def test_a_right_view_moving_slower_implies_that_much_change() -> None:
    u_left, u_right, d = _left_and_right(0.25)
    implied = implied_change(u_left, u_right, d)
    np.testing.assert_allclose(implied[:, 12:], 0.25, atol=1e-5)
    # the columns whose partner lies left of the right view take its border value
    assert np.isfinite(implied).all()
