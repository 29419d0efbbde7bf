"""Display encodings of the fields: grey bytes, colour-coded flow and disparity, JPEG.

Shared by the live view (:mod:`appliance.live.view`) and the figures of the evaluation
commands (:mod:`appliance.evaluation.footage`), so a flow looks the same everywhere.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["disparity_bgr", "encode_jpeg", "flow_bgr", "ir_u8", "to_u8"]


def to_u8(img: np.ndarray) -> np.ndarray:
    """Display bytes of an (H, W) image.

    bool -> 0/255; float in [0, 1] -> x255 (clipped, NaN -> 0); uint8 as is; other integer
    types (raw uint16 counts) min-max stretched to 0..255.
    """
    a = np.asarray(img)
    if a.dtype == np.bool_:
        return a.astype(np.uint8) * 255
    if a.dtype == np.uint8:
        return a
    if np.issubdtype(a.dtype, np.floating):
        return (np.nan_to_num(np.clip(a, 0.0, 1.0)) * 255.0 + 0.5).astype(np.uint8)
    lo, hi = float(a.min()), float(a.max())
    scale = 255.0 / (hi - lo) if hi > lo else 0.0
    return ((a.astype(np.float32) - lo) * scale).astype(np.uint8)


def ir_u8(raw: np.ndarray, low_pct: float = 1.0, high_pct: float = 99.0) -> np.ndarray:
    """Raw IR counts as display bytes with the automatic gain of an OGI camera.

    A percentile stretch (``low_pct``..``high_pct`` to 0..255) rather than min-max, so one
    hot or dead pixel does not flatten the scene; black = cold, white = warm.
    """
    a = np.asarray(raw, np.float32)
    lo, hi = np.percentile(a, [low_pct, high_pct])
    scale = 255.0 / (hi - lo) if hi > lo else 0.0
    return np.clip((a - lo) * scale, 0.0, 255.0).astype(np.uint8)


def flow_bgr(flow: np.ndarray, max_magnitude: float | None = None) -> np.ndarray:
    """Colour-coded optical flow: hue = direction, brightness = magnitude.

    Parameters
    ----------
    flow
        (H, W, 2) flow (u right, v down) in px/frame (paper Eq. 5); NaN counts as zero.
    max_magnitude
        Magnitude in px/frame shown at full brightness (larger ones saturate); None: the
        field's own maximum.

    Returns
    -------
    (H, W, 3) uint8 BGR image; all black for a zero field.
    """
    f = np.nan_to_num(np.asarray(flow, np.float32))
    mag, ang = cv2.cartToPolar(f[..., 0], f[..., 1], angleInDegrees=True)
    top = float(mag.max()) if max_magnitude is None else float(max_magnitude)
    hsv = np.zeros((*f.shape[:2], 3), np.uint8)
    hsv[..., 0] = (ang / 2.0).astype(np.uint8)  # OpenCV hue is 0..179
    hsv[..., 1] = 255
    if top > 0:
        hsv[..., 2] = (np.clip(mag / top, 0.0, 1.0) * 255.0).astype(np.uint8)
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)


def disparity_bgr(disp: np.ndarray) -> np.ndarray:
    """(H, W) disparity in px (Eq. 6) as a TURBO colour map over its finite range; NaN black."""
    d = np.asarray(disp, np.float32)
    ok = np.isfinite(d)
    out = np.zeros(d.shape, np.uint8)
    if ok.any():
        lo, hi = float(d[ok].min()), float(d[ok].max())
        out[ok] = ((d[ok] - lo) / (hi - lo) * 254 + 1).astype(np.uint8) if hi > lo else 128
    bgr = cv2.applyColorMap(out, cv2.COLORMAP_TURBO)
    bgr[~ok] = 0
    return bgr


def encode_jpeg(img: np.ndarray, quality: int) -> bytes:
    """JPEG bytes of a (H, W) or (H, W, 3) BGR uint8 image."""
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError(f"JPEG encoding failed for an image of shape {img.shape}")
    return buf.tobytes()
