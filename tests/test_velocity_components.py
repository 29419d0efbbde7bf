"""The per-component comparison (benchmarks/velocity_components.py) on known fields."""

from __future__ import annotations

import numpy as np

from appliance.evaluation.sceneflow import common_mean_velocities
from benchmarks import velocity_components as vc


def _fields() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A reference of (1, -0.5, -2) m/s on a block of gas, NaN off it; a measurement with
    V_Z at half its value there, garbage on an invalid strip and outside the gas."""
    h, w = 40, 60
    ref_mask = np.zeros((h, w), bool)
    ref_mask[10:30, 10:50] = True
    reference = np.full((h, w, 3), np.nan, np.float32)
    reference[ref_mask] = (1.0, -0.5, -2.0)
    velocity = np.full((h, w, 3), 50.0, np.float32)
    velocity[ref_mask] = (1.0, -0.5, -1.0)
    valid = np.ones((h, w), bool)
    valid[10:30, 10:15] = False
    velocity[10:30, 10:15] = 1e3  # invalid: must not count
    gas = np.zeros((h, w), bool)
    gas[5:35, 10:55] = True  # segmented beyond the reference's gas
    return velocity, valid, gas, reference, ref_mask


def test_the_means_cover_only_pixels_segmented_valid_and_gas() -> None:
    velocity, valid, gas, reference, ref_mask = _fields()
    measured, truth, both = common_mean_velocities(velocity, valid, gas, reference, ref_mask)
    assert measured is not None and truth is not None
    assert both.sum() == 20 * 35
    np.testing.assert_allclose(measured, (1.0, -0.5, -1.0), rtol=1e-6)
    np.testing.assert_allclose(truth, (1.0, -0.5, -2.0), rtol=1e-6)
    np.testing.assert_allclose(vc.component_shares(measured, truth), (1.0, 1.0, 0.5),
                               rtol=1e-6)


def test_no_common_pixel_gives_none() -> None:
    velocity, valid, gas, reference, ref_mask = _fields()
    measured, truth, both = common_mean_velocities(velocity, valid, np.zeros_like(gas),
                                                   reference, ref_mask)
    assert measured is None and truth is None and not both.any()


def test_a_component_the_reference_hardly_has_gets_no_share() -> None:
    # an in-plane wind: V_Z of the reference ~0, any ratio of it would be noise
    shares = vc.component_shares(np.array([0.9, -0.8, 0.3]), np.array([1.0, -1.0, 0.001]))
    np.testing.assert_allclose(shares[:2], (0.9, 0.8))
    assert np.isnan(shares[2])
    assert np.isnan(vc.component_shares(np.ones(3), np.zeros(3))).all()


def test_the_magnitude_splits_into_extra_pixels_velocity_and_coverage() -> None:
    """A reference of 2 m/s on its gas, 1 m/s where the segmentation missed it; measured
    1.5 m/s on the common pixels and 0 on pixels segmented beyond the gas: each factor
    is its own share and the product is |V_avg| / |V*_avg|."""
    h, w = 20, 40
    ref_mask = np.zeros((h, w), bool)
    ref_mask[:, :30] = True
    reference = np.full((h, w, 3), np.nan, np.float32)
    reference[:, :20] = (2.0, 0.0, 0.0)
    reference[:, 20:30] = (1.0, 0.0, 0.0)  # the faint part the segmentation misses
    velocity = np.zeros((h, w, 3), np.float32)
    velocity[:, :20] = (1.5, 0.0, 0.0)
    region = np.zeros((h, w), bool)
    region[:, :20] = True
    region[:, 30:35] = True  # segmented, not gas, still: V = 0
    split = vc.magnitude_factors(velocity, region, reference, ref_mask)
    assert split is not None
    extra, vel, cover = split
    np.testing.assert_allclose((extra, vel, cover), (20 / 25, 0.75, 2.0 / (5.0 / 3.0)),
                               rtol=1e-6)
    measured = np.linalg.norm(velocity[region].mean(axis=0))
    truth = np.linalg.norm(reference[ref_mask].mean(axis=0))
    np.testing.assert_allclose(extra * vel * cover, measured / truth, rtol=1e-6)
    assert vc.magnitude_factors(velocity, np.zeros_like(region), reference, ref_mask) is None
