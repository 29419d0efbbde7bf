"""Pixel binning: the chain on k x k blocks of a wide camera, the fields at camera size.

A 640x480 camera (GF620 class) has four times the pixels of the 320x240 the chain keeps up
with on a small box. ``ChainParameters.binning`` = k makes the chain average each k x k
block of the corrected, rectified frames and work on the smaller images (k^2 fewer pixels,
the temporal noise of a block k times lower), then return its fields at the camera's size,
each block's value on all of its pixels, so that everything downstream (recording, live
view, operator page, events, emission rate) sees the camera it is configured for.

The geometry of the binned images: a block's centre is the mean of its pixels' centres,
so a camera-pixel coordinate x is (x - (k - 1) / 2) / k in blocks, the camera constant is
s / k and the baseline stays. The chain's settings in px stay in camera pixels (what a user
measures on the camera's images) and are converted here; the motion and disparity fields
come back in camera pixels too.
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np

from processing.chain.parameters import ChainParameters
from processing.chain.result import SceneFlowResult
from processing.chain.summary import GasSummary
from processing.preprocess.binning import bin_image, check_binning
from processing.stereo_geometry import StereoGeometry

__all__ = ["bin_image", "binned_geometry", "binned_parameters", "binned_size", "block_of",
           "check_binning", "grow", "upsampled_result", "upsampled_summary"]


def binned_size(image_size: tuple[int, int], k: int) -> tuple[int, int]:
    """(W, H) of the images the chain works on for cameras of ``image_size`` (W, H), px,
    with ``binning`` k: whole k x k blocks."""
    return image_size[0] // k, image_size[1] // k


def binned_geometry(geometry: StereoGeometry, k: int) -> StereoGeometry:
    """The geometry of the binned, rectified images (Eq. 4's s, x0, y0 in blocks).

    Rectification and the radiometric curves are applied before binning, so the binned
    geometry has no maps; the curves stay (the gas radiance is taken from them).
    """
    if k == 1:
        return geometry
    w, h = geometry.image_size
    check_binning((w, h), k)
    x0, y0 = geometry.principal_point
    half = (k - 1) / 2.0
    return dataclasses.replace(
        geometry, camera_constant=geometry.camera_constant / k,
        principal_point=((x0 - half) / k, (y0 - half) / k),
        image_size=binned_size((w, h), k), maps_left=None, maps_right=None)


def binned_parameters(params: ChainParameters) -> ChainParameters:
    """``params`` with their settings in camera pixels converted to blocks.

    The SGM search range stays a multiple of 16 (rounded up: the band it covers never
    shrinks); integer settings are rounded up. ``denoise_lambda`` (px^2) and the solvers'
    options stay as they are: they are tuned to the images the chain works on, and the
    defaults are those of 320x240, which a 640x480 camera binned by 2 becomes.
    """
    k = params.binning
    if k == 1:
        return params
    return dataclasses.replace(
        params,
        d0=params.d0 / k,
        sgm_num_disparities=16 * math.ceil(params.sgm_num_disparities / (16 * k)),
        gate_tolerance_px=params.gate_tolerance_px / k,
        max_motion_px=math.ceil(params.max_motion_px / k),
        region_margin_px=math.ceil(params.region_margin_px / k),
        max_jitter_px=params.max_jitter_px / k,
        binning=1)


def grow(field: np.ndarray, k: int) -> np.ndarray:
    """Each value of ``field`` (h, w[, c]) on its k x k block: (h k, w k[, c])."""
    if field.dtype == np.bool_:
        return grow(field.view(np.uint8), k).view(np.bool_)
    h, w = field.shape[:2]
    # OpenCV's nearest neighbour at an integer factor takes source pixel floor(x / k):
    # the same values as np.repeat (tested), several times faster at 640x480
    out = cv2.resize(field, (w * k, h * k), interpolation=cv2.INTER_NEAREST)
    return out.reshape(h * k, w * k, *field.shape[2:])


def block_of(flat_index: np.ndarray, width: int, k: int) -> np.ndarray:
    """The flat indices into a block field (h, w) of the camera pixels whose flat indices
    into the camera-size field (h k, ``width`` = w k) are ``flat_index``: reading a block
    field there reads :func:`grow`'s field at those pixels, without growing it."""
    ys, xs = np.divmod(flat_index, width)
    return (ys // k) * (width // k) + xs // k


def upsampled_summary(summary: GasSummary, k: int) -> GasSummary:
    """The summary of the binned chain in camera pixels: its pixel counts times k^2, its
    means unchanged (every block counts k^2 times)."""
    if k == 1:
        return summary
    return dataclasses.replace(summary, pixel_count=summary.pixel_count * k * k,
                               gas_pixel_count=summary.gas_pixel_count * k * k)


def _shifts(shifts: tuple[tuple[float, float], tuple[float, float]], k: int
            ) -> tuple[tuple[float, float], tuple[float, float]]:
    return ((shifts[0][0] * k, shifts[0][1] * k), (shifts[1][0] * k, shifts[1][1] * k))


def upsampled_result(res: SceneFlowResult, k: int) -> SceneFlowResult:
    """The result of the binned chain at camera size: fields grown to k x k blocks,
    motions and disparities (px) times k, registration shifts and the solvers' box in
    camera pixels, the summary's pixel counts in camera pixels (its means unchanged: every
    block counts k^2 times)."""
    if k == 1:
        return res
    region = None if res.region is None else tuple(int(b) * k for b in res.region)
    return dataclasses.replace(
        res,
        diff_left=(grow(res.diff_left[0], k), grow(res.diff_left[1], k)),
        diff_right=(grow(res.diff_right[0], k), grow(res.diff_right[1], k)),
        flow=grow(res.flow, k) * np.float32(k),
        disparity=grow(res.disparity, k) * np.float32(k),
        disparity_change=grow(res.disparity_change, k) * np.float32(k),
        velocity=grow(res.velocity, k), position=grow(res.position, k),
        valid=grow(res.valid, k), u_sf=grow(res.u_sf, k),
        u_sf_valid=grow(res.u_sf_valid, k), gas_mask=grow(res.gas_mask, k),
        phi=grow(res.phi, k),
        summary=upsampled_summary(res.summary, k),
        shifts_left=_shifts(res.shifts_left, k), shifts_right=_shifts(res.shifts_right, k),
        region=region)  # type: ignore[arg-type]
