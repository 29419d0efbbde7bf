"""Opaque-edge gate: remove the moving edges of a warm object inside the gas's depth band.

The depth gate (:mod:`processing.preprocess.depth_gate`) removes what moves outside the gas's
disparity band; an object inside it cannot be told from gas by depth. Its radiance can: by
Eq. 1 a pixel seen through gas of transmittance tau reads I = L_bg tau + L_g (1 - tau), so
between two frames gas changes it by (L_bg - L_g) (tau0 - tau1), and the differential optical
depth D = (I(t) - I(t+1)) / (I_mid - L_g) = (tau0 - tau1) / tau_mid is the change of the gas's
optical depth: a few hundredths per frame. The edge of an opaque object crossing a pixel
changes it from the wall's radiance to its own, D = (L_bg - L_obj) / ((L_bg + L_obj) / 2 - L_g):
tenths (measured on the wide matrix's development scenes with the object at the gas's depth:
|D| > 0.2 for 88 % of the edge's pixels, for 1.3 % of the moving gas's,
``benchmarks/object_optical_depth.py``). The gas above that is the densest, where little of
the wall's radiance is left and I lies close to L_g; a warm object is brighter than the
wall. So a pixel is an object's edge when its |D| exceeds :data:`MIN_DEPTH_CHANGE` and its
radiance lies farther from L_g than that of the frame's median pixel; connected pieces of
at least :data:`MIN_PIXELS` such pixels, grown by :data:`GROW_PX`, are removed like the
depth gate's (:func:`processing.preprocess.depth_gate.apply_gate`). The object's soft rim
beyond them changes the wall by less than that but by far more than faint gas; left in the
raw differences it set the normalisation scale (0.999 quantile) at 1.5-2x the gas's own
(81-100 % of the pixels that set it lay within 10 px of the removed pieces, measured on
two scenes with the object inside the band), and on a plume moving away from the cameras
the constant-mode step then read d' twice too long. A further :data:`RIM_PX` ring therefore
leaves the raw differences too; the solvers keep it.

It needs L_g, the radiance of a black body at the gas's temperature (about the ambient air's),
and radiance units (the cameras' characteristic curves).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import cv2
import numpy as np

from processing.calibration.radiometric import CharacteristicCurve, gas_radiance_and_floor
from processing.preprocess.depth_gate import DepthGate, apply_gate, grown
from processing.preprocess.differential import PreprocessedTriple
from processing.preprocess.order_statistics import median

#: |D| above which a change is an opaque edge, not gas (dimensionless, per frame).
MIN_DEPTH_CHANGE = 0.2
#: Smallest connected piece of edge pixels that is removed, px (fewer are dense gas).
MIN_PIXELS = 20
#: The removed pieces grow by this much, px: the soft rim of the edge.
GROW_PX = 5
#: Beyond the removed pieces, this wide a ring leaves the raw differences too, px: the
#: normalisation quantile must not see the object's rim (module docstring).
RIM_PX = 10


def opaque_edges(frames: Sequence[np.ndarray], raw0: np.ndarray, raw1: np.ndarray,
                 gas_radiance: float, min_contrast: float) -> np.ndarray:
    """Pixels of one view that an opaque object's moving edge changed.

    Parameters
    ----------
    frames : three ndarrays, shape (H, W), float32
        The camera's corrected frames I(t0), I(t1), I(t2), radiance.
    raw0, raw1 : ndarray, shape (H, W), float32
        The triple's raw differences I(t0) - I(t1) and I(t1) - I(t2), radiance
        (:class:`processing.preprocess.differential.PreprocessedTriple`).
    gas_radiance : float
        L_g, radiance of a black body at the gas temperature.
    min_contrast : float
        Floor of |I_mid - L_g| in the division, radiance (the chain's 1 K).

    Returns
    -------
    ndarray, shape (H, W), bool
        The edge pixels, in pieces of at least :data:`MIN_PIXELS`, grown by :data:`GROW_PX`.
    """
    lg = np.float32(gas_radiance)
    wall = median(np.abs(frames[1] - lg))
    edge = np.zeros(raw0.shape, bool)
    for raw, a, b in ((raw0, frames[0], frames[1]), (raw1, frames[1], frames[2])):
        contrast = np.abs(np.float32(0.5) * (a + b) - lg)
        depth = np.abs(raw) / np.maximum(contrast, np.float32(min_contrast))
        edge |= (depth > MIN_DEPTH_CHANGE) & (contrast > wall)
    if not edge.any():
        return edge
    n, labels, stats, _ = cv2.connectedComponentsWithStats(edge.view(np.uint8), connectivity=8)
    keep = np.zeros(n, bool)
    keep[1:] = stats[1:, cv2.CC_STAT_AREA] >= MIN_PIXELS
    return grown(keep[labels], GROW_PX)


def _without_rim(triple: PreprocessedTriple, removed: np.ndarray) -> PreprocessedTriple:
    """``triple`` with its raw differences 0 within :data:`RIM_PX` of the ``removed``
    pixels; the normalised differences, which the solvers see, keep the rim."""
    rim = grown(removed, RIM_PX)
    zero = np.float32(0)
    return dataclasses.replace(triple, raw0=np.where(rim, zero, triple.raw0),
                               raw1=np.where(rim, zero, triple.raw1))


def remove_opaque_edges(pl: PreprocessedTriple, pr: PreprocessedTriple,
                        frames: tuple[Sequence[np.ndarray], Sequence[np.ndarray]],
                        curves: tuple[CharacteristicCurve | None, CharacteristicCurve | None],
                        gas_k: float, min_contrast_k: float,
                        blanked: tuple[np.ndarray, np.ndarray] | None, flags: list[str]
                        ) -> tuple[PreprocessedTriple, PreprocessedTriple,
                                   tuple[np.ndarray, np.ndarray] | None]:
    """Both views of a triple without their opaque edges (:func:`opaque_edges`), besides
    what is ``blanked`` already (the depth gate's masks, or None).

    ``frames`` are each camera's corrected frames (t0, t1, t2), ``curves`` their
    characteristic curves (radiance units), ``gas_k`` the gas temperature, K, and
    ``min_contrast_k`` the contrast floor, K. Returns the triples and the blanked masks
    (None when nothing is); appends ``object_motion_rejected`` to ``flags`` when it removes
    something.

    Raises
    ------
    ValueError
        A camera without a characteristic curve.
    """
    masks = []
    for triple, curve, own in zip((pl, pr), curves, frames, strict=True):
        if curve is None:
            raise ValueError("opaque_gate_gas_k needs the cameras' radiometric curves "
                             "(a calibration with characteristic curves)")
        lg, floor = gas_radiance_and_floor(gas_k, curve.band_m, min_contrast_k)
        masks.append(opaque_edges(own, triple.raw0, triple.raw1, lg, floor))
    if not (masks[0].any() or masks[1].any()):
        return pl, pr, blanked
    if "object_motion_rejected" not in flags:
        flags.append("object_motion_rejected")
    # only the new pixels: what the depth gate blanked is blanked already
    pl, pr = apply_gate(pl, pr, DepthGate(masks[0], masks[1], float(masks[0].mean())))
    pl, pr = (_without_rim(t, m) for t, m in zip((pl, pr), masks, strict=True))
    if blanked is not None:
        masks = [m | b for m, b in zip(masks, blanked, strict=True)]
    return pl, pr, (masks[0], masks[1])
