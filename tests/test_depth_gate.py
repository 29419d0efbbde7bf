"""Depth-band gate (processing.depth_gate): objects out of the gas's band, wherever they are."""

from __future__ import annotations

import cv2
import numpy as np

from processing.depth_gate import DepthGate, apply_gate, out_of_band_motion
from processing.preprocess import PreprocessedTriple

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


def _gated_scale(renormalise: bool) -> tuple[float, np.ndarray]:
    """A faint gas texture (|D| <= 1) and a warm object (|D| = 20) that the gate removes;
    the triple normalised with a scale of 20 (as the object set it)."""
    gas, _ = _blob((200.0, 60.0), 50.0, seed=2)
    raw = (gas / 0.3 * 0.5).astype(np.float32)
    obj = np.zeros((H, W), bool)
    obj[40:80, 20:60] = True
    raw[obj] = 20.0
    tri = _triple(raw, 20.0)
    gate = DepthGate(left=obj, right=obj, fraction=float(obj.mean()))
    pl, _, scale = apply_gate(tri, tri, gate, 20.0, renormalise=renormalise)
    assert np.all(pl.diff0[obj] == 0.5) and np.all(pl.raw0[obj] == 0)  # removed either way
    return scale, pl.diff0


def test_a_scale_from_the_triple_itself_is_taken_again_without_the_object() -> None:
    scale, diff = _gated_scale(renormalise=True)
    assert 0.5 < scale < 1.5  # the gas's own 0.999 quantile, not the object's 20
    assert np.abs(diff - 0.5).max() > 0.4  # the gas spans the grey levels again


def test_a_tracked_scale_is_kept_when_the_gate_fires() -> None:
    # A tracked scale comes from gated triples already; re-taking it from one triple's
    # remaining pixels made it jump whenever the gate fired (README, field robustness).
    scale, diff = _gated_scale(renormalise=False)
    assert scale == 20.0
    assert np.abs(diff - 0.5).max() < 0.05  # unchanged contrast
