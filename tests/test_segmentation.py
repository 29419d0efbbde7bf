"""Two-region level-set gas segmentation (Eq. 9) on noisy synthetic moving blobs."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from processing.segmentation.level_set import dirac, heaviside
from processing.segmentation.segment import initial_phi, segment_gas


def _moving_blob(
    seed: int, *, noise: float = 0.05, contrast: float = 0.15, h: int = 240, w: int = 320
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Normalised differential image of a textured gas ellipse moving by (1.5, -0.8) px.

    The flow is the blob's motion inside and zero outside, both with noise (what a flow
    solver gives on a noisy static background).
    """
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w]
    inside = ((x - 0.53 * w) / (0.22 * w)) ** 2 + ((y - 0.46 * h) / (0.21 * h)) ** 2 < 1
    texture = cv2.GaussianBlur(rng.standard_normal((h, w)).astype(np.float32), (0, 0), 2.0)
    texture /= texture.std()
    diff = 0.5 + np.where(inside, contrast * texture, 0.0) + noise * rng.standard_normal((h, w))
    flow = 0.3 * rng.standard_normal((h, w, 2))
    flow[inside] += (1.5, -0.8)
    return np.clip(diff, 0, 1).astype(np.float32), flow.astype(np.float32), inside


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum()) / float((a | b).sum())


@pytest.mark.parametrize(("seed", "noise"), [(0, 0.05), (1, 0.1), (2, 0.05)])
def test_noisy_moving_blob_iou_at_least_0_9(seed: int, noise: float) -> None:
    diff, flow, truth = _moving_blob(seed, noise=noise)
    seg = segment_gas(diff, flow)
    assert seg.mask.dtype == np.bool_ and seg.mask.shape == diff.shape
    assert seg.phi.dtype == np.float32 and seg.phi.shape == diff.shape
    np.testing.assert_array_equal(seg.mask, seg.phi > 0)
    assert _iou(seg.mask, truth) >= 0.9


def test_motion_alone_separates_a_blob_without_intensity_contrast() -> None:
    """u, v carry the information when I_diff does not: the flow term of q_i is used."""
    diff, flow, truth = _moving_blob(3, contrast=0.0)
    assert _iou(segment_gas(diff, flow).mask, truth) >= 0.9


def test_gas_side_chosen_from_activity_even_from_a_checkerboard_start() -> None:
    diff, flow, truth = _moving_blob(4)
    seg = segment_gas(diff, flow, init_threshold=1e9)  # forces the checkerboard start
    assert _iou(seg.mask, truth) >= 0.9


def test_static_noise_only_gives_no_gas() -> None:
    rng = np.random.default_rng(5)
    diff = (0.5 + 0.05 * rng.standard_normal((120, 160))).astype(np.float32)
    flow = (0.3 * rng.standard_normal((120, 160, 2))).astype(np.float32)
    seg = segment_gas(diff, flow)
    assert not seg.mask.any()
    assert (seg.phi < 0).all()


def test_heaviside_and_dirac() -> None:
    phi = np.array([-1e6, -1.0, 0.0, 1.0, 1e6], np.float32)
    np.testing.assert_allclose(heaviside(phi), [0.0, 0.25, 0.5, 0.75, 1.0], atol=1e-6)
    np.testing.assert_allclose(dirac(np.float32(0.0)), 1.0 / np.pi, rtol=1e-6)


def test_initial_phi_marks_active_pixels() -> None:
    diff, flow, truth = _moving_blob(6, noise=0.02)
    phi = initial_phi(diff, flow)
    assert _iou(phi > 0, truth) > 0.7


@pytest.mark.parametrize(
    ("diff", "flow", "match"),
    [
        (np.zeros((40, 40), np.float32), np.zeros((40, 41, 2), np.float32), "flow must have"),
        (np.zeros((40, 40), np.uint8), np.zeros((40, 40, 2), np.float32), "floating-point"),
        (np.zeros((4, 4), np.float32), np.zeros((4, 4, 2), np.float32), "too small"),
        (np.full((40, 40), np.nan, np.float32), np.zeros((40, 40, 2), np.float32), "NaN"),
        (np.zeros((40, 40), np.float32), np.full((40, 40, 2), np.inf, np.float32), "finite"),
    ],
)
def test_bad_input_raises(diff: np.ndarray, flow: np.ndarray, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        segment_gas(diff, flow)


def test_bad_parameters_raise() -> None:
    diff, flow, _ = _moving_blob(0, h=40, w=40)
    with pytest.raises(ValueError, match="nu"):
        segment_gas(diff, flow, nu=-1.0)
    with pytest.raises(ValueError, match="n_levels"):
        segment_gas(diff, flow, n_levels=0)
    with pytest.raises(ValueError, match="sweeps_per_update"):
        segment_gas(diff, flow, sweeps_per_update=0)


def _boxed(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The moving blob with its flow solved only in a box around it (the chain's active
    region): zero flow outside, as the chain leaves it."""
    diff, flow, truth = _moving_blob(seed, contrast=0.06)
    box = np.zeros(diff.shape, bool)
    box[40:200, 60:260] = True
    flow = np.where(box[..., None], flow, np.float32(0.0)).astype(np.float32)
    return diff, flow, truth, box


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_motion_counts_only_where_the_flow_was_solved(seed: int) -> None:
    """Outside the box the zero flow made the background's motion model a spike at zero,
    and the box's noise flow looked like gas; with the box given as ``flow_known`` the box's
    background stays background."""
    diff, flow, truth, box = _boxed(seed)
    plain = segment_gas(diff, flow)
    known = segment_gas(diff, flow, flow_known=box)
    false_plain = float((plain.mask & ~truth & box).sum()) / float((box & ~truth).sum())
    false_known = float((known.mask & ~truth & box).sum()) / float((box & ~truth).sum())
    assert false_known < 0.012
    assert false_plain > 2.5 * false_known
    assert _iou(known.mask, truth) > _iou(plain.mask, truth) + 0.01


def test_every_pixel_known_is_the_plain_segmentation_to_the_bit() -> None:
    diff, flow, _truth = _moving_blob(0)
    plain = segment_gas(diff, flow)
    known = segment_gas(diff, flow, flow_known=np.ones(diff.shape, bool))
    assert np.array_equal(plain.phi, known.phi) and np.array_equal(plain.mask, known.mask)


def test_flow_known_of_another_shape_is_refused() -> None:
    diff, flow, _truth = _moving_blob(0)
    with pytest.raises(ValueError, match="flow_known must have shape"):
        segment_gas(diff, flow, flow_known=np.ones((10, 10), bool))
