"""Depth-band gate (processing.preprocess.depth_gate): objects out of the gas's band."""

from __future__ import annotations

import cv2
import numpy as np

from processing.preprocess.depth_gate import DepthGate, apply_gate, out_of_band_motion
from processing.preprocess.differential import PreprocessedTriple

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
