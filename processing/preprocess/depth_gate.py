"""Depth-band gate: remove moving things that are not at the gas's depth (beyond the paper).

The paper (Sec. 5.2, 6) names moving objects - flies, trees, clouds, vehicles - as what its
segmentation takes for gas. They also corrupt the velocity of the gas itself: a warm object
has far more contrast in the differential images than the faint gas, and the smoothness of
the joint disparity solver (Eq. 6) spreads the object's disparity over the whole image
(measured: an object at 8 m pulled the disparity of gas at 5.5 m from 42 to 29 px).

The site knows where the gas can be: between Z_near and Z_far, i.e. disparities in the band
[d_min, d_max] = [s b / Z_far, s b / Z_near] (the chain's ``d0`` and ``d0 +
sgm_num_disparities``). A wall, a tree or a vehicle behind the plume, or a fly in front of the
lens, lies outside the band. So before any solver runs:

1. semi-global matching (:func:`processing.stereo.sgm.sgbm_disparity`, uniqueness and
   left-right checks) of the two t0 differential images over a range wider than the band,
   around the pixels that can vote (step 2) only: nothing else needs a disparity;
2. a pixel is *out of band* when SGBM found a reliable disparity outside [d_min - tol,
   d_max + tol] and the pixel is active (its differential value stands out of the noise);
   columns left of d_min, where no gas has a partner in the right image, do not vote;
   connected regions take their votes' majority near the votes, and an object found so
   also takes the connected pixels that change nearly as much as it does (its edges seen
   through gas, whose disparities drift into the band);
3. its partner in the right image is x_R = x_L - d; both masks are dilated by the largest
   motion expected within a triple, so that the object's edges at t1 are covered too;
4. the masked pixels of all four differential images are set to "no change" (0.5): the
   flow, the disparity solver and the segmentation never see the object.

Static things out of band do not appear in differential images at all (unless jitter is
left over, which this removes as well). Something moving inside the band cannot be told
from gas by depth; it remains for the segmentation.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import cv2
import numpy as np

from processing.preprocess.differential import PreprocessedTriple
from processing.preprocess.gate_sgbm import coarse_sgbm
from processing.preprocess.order_statistics import mad_spread
from processing.validation import as_float_image, check_same_shape

#: Multiple of the robust noise spread above which a differential pixel counts as active.
ACTIVITY_SIGMAS = 4.0
#: ... and at least this far from "no change" (normalised units): SGBM quantises to 8 bits,
#: so fainter structure (the gas's thin edges) gives it nothing to match and it returns
#: spurious small disparities there.
ACTIVITY_FLOOR = 0.05
#: Half side of the window that averages out-of-band disparities for the right view's mask,
#: px, and the out-of-band votes a region needs to be an object (fewer are SGBM outliers).
VOTE_RADIUS = 7
MIN_VOTES = 12
#: An object's region needs this many times more out-of-band than in-band votes.
MAJORITY = 3.0
#: Largest standard deviation of the out-of-band disparities of one local vote, px.
LOCAL_SPREAD_PX = 4.0
#: Columns at the right border whose SGBM disparities are not used, px.
RIGHT_EDGE_PX = 12
#: A region taken for an object is removed within this distance of its out-of-band votes, px.
REGION_REACH_PX = 16
#: An object grows by its change only when its votes change this many times as much as
#: the in-band ones (:func:`grow_by_amplitude`).
GROW_CONTRAST = 1.25
#: Half side of the window of the local vote (:func:`_local_majority`), px.
LOCAL_RADIUS = 12


@dataclass(frozen=True)
class DepthGate:
    """Pixels removed by :func:`out_of_band_motion`.

    Attributes
    ----------
    left, right : ndarray, shape (H, W), bool
        Removed pixels of each view (dilated).
    fraction : float
        Share of the left image's pixels that were found out of band (before dilation).
    """

    left: np.ndarray
    right: np.ndarray
    fraction: float


def out_of_band_motion(
    left: np.ndarray,
    right: np.ndarray,
    *,
    d_min: float,
    d_max: float,
    tolerance_px: float = 3.0,
    dilate_px: int = 8,
    sgbm_downsample: int = 2,
    amplitude: np.ndarray | None = None,
    grow_fraction: float = 0.5,
) -> DepthGate:
    """Find moving image regions whose stereo disparity lies outside the gas's band.

    Parameters
    ----------
    left, right : ndarray, shape (H, W), float32
        Normalised differential images of the left and right camera at t0 (0.5 = no change).
    d_min, d_max : float
        Disparity band of the gas, px (x_R = x_L - d), 0 <= d_min < d_max.
    tolerance_px : float
        Margin around the band, px (SGBM's error and the gas's own depth spread).
    dilate_px : int
        Radius by which the masks grow: the largest image motion within a triple, px.
    sgbm_downsample : int
        1 or 2: semi-global matching on images reduced by this factor (Gaussian pyramid;
        images narrower than ``gate_sgbm.MIN_WIDTH_HALF_SGBM`` px stay at full resolution),
        its disparities scaled back up. SGBM's cost is pixels x disparities, so 2 makes it
        8x cheaper (it was 10 of the gate's 12 ms); the band's tolerance (3 px) is larger
        than the 2 px steps of the coarser disparity, and the votes, regions and masks stay
        at full resolution.
    amplitude : ndarray, shape (H, W), optional
        The left raw differential image at t0 (radiance units, unclipped): an object found
        by its votes then also takes the pixels connected to it whose change is at least
        ``grow_fraction`` of its own typical change (:func:`grow_by_amplitude`). None: votes
        alone.
    grow_fraction : float
        That share, in (0, 1]; 0 disables the growth.

    Returns
    -------
    DepthGate
    """
    il = as_float_image(left, "left")
    ir = as_float_image(right, "right")
    check_same_shape(il, ir, "left", "right")
    if not 0 <= d_min < d_max:
        raise ValueError(f"need 0 <= d_min < d_max, got {d_min}, {d_max}")
    h, w = il.shape
    hi = d_max + tolerance_px + 16.0
    n_disp = int(16 * np.ceil(hi / 16.0))
    n_disp = min(n_disp, 16 * ((w - 8) // 16))
    noise = mad_spread(il) + 1e-6  # of a mostly still image
    voting = np.abs(il - 0.5) > max(ACTIVITY_SIGMAS * noise, ACTIVITY_FLOOR)  # active
    # SGBM's blocks are cut by the right border, where it returns d ~ 0 on any texture
    # (measured: 1656 such votes in the last 10 columns as gas left the view, which the
    # local vote then removed as an object).
    # Left of column d_min no gas point has its partner inside the right image
    # (x_R = x_L - d < 0), so SGBM returns whatever else matches there, mostly small
    # disparities: gas leaving the view on the left was removed as an object (measured on
    # the wide robustness matrix's ideal condition: 4-15 % of the gas of three of 12 scenes
    # in most triples). An object farther than the gas keeps its votes right of it.
    voting[:, max(w - RIGHT_EDGE_PX, 0):] = False
    voting[:, :min(int(np.ceil(d_min)), w)] = False
    # Votes are a subset of these pixels: too few of them cannot make an object, and SGBM
    # need only match around them.
    if too_few_votes(voting):
        return _empty_gate(h, w)
    d, valid = coarse_sgbm(il, ir, n_disp, sgbm_downsample, _bounds(voting))
    measured = valid & voting
    outside = measured & ((d < d_min - tolerance_px) | (d > d_max + tolerance_px))
    # The regions, votes and masks below would only confirm that nothing is removed (the
    # common case: gas alone).
    if too_few_votes(outside):
        return _empty_gate(h, w)
    inside = measured & ~outside
    # SGBM finds reliable disparities only at part of an object's pixels: every connected
    # region of active pixels takes the verdict of the majority of its measured pixels.
    # (regions grown from a lower threshold, so an object's faint rims join its body)
    weak = np.abs(il - 0.5) > 0.4 * ACTIVITY_FLOOR
    near_active = cv2.dilate(weak.astype(np.uint8), np.ones((7, 7), np.uint8))
    n_labels, labels = cv2.connectedComponents(near_active, connectivity=8)
    out, reject = _verdict(outside, inside, d, labels, n_labels)
    if amplitude is not None and grow_fraction > 0:
        out = grow_by_amplitude(out, outside & out, inside, amplitude, grow_fraction)
    if not out.any():
        return _empty_gate(h, w)
    win = (2 * VOTE_RADIUS + 1, 2 * VOTE_RADIUS + 1)
    # Each removed pixel's partner in the right view, at the local out-of-band disparity.
    d_sum = cv2.boxFilter(np.where(outside, d, 0).astype(np.float32), -1, win,
                          normalize=False)
    n_near = cv2.boxFilter(outside.astype(np.float32), -1, win, normalize=False)
    # where no out-of-band disparity is near, the region's median stands in
    d_region = np.zeros(n_labels, np.float32)
    for lab in np.flatnonzero(reject):
        d_region[lab] = float(np.median(d[outside & (labels == lab)]))
    # ... and where neither is (pixels added by their amplitude), all objects' median.
    d_all = float(np.median(d[outside])) if outside.any() else 0.0
    d_region = np.where(reject, d_region, np.float32(d_all))
    d_local = np.where(n_near > 0, d_sum / np.maximum(n_near, 1.0), d_region[labels])
    ys, xs = np.nonzero(out)
    right_mask = np.zeros((h, w), np.uint8)
    xr = np.rint(xs - d_local[ys, xs]).astype(int)
    keep = (xr >= 0) & (xr < w)
    right_mask[ys[keep], xr[keep]] = 1
    return DepthGate(grown(out, int(dilate_px)), grown(right_mask, int(dilate_px)),
                     float(out.mean()))


def grown(mask: np.ndarray, radius_px: int) -> np.ndarray:
    """``mask`` (H, W, bool or 0/1) dilated by a disk of ``radius_px`` px, (H, W) bool."""
    k = 2 * radius_px + 1
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))
    return cv2.dilate(mask.astype(np.uint8), disk) > 0


def too_few_votes(outside: np.ndarray) -> bool:
    """Whether ``outside`` (H, W) bool has too few out-of-band votes for any object.

    An object needs ``MIN_VOTES`` votes in its region (:func:`_verdict`) or in its window
    (:func:`_local_majority`); with fewer in the whole image and in every window, nothing
    is removed. The windows matter near the border: their box sums count the votes
    mirrored there once more (9 votes in a corner made a 192 px object of a jittered
    scene).
    """
    return (np.count_nonzero(outside) < MIN_VOTES
            and float(_window_votes(outside).max()) < MIN_VOTES)


def _empty_gate(h: int, w: int) -> DepthGate:
    """A gate of an (H, W) view pair that removes nothing."""
    return DepthGate(np.zeros((h, w), bool), np.zeros((h, w), bool), 0.0)


def grow_by_amplitude(out: np.ndarray, seeds: np.ndarray, gas: np.ndarray,
                      amplitude: np.ndarray, fraction: float) -> np.ndarray:
    """``out`` with every connected region of strong change that touches it.

    Where an object passes behind gas, the gas in front changes what each camera sees of
    the object's edge differently, and SGBM's disparities there drift into the band
    (measured on the wide robustness matrix: 29.6-32 px for an object at 29.1 px, gas band
    from 32 px): a piece of the edge stays. Its change is the object's own, far above the
    gas's (Eq. 1: gas changes a pixel by (L_bg - L_g) dtau; an opaque object's edge by
    L_obj - L_bg; measured 4-10x the gas's largest change), so the regions of change of at
    least ``fraction`` of the object's typical (median) one that touch the object are the
    object too. Only for an object whose votes change at least ``GROW_CONTRAST`` times as
    much as the in-band ones (the gas's): SGBM on noisy faint gas also puts a few votes out
    of band, and growing from those took the whole plume (measured on the wide robustness
    matrix: 78 % of it under 0.03 K noise, where such votes changed 0.8-1.0x as much as the
    gas's; an object's votes 1.3-4.4x in 35 of 36 triples).

    Parameters
    ----------
    out : ndarray, shape (H, W), bool
        Pixels taken for objects by their votes.
    seeds : ndarray, shape (H, W), bool
        Their out-of-band votes, whose change is the objects'.
    gas : ndarray, shape (H, W), bool
        The in-band votes.
    amplitude : ndarray, shape (H, W), float
        Raw differential image, radiance (or count) units.
    fraction : float
        Share of the objects' median change a pixel needs, in (0, 1].

    Returns
    -------
    ndarray, shape (H, W), bool
    """
    if not seeds.any():
        return out
    a = np.abs(np.asarray(amplitude, np.float32))
    typical = float(np.median(a[seeds]))
    # No in-band votes: no gas to tell the object's change from, and none it could hide
    # behind; strong change then connects across a textured wall under jitter, and growing
    # took all of it (measured: 18845 of 19200 px of a gas-free scene).
    if not gas.any() or typical < GROW_CONTRAST * float(np.median(a[gas])):
        return out
    strong = (a >= fraction * typical).astype(np.uint8)
    n, labels = cv2.connectedComponents(strong, connectivity=8)
    touched = np.zeros(n, bool)
    touched[np.unique(labels[out & (strong > 0)])] = True
    touched[0] = False
    return out | touched[labels]


def _verdict(outside: np.ndarray, inside: np.ndarray, d: np.ndarray, labels: np.ndarray,
             n_labels: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixels taken for out-of-band objects, (H, W) bool, and the rejected region labels.

    A region of ``labels`` (connected active pixels, label 0 the still background) is an
    object when its out-of-band votes are at least ``MIN_VOTES`` and a clear ``MAJORITY``
    over its in-band ones: SGBM on noise (low contrast) scatters over the whole search range
    and would otherwise put about a third of a noise region out of band. Where an object
    touches the gas, :func:`_local_majority` decides.
    """
    n_out = np.bincount(labels[outside], minlength=n_labels)
    n_in = np.bincount(labels[inside], minlength=n_labels)
    reject = (n_out >= MIN_VOTES) & (n_out > MAJORITY * n_in)
    reject[0] = False
    # ... but only near its votes: an object behind faint gas joins it into one region
    # whose gas has no votes of its own (too faint to be active next to the object), and
    # the whole region went (measured: 25-35 % of a plume with the object at its edge).
    local = _local_majority(outside, inside, d, labels > 0)
    if not reject.any():  # no region to restrict (the dilation is the dearest step here)
        return local, reject
    near = grown(outside, REGION_REACH_PX)
    out = (reject[labels] & near) | local
    return out, reject


def _bounds(mask: np.ndarray) -> tuple[int, int, int, int]:
    """The bounding box (y0, y1, x0, x1; half-open) of a non-empty (H, W) bool mask."""
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    return int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1


def _local_majority(outside: np.ndarray, inside: np.ndarray, d: np.ndarray,
                    region: np.ndarray) -> np.ndarray:
    """Pixels of ``region`` where out-of-band votes win within ``LOCAL_RADIUS`` and agree
    on one disparity (spread below ``LOCAL_SPREAD_PX``).

    The region majority fails where an object touches the gas: both become one connected
    region and the gas's in-band votes outnumber the object's (measured on a field scene
    once the tracked scale had made the gas active: 4219 out of band against 6902 in band,
    the object stayed and every later triple was taken for a scene change). Locally the
    object's votes still win. SGBM on noise scatters over the whole search range and can
    win a window too (measured: 30 % of a faint, noisy plume removed); an object's votes
    lie at its one depth."""
    win = (2 * LOCAL_RADIUS + 1, 2 * LOCAL_RADIUS + 1)
    n_out = _window_votes(outside)
    n_in = _window_votes(inside)
    d_out = np.where(outside, d, 0).astype(np.float32)
    n = np.maximum(n_out, 1.0)
    mean = cv2.boxFilter(d_out, -1, win, normalize=False) / n
    var = cv2.boxFilter(d_out * d_out, -1, win, normalize=False) / n - mean * mean
    return (region & (n_out >= MIN_VOTES) & (n_out > MAJORITY * n_in)
            & (var < LOCAL_SPREAD_PX ** 2))


def _window_votes(votes: np.ndarray) -> np.ndarray:
    """Votes within ``LOCAL_RADIUS`` of each pixel, (H, W) float32, of a (H, W) bool mask
    (OpenCV's box sum: near the border the window also counts mirrored votes)."""
    win = (2 * LOCAL_RADIUS + 1, 2 * LOCAL_RADIUS + 1)
    return cv2.boxFilter(votes.astype(np.float32), -1, win, normalize=False)


def suppress(diff: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """A copy of a normalised differential image with ``mask`` set to "no change" (0.5)."""
    out = np.array(diff, dtype=np.float32, copy=True)
    out[mask] = 0.5
    return out


def apply_gate(pl: PreprocessedTriple, pr: PreprocessedTriple, gate: DepthGate
               ) -> tuple[PreprocessedTriple, PreprocessedTriple]:
    """Remove the gate's pixels from both views of a triple: "no change" in the normalised
    differences, 0 in the raw ones (so that no normalisation quantile sees them).

    A warm object has far more contrast than the gas; left in the raw differences, it
    would set the normalisation scale (0.999 quantile of |D|) and squeeze the gas into a
    few grey levels around 0.5 where the flow sees no signal. The chain takes a triple's
    own first scale again from the gated differences
    (:func:`processing.chain.compute_scene_flow`); a tracked scale is fed only gated ones.
    """
    def raw(a: np.ndarray, mask: np.ndarray) -> np.ndarray:
        return np.where(mask, np.float32(0), a)

    pl = dataclasses.replace(pl, diff0=suppress(pl.diff0, gate.left),
                             diff1=suppress(pl.diff1, gate.left),
                             raw0=raw(pl.raw0, gate.left), raw1=raw(pl.raw1, gate.left))
    pr = dataclasses.replace(pr, diff0=suppress(pr.diff0, gate.right),
                             diff1=suppress(pr.diff1, gate.right),
                             raw0=raw(pr.raw0, gate.right), raw1=raw(pr.raw1, gate.right))
    return pl, pr
