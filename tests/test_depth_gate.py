"""Depth-band gate (processing.preprocess.depth_gate): objects out of the gas's band."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from processing.chain import ChainParameters
from processing.preprocess.depth_gate import (
    MIN_VOTES,
    DepthGate,
    _local_majority,
    apply_gate,
    out_of_band_motion,
    too_few_votes,
)
from processing.preprocess.differential import PreprocessedTriple
from processing.preprocess.gate_sgbm import sgbm_around

H, W = 120, 320
BAND = (40.0, 72.0)  # the gas's disparity band, px


def _blob(center: tuple[float, float], radius: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Smooth texture (+-0.3 around 0) on a soft disk, and the disk."""
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.standard_normal((H, W)).astype(np.float32), (0, 0), 2.0)
    tex *= 0.3 / tex.std()
    yy, xx = np.mgrid[0:H, 0:W]
    disk = np.hypot(xx - center[0], yy - center[1]) < radius
    return np.where(disk, tex, 0).astype(np.float32), disk


def _views(blobs: list[tuple[np.ndarray, float]]) -> tuple[np.ndarray, np.ndarray]:
    """Differential images (0.5 = no change): each blob at its disparity (x_R = x_L - d)."""
    left = np.full((H, W), 0.5, np.float32)
    right = left.copy()
    for tex, d in blobs:
        left += tex
        m = np.float32([[1, 0, -d], [0, 1, 0]])
        right += cv2.warpAffine(tex, m, (W, H), flags=cv2.INTER_LINEAR)
    return np.clip(left, 0, 1), np.clip(right, 0, 1)


def test_object_at_the_left_edge_is_gated() -> None:
    # SGBM gives no disparity in the leftmost num_disparities columns (here 96 of 320 at
    # full resolution): an object there went through the gate (none of it matched).
    obj, disk = _blob((48.0, 60.0), 25.0, seed=1)
    left, right = _views([(obj, 20.0)])
    gate = out_of_band_motion(left, right, d_min=BAND[0], d_max=BAND[1], dilate_px=2)
    assert gate.left[disk].mean() > 0.9
    assert gate.right[np.roll(disk, -20, axis=1)].mean() > 0.9


def test_object_touching_gas_is_gated_and_the_gas_kept() -> None:
    # The object (d = 20 px, out of band) overlaps a larger gas cloud (d = 50 px): one
    # connected active region in which the gas's in-band votes are the majority. The
    # region's verdict kept the object; the local vote removes it and keeps the gas.
    obj, obj_disk = _blob((190.0, 60.0), 25.0, seed=1)
    gas, gas_disk = _blob((250.0, 60.0), 50.0, seed=2)
    left, right = _views([(obj, 20.0), (gas, 50.0)])
    gate = out_of_band_motion(left, right, d_min=BAND[0], d_max=BAND[1], dilate_px=2)
    only_obj = obj_disk & ~gas_disk
    only_gas = gas_disk & ~obj_disk & ~cv2.dilate(obj_disk.astype(np.uint8),
                                                  np.ones((41, 41), np.uint8)).astype(bool)
    assert gate.left[only_obj].mean() > 0.8  # measured 0.86 (the rest: beside the gas)
    assert gate.left[only_gas].mean() < 0.05
    assert gate.fraction < 0.1


def test_sgbm_matches_only_around_the_voting_pixels() -> None:
    # An object (d = 20 px) in front of a textured wall (d = 4 px) that SGBM matches
    # everywhere: SGBM around the object's box gives the whole image's verdict there and
    # matches nothing farther than the margin.
    obj, disk = _blob((120.0, 60.0), 20.0, seed=1)
    wall, _ = _blob((160.0, 60.0), 1000.0, seed=4)
    left, right = _views([(obj, 20.0), (wall / 3, 4.0)])
    box = (40, 81, 100, 141)
    d, valid = sgbm_around(left, right, 48, box, 1)
    whole_d, whole_valid = sgbm_around(left, right, 48, (0, H, 0, W), 1)
    assert not valid[:, :84].any() and not valid[:, 157:].any() and not valid[:24].any()
    assert whole_valid[:, 160:].mean() > 0.5  # the wall: matched on the whole image
    both = valid & whole_valid & disk
    assert both.sum() > 0.5 * disk.sum()
    assert np.median(np.abs(d[both] - whole_d[both])) < 0.5
    assert abs(float(np.median(d[both])) - 20.0) < 1.0


def test_a_still_view_pair_skips_semi_global_matching(monkeypatch: pytest.MonkeyPatch) -> None:
    # Without active pixels (or with fewer than an object needs) nothing can vote out of
    # band: the gate is empty without matching at all.
    import processing.preprocess.gate_sgbm as gate_module

    def no_sgbm(*args: object, **kwargs: object) -> None:
        raise AssertionError("SGBM ran on a still pair")

    monkeypatch.setattr(gate_module, "sgbm_disparity", no_sgbm)
    rng = np.random.default_rng(3)
    still = (0.5 + 0.002 * rng.standard_normal((H, W))).astype(np.float32)
    gate = out_of_band_motion(still, still.copy(), d_min=BAND[0], d_max=BAND[1])
    assert gate.fraction == 0.0 and not gate.left.any()


def test_gas_alone_is_not_gated() -> None:
    gas, _ = _blob((200.0, 60.0), 50.0, seed=2)
    left, right = _views([(gas, 50.0)])
    gate = out_of_band_motion(left, right, d_min=BAND[0], d_max=BAND[1], dilate_px=2)
    assert gate.fraction == 0.0 and not gate.left.any() and not gate.right.any()


def _triple(raw: np.ndarray, scale: float) -> PreprocessedTriple:
    diff = np.clip(0.5 + raw / (2 * scale), 0, 1).astype(np.float32)
    return PreprocessedTriple(diff0=diff, diff1=diff.copy(), raw0=raw, raw1=raw.copy(),
                              shifts=((0.0, 0.0), (0.0, 0.0)), rejected_shifts=0,
                              rejected=(False, False))


def test_the_gate_removes_its_pixels_from_normalised_and_raw_differences() -> None:
    # Raw differences too: no normalisation quantile may see the warm object.
    gas, _ = _blob((200.0, 60.0), 50.0, seed=2)
    raw = (gas / 0.3 * 0.5).astype(np.float32)
    obj = np.zeros((H, W), bool)
    obj[40:80, 20:60] = True
    raw[obj] = 20.0
    tri = _triple(raw, 20.0)
    gate = DepthGate(left=obj, right=obj, fraction=float(obj.mean()))
    pl, pr = apply_gate(tri, tri, gate)
    for t in (pl, pr):
        assert np.all(t.diff0[obj] == 0.5) and np.all(t.diff1[obj] == 0.5)
        assert not t.raw0[obj].any() and not t.raw1[obj].any()
        np.testing.assert_array_equal(t.raw0[~obj], raw[~obj])


def _shifted(a: np.ndarray, d: float) -> np.ndarray:
    """``a`` as the right camera sees it at disparity ``d`` (x_R = x_L - d)."""
    return cv2.warpAffine(a, np.float32([[1, 0, -d], [0, 1, 0]]), (W, H),
                          flags=cv2.INTER_LINEAR)


def test_gas_at_the_left_border_without_a_partner_is_kept() -> None:
    # Left of x = d the right camera does not see the gas: SGBM's disparities there are
    # whatever else matches, mostly small ones, and 6 % of this gas went as an object.
    gas, disk = _blob((30.0, 60.0), 28.0, seed=3)
    left = np.clip(0.5 + gas, 0, 1)
    right = np.clip(0.5 + _shifted(gas, 50.0), 0, 1)
    gate = out_of_band_motion(left, right, d_min=BAND[0], d_max=BAND[1], dilate_px=2)
    assert gate.left[disk].mean() < 0.01


def test_default_tolerance_gates_an_object_just_beyond_the_band() -> None:
    # An object 2.5 px beyond the gas's far edge (the wide matrix's warm object at 8 m,
    # 29.3 px, behind gas whose band starts at 32 px): 3 px of tolerance kept it.
    obj, disk = _blob((200.0, 60.0), 25.0, seed=1)
    left = np.clip(0.5 + obj, 0, 1)
    right = np.clip(0.5 + _shifted(obj, BAND[0] - 2.5), 0, 1)
    gate = out_of_band_motion(left, right, d_min=BAND[0], d_max=BAND[1], dilate_px=2,
                              tolerance_px=ChainParameters().gate_tolerance_px)
    assert gate.left[disk].mean() > 0.9


def _ring_and_gas() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A strong ring (an object's edges): its left half at d = 20 px, out of band, its right
    half seen at d = 50 px (in band, as through gas); and a faint gas cloud at 50 px
    touching it. Returns left, right, the raw change, the ring's two halves."""
    yy, xx = np.mgrid[0:H, 0:W]
    r = np.hypot(xx - 150.0, yy - 60.0)
    ring = (r < 30) & (r > 22)
    near_half = ring & (xx > 150)
    change = np.where(ring, 0.4, 0).astype(np.float32)
    change += np.where(ring, _blob((150.0, 60.0), 40.0, seed=5)[0] / 6, 0).astype(np.float32)
    gas, _ = _blob((215.0, 60.0), 38.0, seed=2)
    gas *= np.float32(0.25)
    right = (_shifted(np.where(near_half, 0, change).astype(np.float32), 20.0)
             + _shifted(np.where(near_half, change, 0).astype(np.float32), 50.0)
             + _shifted(gas, 50.0))
    return (np.clip(0.5 + change + gas, 0, 1), np.clip(0.5 + right, 0, 1), change + gas,
            ring & ~near_half, near_half)


def test_an_objects_edge_with_in_band_disparities_goes_with_it() -> None:
    left, right, raw, far_half, near_half = _ring_and_gas()
    votes_only = out_of_band_motion(left, right, d_min=BAND[0], d_max=BAND[1], dilate_px=2)
    grown = out_of_band_motion(left, right, d_min=BAND[0], d_max=BAND[1], dilate_px=2,
                               amplitude=raw)
    assert votes_only.left[far_half].mean() > 0.7  # measured 0.83
    assert votes_only.left[near_half].mean() < 0.2  # measured 0
    assert grown.left[far_half].mean() > 0.9 and grown.left[near_half].mean() > 0.9
    # the faint gas beside the ring stays: its change is far below the object's
    yy, xx = np.mgrid[0:H, 0:W]
    gas_only = (np.hypot(xx - 215.0, yy - 60.0) < 38) & (xx > 200)
    assert grown.left[gas_only].mean() < 0.05


def test_grow_fraction_is_checked() -> None:
    with pytest.raises(ValueError, match="gate_grow_fraction"):
        ChainParameters(gate_grow_fraction=1.5)


def test_votes_as_faint_as_the_gas_do_not_grow_into_it() -> None:
    # Out-of-band votes whose change is no stronger than the gas's (SGBM on noisy faint gas)
    # must not take the gas they touch: growing from them took 78 % of a noisy plume.
    yy, xx = np.mgrid[0:H, 0:W]
    ring = (np.hypot(xx - 150.0, yy - 60.0) < 30) & (np.hypot(xx - 150.0, yy - 60.0) > 22)
    faint = np.where(ring, 0.1, 0).astype(np.float32)
    faint += np.where(ring, _blob((150.0, 60.0), 40.0, seed=5)[0] / 12, 0).astype(np.float32)
    gas, gas_disk = _blob((200.0, 60.0), 30.0, seed=2)
    left = np.clip(0.5 + faint + gas, 0, 1)
    right = np.clip(0.5 + _shifted(faint, 20.0) + _shifted(gas, 50.0), 0, 1)
    gate = out_of_band_motion(left, right, d_min=BAND[0], d_max=BAND[1], dilate_px=2,
                              amplitude=faint + gas)
    assert gate.left[ring & (xx < 140)].mean() > 0.7  # the faint object itself still goes
    assert gate.left[gas_disk & (xx > 190)].mean() < 0.05


def test_faint_gas_joined_to_an_object_is_kept_away_from_its_votes() -> None:
    # Gas too faint to vote (below the activity floor, above the region threshold) that
    # touches an object forms one region with it; the object's verdict took all of it
    # (measured: 30 % of a plume with the object at its edge).
    obj, obj_disk = _blob((80.0, 60.0), 22.0, seed=1)
    yy, xx = np.mgrid[0:H, 0:W]
    faint_gas = ((xx > 95) & (xx < 300) & (np.abs(yy - 60) < 30)).astype(np.float32)
    faint_gas *= np.float32(0.035)
    left = np.clip(0.5 + obj + faint_gas, 0, 1)
    right = np.clip(0.5 + _shifted(obj, 20.0) + _shifted(faint_gas, 50.0), 0, 1)
    gate = out_of_band_motion(left, right, d_min=BAND[0], d_max=BAND[1], dilate_px=2)
    assert gate.left[obj_disk].mean() > 0.9
    assert gate.left[(faint_gas > 0) & (xx > 160)].mean() < 0.05


def test_too_few_votes_counts_the_windows_mirrored_votes_at_the_border() -> None:
    # Fewer than MIN_VOTES out-of-band votes remove nothing in the middle of the image, but
    # in a corner the local vote's window counts them up to four times (mirrored border):
    # the shortcut must then leave the decision to the vote, which does remove them.
    votes = MIN_VOTES - 3
    none_in = np.zeros((H, W), bool)
    d = np.full((H, W), 20.0, np.float32)
    middle = none_in.copy()
    middle[60, 150:150 + votes] = True
    assert too_few_votes(middle)
    assert not _local_majority(middle, none_in, d, np.ones((H, W), bool)).any()
    corner = none_in.copy()
    corner[:3, :3] = True
    assert corner.sum() == votes
    assert not too_few_votes(corner)
    assert _local_majority(corner, none_in, d, np.ones((H, W), bool)).any()
    assert not too_few_votes(np.ones((H, W), bool))
