"""Target detection in IR-like images: polarity, bit depth, contrast, sub-pixel accuracy."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from processing.calibration.pattern import (
    PatternSpec,
    detect_pattern,
    grid_irregularity,
    object_points,
    right_handed,
    to_gray8,
)
from processing.calibration.rig import (
    camera_rays,
    example_rig,
    ir_counts,
    random_target_poses,
    render_pattern,
)

SPECS = {
    "chessboard": PatternSpec("chessboard", 6, 9, 0.05),
    "circles": PatternSpec("circles", 6, 8, 0.05),
    "acircles": PatternSpec("acircles", 7, 4, 0.05),
}


@pytest.fixture(scope="module")
def rays():
    rig = example_rig()
    return rig, camera_rays(rig.K_left, rig.D_left, rig.image_size, 2)


def _match_error(points: np.ndarray, truth: np.ndarray) -> float:
    """RMS distance, allowing the 180 deg renumbering of a symmetric grid."""
    e = min(np.sqrt(((points - truth) ** 2).sum(1).mean()),
            np.sqrt(((points[::-1] - truth) ** 2).sum(1).mean()))
    return float(e)


@pytest.mark.parametrize("kind", list(SPECS))
@pytest.mark.parametrize("inverted", [False, True])
@pytest.mark.parametrize("dtype", [np.uint16, np.uint8])
def test_detects_target_in_low_contrast_ir(rays, kind, inverted, dtype) -> None:
    rig, r = rays
    spec = SPECS[kind]
    rng = np.random.default_rng(7)
    (rvec, tvec), = random_target_poses(rig, spec, 1, rng, distance_m=(1.2, 1.5),
                                        max_tilt_deg=30)
    # 600 counts of contrast on a 20000-count offset, 50 % contrast loss at the corners,
    # noise, blur: a heated target seen by a cooled MWIR camera.
    img = ir_counts(render_pattern(spec, r, rvec, tvec), rng, inverted=inverted, dtype=dtype)
    found = detect_pattern(img, spec)
    assert found is not None
    pts, _variant = found
    truth, _ = cv2.projectPoints(object_points(spec), rvec, tvec, rig.K_left, rig.D_left)
    assert pts.shape == (spec.n_points, 2)
    assert _match_error(pts, truth.reshape(-1, 2)) < 0.2


def test_absent_target_is_not_found(rays) -> None:
    rng = np.random.default_rng(1)
    noise = (20000 + rng.normal(0, 30, (240, 320))).astype(np.uint16)
    assert detect_pattern(noise, SPECS["chessboard"]) is None
    assert detect_pattern(noise, SPECS["circles"]) is None


def test_to_gray8_ignores_hot_pixels() -> None:
    img = np.full((100, 100), 20000, np.uint16)
    img[:, 50:] = 20400
    img[3, 3] = 65535  # a hot pixel must not squeeze the target into a few grey levels
    g = to_gray8(img)
    assert g.dtype == np.uint8
    assert int(g[:, 60].mean()) - int(g[:, 10].mean()) > 200


def test_grid_irregularity_flags_a_misplaced_point() -> None:
    spec = SPECS["chessboard"]
    pts = object_points(spec)[:, :2] * 300 + 20
    assert grid_irregularity(pts, spec) < 1e-6
    bad = pts.copy()
    bad[20] += 4.0
    assert grid_irregularity(bad, spec) > 0.3


def test_right_handed_undoes_a_mirrored_numbering() -> None:
    spec = SPECS["circles"]
    pts = object_points(spec)[:, :2] * 300 + 20
    mirrored = pts.reshape(spec.rows, spec.cols, 2)[:, ::-1].reshape(-1, 2)
    np.testing.assert_allclose(right_handed(mirrored, spec), pts)
    np.testing.assert_allclose(right_handed(pts, spec), pts)


@pytest.mark.parametrize("kwargs", [
    {"kind": "hexagons", "rows": 6, "cols": 9, "spacing_m": 0.05},
    {"kind": "chessboard", "rows": 1, "cols": 9, "spacing_m": 0.05},
    {"kind": "chessboard", "rows": 6, "cols": 9, "spacing_m": 0.0},
    {"kind": "acircles", "rows": 6, "cols": 4, "spacing_m": 0.05},
])
def test_bad_pattern_spec_raises(kwargs) -> None:
    with pytest.raises(ValueError):
        PatternSpec(**kwargs)


def test_asymmetric_object_points_follow_opencv() -> None:
    spec = PatternSpec("acircles", 3, 2, 0.01)
    np.testing.assert_allclose(
        object_points(spec)[:, :2],
        [[0, 0], [0.02, 0], [0.01, 0.01], [0.03, 0.01], [0, 0.02], [0.02, 0.02]], atol=1e-9)
