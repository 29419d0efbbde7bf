"""Stereo calibration recovers a known stereo model from rendered IR target images.

Acceptance: focal length within 0.5 %, baseline within 1 %, reprojection RMS
below 0.3 px, from 14 views at 320x240 with lens distortion, IR-like low and uneven
contrast, noise, inverted polarity and mixed 8/16-bit images.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from processing.calibration import (
    ImageSizeError,
    PatternNotFoundError,
    PoorCalibrationError,
    TooFewViewsError,
    calibrate_stereo_images,
    calibrate_stereo_points,
    ideal_calibration,
    rectification_maps,
    rectify_pair,
)
from processing.calibration.pattern import PatternSpec, detect_pattern, object_points
from processing.calibration.rig import (
    example_rig,
    random_target_poses,
    render_stereo_views,
    right_pose,
)
from processing.calibration.stereo import outlier_threshold

RIG = example_rig()
CHESS = PatternSpec("chessboard", 6, 9, 0.05)
CIRCLES = PatternSpec("circles", 6, 8, 0.05)


def _views(spec: PatternSpec, n: int, seed: int):
    rng = np.random.default_rng(seed)
    poses = random_target_poses(RIG, spec, n, rng, distance_m=(1.0, 1.8))
    return poses, render_stereo_views(RIG, spec, poses, rng)


@pytest.fixture(scope="module")
def chess_result():
    poses, views = _views(CHESS, 14, seed=0)
    return poses, views, calibrate_stereo_images(CHESS, views)


def _check_acceptance(calib) -> None:
    for est, true in ((calib.K_left[0, 0], RIG.K_left[0, 0]),
                      (calib.K_left[1, 1], RIG.K_left[1, 1]),
                      (calib.K_right[0, 0], RIG.K_right[0, 0]),
                      (calib.K_right[1, 1], RIG.K_right[1, 1])):
        assert abs(est / true - 1) < 0.005, (est, true)
    assert abs(np.linalg.norm(calib.T) / np.linalg.norm(RIG.T) - 1) < 0.01
    assert abs(calib.b_m / np.linalg.norm(RIG.T) - 1) < 0.01
    assert calib.rms_px < 0.3


def test_chessboard_recovers_focal_length_baseline(chess_result) -> None:
    result = chess_result[2]
    _check_acceptance(result.calibration)
    assert len(result.views) == 14
    assert all(v.rms_px < 0.5 for v in result.views if v.kept)
    # R recovered to a fraction of a degree.
    dR = result.calibration.R @ RIG.R.T
    assert np.degrees(np.linalg.norm(cv2.Rodrigues(dR)[0])) < 0.2


@pytest.mark.parametrize("spec", [CIRCLES, PatternSpec("acircles", 7, 4, 0.05)],
                         ids=["circles", "acircles"])
def test_circle_grids_recover_focal_length_baseline(spec: PatternSpec) -> None:
    _poses, views = _views(spec, 14, seed=1)
    result = calibrate_stereo_images(spec, views)
    _check_acceptance(result.calibration)


def test_rectified_rows_align_and_disparity_gives_depth(chess_result) -> None:
    result = chess_result[2]
    calib = result.calibration
    rng = np.random.default_rng(3)
    X = np.column_stack([rng.uniform(-0.4, 0.6, 200), rng.uniform(-0.3, 0.3, 200),
                         rng.uniform(1.0, 3.0, 200)])
    pl, _ = cv2.projectPoints(X, np.zeros(3), np.zeros(3), RIG.K_left, RIG.D_left)
    pr, _ = cv2.projectPoints(X, cv2.Rodrigues(RIG.R)[0], RIG.T, RIG.K_right, RIG.D_right)
    pl, pr = pl.reshape(-1, 2), pr.reshape(-1, 2)
    seen = np.all((pl > 5) & (pl < [314, 234]) & (pr > 5) & (pr < [314, 234]), axis=1)
    assert seen.sum() > 100
    X, pl, pr = X[seen], pl[seen], pr[seen]
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    rl = cv2.undistortPoints(pl[:, None], calib.K_left, calib.D_left, None, calib.R1, calib.P1,
                             crit).reshape(-1, 2)
    rr = cv2.undistortPoints(pr[:, None], calib.K_right, calib.D_right, None, calib.R2,
                             calib.P2, crit).reshape(-1, 2)
    assert np.abs(rl[:, 1] - rr[:, 1]).max() < 0.3  # epipolar lines are image rows
    d = rl[:, 0] - rr[:, 0]
    z_rect = (calib.R1 @ X.T)[2]
    np.testing.assert_allclose(calib.s_px * calib.b_m / d, z_rect, rtol=0.01)  # Eq. 4


def test_rectify_pair_on_rendered_images(chess_result) -> None:
    _poses, views, result = chess_result
    maps = rectification_maps(result.calibration)
    name, left, right = views[2]
    left_r, right_r = rectify_pair(left, right, maps)
    assert left_r.dtype == left.dtype and left_r.shape == left.shape
    found_l, found_r = detect_pattern(left_r, CHESS), detect_pattern(right_r, CHESS)
    assert found_l is not None and found_r is not None, name
    pl, pr = found_l[0], found_r[0]
    if np.dot(pl[-1] - pl[0], pr[-1] - pr[0]) < 0:
        pr = pr[::-1]
    assert np.abs(pl[:, 1] - pr[:, 1]).max() < 0.5
    assert (pl[:, 0] - pr[:, 0]).min() > 0  # positive disparities
    assert maps.valid_left.mean() > 0.95  # alpha = 0 keeps (almost) only valid pixels


def test_ideal_calibration_rectifies_to_identity() -> None:
    calib = ideal_calibration(400.0, 0.3, (320, 240))
    maps = rectification_maps(calib)
    yy, xx = np.mgrid[0:240, 0:320]
    np.testing.assert_allclose(maps.left_x, xx, atol=1e-3)
    np.testing.assert_allclose(maps.right_y, yy, atol=1e-3)
    assert calib.s_px == 400.0 and calib.b_m == pytest.approx(0.3)
    img = np.random.default_rng(0).random((240, 320)).astype(np.float32)
    out, _ = rectify_pair(img, img, maps)
    np.testing.assert_allclose(out, img, atol=1e-5)


def test_rectify_pair_rejects_wrong_size() -> None:
    maps = rectification_maps(ideal_calibration(400.0, 0.3, (320, 240)))
    with pytest.raises(ValueError, match="320x240"):
        rectify_pair(np.zeros((240, 321)), np.zeros((240, 320)), maps)


# ------------------------------------------------------------------ outliers and errors


def _true_points(spec: PatternSpec, n: int, seed: int, noise_px: float = 0.05):
    rng = np.random.default_rng(seed)
    obj = object_points(spec)
    left, right = [], []
    for rvec, tvec in random_target_poses(RIG, spec, n, rng):
        p, _ = cv2.projectPoints(obj, rvec, tvec, RIG.K_left, RIG.D_left)
        left.append(p.reshape(-1, 2) + rng.normal(0, noise_px, (len(obj), 2)))
        rr, tr = right_pose(RIG, rvec, tvec)
        p, _ = cv2.projectPoints(obj, rr, tr, RIG.K_right, RIG.D_right)
        right.append(p.reshape(-1, 2) + rng.normal(0, noise_px, (len(obj), 2)))
    return [f"v{i:02d}" for i in range(n)], left, right


def test_outlier_view_is_dropped_and_named() -> None:
    names, left, right = _true_points(CHESS, 12, seed=5)
    rng = np.random.default_rng(9)
    right[4] = right[4] + rng.normal(0, 3.0, right[4].shape)  # e.g. target moved
    result = calibrate_stereo_points(CHESS, names, left, right, RIG.image_size)
    assert [v.name for v in result.dropped] == ["v04"]
    assert "RMS" in result.dropped[0].reason
    assert result.calibration.rms_px < 0.15
    assert result.calibration.meta["views_dropped"] == ["v04"]
    _check_acceptance(result.calibration)


def test_uniformly_good_views_are_all_kept() -> None:
    names, left, right = _true_points(CHESS, 10, seed=6)
    result = calibrate_stereo_points(CHESS, names, left, right, RIG.image_size)
    assert result.dropped == []


def test_outlier_threshold_has_a_floor() -> None:
    rms = np.array([0.10, 0.11, 0.12, 0.10, 0.13])
    assert outlier_threshold(rms, 3.0, 0.5) == 0.5
    assert outlier_threshold(np.array([1.0, 1.1, 0.9, 1.0]), 3.0, 0.5) > 1.1


def test_too_few_views_names_the_missing_ones() -> None:
    names, left, right = _true_points(CHESS, 4, seed=2)
    with pytest.raises(TooFewViewsError, match="only 4 usable") as exc:
        calibrate_stereo_points(CHESS, names, left, right, RIG.image_size,
                                not_found=["img9.png (left)"])
    assert "img9.png (left)" in str(exc.value)
    assert isinstance(exc.value, ValueError)


def test_too_few_views_after_dropping_outliers() -> None:
    names, left, right = _true_points(CHESS, 6, seed=2)
    right[1] = right[1] + 5.0 * np.random.default_rng(0).normal(size=right[1].shape)
    with pytest.raises(TooFewViewsError, match="v01"):
        calibrate_stereo_points(CHESS, names, left, right, RIG.image_size)


def test_wrong_spacing_gives_wrong_scale_not_wrong_rms() -> None:
    # The spacing sets the metric scale only: a wrong --spacing keeps the RMS but scales b.
    names, left, right = _true_points(CHESS, 8, seed=4)
    wrong = PatternSpec("chessboard", 6, 9, 0.025)
    calib = calibrate_stereo_points(wrong, names, left, right, RIG.image_size).calibration
    assert calib.b_m == pytest.approx(np.linalg.norm(RIG.T) / 2, rel=0.01)


def test_points_of_two_different_targets_give_poor_calibration() -> None:
    names, left, right = _true_points(CHESS, 8, seed=4, noise_px=2.0)
    with pytest.raises(PoorCalibrationError, match="exceeds"):
        calibrate_stereo_points(CHESS, names, left, right, RIG.image_size, outlier_floor_px=5.0)


def test_images_of_different_sizes_are_named() -> None:
    a = np.zeros((240, 320), np.uint16)
    b = np.zeros((240, 330), np.uint16)
    views = [(f"v{i}.png", a, a) for i in range(6)] + [("odd.png", a, b)]
    with pytest.raises(ImageSizeError, match=r"odd\.png \(right\)"):
        calibrate_stereo_images(CHESS, views)


def test_pattern_never_found() -> None:
    rng = np.random.default_rng(0)
    views = [(f"v{i}.png", (20000 + rng.normal(0, 30, (240, 320))).astype(np.uint16),
              (20000 + rng.normal(0, 30, (240, 320))).astype(np.uint16)) for i in range(2)]
    with pytest.raises(PatternNotFoundError, match="found in none of the 4 images"):
        calibrate_stereo_images(CHESS, views)


def test_wrong_pattern_size_is_never_found(chess_result) -> None:
    _poses, views, _ = chess_result
    with pytest.raises(PatternNotFoundError, match="--rows"):
        calibrate_stereo_images(PatternSpec("chessboard", 5, 9, 0.05), views[:1])
