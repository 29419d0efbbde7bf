"""Display encodings of the fields: grey bytes, colour-coded flow and disparity, JPEG.

Shared by the live view (:mod:`appliance.live.view`) and the figures of the evaluation
commands (:mod:`appliance.evaluation.footage`), so a flow looks the same everywhere.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["ARROW_PX_PER_M_S", "GAS_COLOR", "disparity_bgr", "encode_jpeg", "flow_bgr",
           "ir_u8", "operator_arrows", "operator_bgr", "to_u8"]

#: Colour of the gas (overlay, arrows, series), RGB.
GAS_COLOR = (230, 120, 20)
#: Operator's picture: px of arrow per m/s of in-plane gas velocity.
ARROW_PX_PER_M_S = 12.0
#: Opacity of the gas overlay on the operator's picture.
GAS_OPACITY = 0.45


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


def operator_arrows(pixels: np.ndarray | None, velocity3d: np.ndarray | None,
                    max_arrows: int) -> tuple[np.ndarray, np.ndarray] | None:
    """The in-plane gas velocity arrows of the operator's picture.

    Parameters
    ----------
    pixels
        (N, 2) image positions (x, y) of the virtual gas surface points, px.
    velocity3d
        (N, 3) their 3D velocity, m/s (left camera frame, X right, Y down).
    max_arrows
        At most this many, evenly subsampled: a readable picture has fewer, longer arrows.

    Returns
    -------
    (origins (M, 2) px, vectors (M, 2) px) as float32, or None without points.
    """
    if pixels is None or velocity3d is None or not len(pixels):
        return None
    pix = np.asarray(pixels, np.float32).reshape(-1, 2)
    vel = np.asarray(velocity3d, np.float32).reshape(-1, 3)
    ok = np.isfinite(vel).all(1) & np.isfinite(pix).all(1)
    pix, vel = pix[ok], vel[ok]
    if len(pix) > max_arrows:
        keep = np.linspace(0, len(pix) - 1, max_arrows).astype(int)
        pix, vel = pix[keep], vel[keep]
    return pix, vel[:, :2] * ARROW_PX_PER_M_S


def operator_bgr(raw: np.ndarray, gas_mask: np.ndarray | None = None,
                 arrows: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """The operator's picture as one image: raw IR (:func:`ir_u8`), the gas region in
    :data:`GAS_COLOR` at :data:`GAS_OPACITY` and the in-plane velocity arrows
    (:func:`operator_arrows`), what the Rerun operator tab layers as separate entities.

    Returns
    -------
    (H, W, 3) uint8 BGR.
    """
    grey = ir_u8(raw)
    bgr = cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)
    colour = np.array(GAS_COLOR[::-1], np.float32)
    if gas_mask is not None:
        m = np.asarray(gas_mask, bool)
        if m.shape != grey.shape:
            raise ValueError(f"gas mask of shape {m.shape} for a picture of {grey.shape}")
        bgr[m] = ((1.0 - GAS_OPACITY) * bgr[m] + GAS_OPACITY * colour).astype(np.uint8)
    if arrows is not None:
        c = tuple(int(v) for v in colour)
        for (x, y), (u, v) in zip(*arrows, strict=True):
            cv2.arrowedLine(bgr, (round(float(x)), round(float(y))),
                            (round(float(x + u)), round(float(y + v))), c, 1,
                            cv2.LINE_AA, tipLength=0.3)
    return bgr
