"""Accuracy metrics of a 3D gas velocity field against a synthetic reference (paper Sec. 5.1).

The paper's Eq. 10 and the sentences around it define, per frame:

- RMVE, the relative error of the magnitude of the mean velocity, in %;
- AEMV, the angle between the computed and the reference mean velocity, in degrees (the
  paper's text says "px", a typo: Table 3 gives degrees);
- 3D AEE, the mean endpoint error |V* - V| over the gas region, in m/s (Table 3 prints mm/s;
  multiply by 1000);
- 3D AAE, the mean angle between V* and V over the gas region, in degrees, with Eq. 10's
  absolute value |V* . V| (so the per-pixel angle lies in [0, 90] deg: a reversed vector
  counts as aligned; we keep the formula as printed so that our numbers compare with
  Table 3, and say so wherever the number is shown);
- r_SF,X/Y/Z, the correlation between the histograms of each component of V and of V*
  (50 bins over [0, max V*_c] per frame, see :func:`histogram_correlation`);
- SA, the ratio of the segmented gas region to the reference gas region, in %.

Beyond the paper, :func:`errors_of_sequence_mean` applies RMVE and AEMV to a sequence's mean
velocity (the mean of the frames' V_avg against the mean of their V*_avg): what a velocity
averaged over the sequence reads, as the appliance's leak events average theirs. A frame's
error that scatters both ways averages out of it; a bias does not.

Regions: the computed mean velocity is averaged over the segmented gas region where the
velocity is valid (``gas_mask & valid``); the reference mean over the reference gas mask.
The pixelwise metrics (AEE, AAE) run over the pixels where both are defined.

Undefined values (empty region, zero vector, degenerate histogram) are returned as ``None``,
never NaN: None cannot slip silently into an average, and the caller must count or flag it.
Every function is pure and checks shapes.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

#: Number of histogram bins of r_SF (paper Sec. 5.1).
HIST_BINS = 50


def _check_field(field: np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(field)
    if arr.ndim != 3 or arr.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (H, W, 3), got {arr.shape}")
    if not np.issubdtype(arr.dtype, np.floating):
        raise ValueError(f"{name} must have a floating-point dtype, got {arr.dtype}")
    return arr.astype(np.float64)


def _check_mask(mask: np.ndarray, shape: tuple[int, ...], name: str) -> np.ndarray:
    m = np.asarray(mask)
    if m.dtype != np.bool_:
        raise ValueError(f"{name} must be a boolean array, got {m.dtype}")
    if m.shape != tuple(shape):
        raise ValueError(f"{name} has shape {m.shape}, expected {tuple(shape)}")
    return m


def _check_vector(vec: np.ndarray | None, name: str) -> np.ndarray | None:
    if vec is None:
        return None
    v = np.asarray(vec, dtype=np.float64)
    if v.shape != (3,):
        raise ValueError(f"{name} must be a 3-vector, got shape {v.shape}")
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be finite, got {v}")
    return v


def mean_velocity(velocity: np.ndarray, region: np.ndarray) -> np.ndarray | None:
    """Mean 3D velocity V_avg over a region (Eq. 10's V_avg and V*_avg).

    Parameters
    ----------
    velocity : ndarray, shape (H, W, 3), floating point
        V (or V*) in m/s.
    region : ndarray, shape (H, W), bool
        Pixels to average: ``gas_mask & valid`` for the computed field, the reference gas
        mask for V*. Pixels with a non-finite vector inside the region are an error.

    Returns
    -------
    ndarray, shape (3,), float64, or None
        Mean (V_X, V_Y, V_Z) in m/s; None when the region is empty.

    Raises
    ------
    ValueError
        Wrong shapes/dtypes, or NaN/inf inside the region.
    """
    v = _check_field(velocity, "velocity")
    m = _check_mask(region, v.shape[:2], "region")
    if not m.any():
        return None
    vals = v[m]
    if not np.all(np.isfinite(vals)):
        raise ValueError("velocity is not finite inside the region")
    return vals.mean(axis=0)


def rmve(reference_mean: np.ndarray | None, computed_mean: np.ndarray | None) -> float | None:
    """Relative mean velocity error RMVE of Eq. 10, in %.

    RMVE = 100 % * | (|V*_avg| - |V_avg|) / |V*_avg| |

    Parameters
    ----------
    reference_mean, computed_mean : array-like of 3 floats, or None
        V*_avg and V_avg in m/s (from :func:`mean_velocity`).

    Returns
    -------
    float or None
        >= 0; None when either mean is None or |V*_avg| = 0 (no relative error exists).
    """
    ref = _check_vector(reference_mean, "reference_mean")
    got = _check_vector(computed_mean, "computed_mean")
    if ref is None or got is None:
        return None
    nref = float(np.linalg.norm(ref))
    if nref == 0.0:
        return None
    return 100.0 * abs((nref - float(np.linalg.norm(got))) / nref)


def _angle_deg(cos: np.ndarray | float) -> np.ndarray | float:
    # Rounding can push |cos| a hair above 1; arccos would then return NaN.
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def aemv(reference_mean: np.ndarray | None, computed_mean: np.ndarray | None) -> float | None:
    """Angular error of the mean velocity AEMV of Eq. 10, in degrees.

    AEMV = arccos( V*_avg . V_avg / (|V*_avg| |V_avg|) ), in [0, 180].

    Returns
    -------
    float or None
        None when either mean is None or has zero length (no direction).
    """
    ref = _check_vector(reference_mean, "reference_mean")
    got = _check_vector(computed_mean, "computed_mean")
    if ref is None or got is None:
        return None
    n = float(np.linalg.norm(ref)) * float(np.linalg.norm(got))
    if n == 0.0:
        return None
    return float(_angle_deg(float(ref @ got) / n))


def errors_of_sequence_mean(computed_means: Sequence[Sequence[float] | np.ndarray | None],
                            reference_means: Sequence[Sequence[float] | np.ndarray | None]
                            ) -> tuple[float | None, float | None]:
    """RMVE (%) and AEMV (deg) of Eq. 10 on a sequence's mean velocity.

    Parameters
    ----------
    computed_means, reference_means : sequences of array-like of 3 floats, or None
        Per frame V_avg and V*_avg in m/s (:func:`mean_velocity`), in the same order; the
        frames where either is None are left out of both means.

    Returns
    -------
    (float or None, float or None)
        :func:`rmve` and :func:`aemv` of the mean of the V_avg against the mean of the
        V*_avg; None when no frame has both.
    """
    if len(computed_means) != len(reference_means):
        raise ValueError(f"need one reference mean per computed mean, got "
                         f"{len(computed_means)} and {len(reference_means)}")
    both = [(_check_vector(c, "computed_means"), _check_vector(r, "reference_means"))
            for c, r in zip(computed_means, reference_means, strict=True)]
    both = [(c, r) for c, r in both if c is not None and r is not None]
    if not both:
        return None, None
    got = np.mean([c for c, _ in both], axis=0)
    ref = np.mean([r for _, r in both], axis=0)
    return rmve(ref, got), aemv(ref, got)


def _pair_region(reference: np.ndarray, computed: np.ndarray,
                 region: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    ref = _check_field(reference, "reference")
    got = _check_field(computed, "computed")
    if ref.shape != got.shape:
        raise ValueError(f"reference {ref.shape} and computed {got.shape} differ in shape")
    m = _check_mask(region, ref.shape[:2], "region")
    if not m.any():
        return None
    a, b = ref[m], got[m]
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise ValueError("reference or computed velocity is not finite inside the region")
    return a, b


def aee_3d(reference: np.ndarray, computed: np.ndarray, region: np.ndarray) -> float | None:
    """3D average endpoint error of Eq. 10: mean |V* - V| over the region, in m/s.

    Parameters
    ----------
    reference, computed : ndarray, shape (H, W, 3), floating point
        V* and V in m/s.
    region : ndarray, shape (H, W), bool
        Omega_g of Eq. 10: pixels where both fields are defined (the evaluation uses the
        segmented gas region & valid velocity & reference gas mask).

    Returns
    -------
    float or None
        In m/s (Table 3 prints mm/s); None for an empty region.
    """
    pair = _pair_region(reference, computed, region)
    if pair is None:
        return None
    a, b = pair
    return float(np.linalg.norm(a - b, axis=-1).mean())


def aae_3d(reference: np.ndarray, computed: np.ndarray, region: np.ndarray) -> float | None:
    """3D average angular error of Eq. 10 as printed, in degrees.

    AAE = mean over the region of arccos( |V* . V| / (|V*| |V|) ), each angle in [0, 90].
    The absolute value is the paper's; it folds a reversed vector onto an aligned one.
    Pixels where |V*| or |V| is 0 have no direction and are left out of the mean.

    Returns
    -------
    float or None
        Degrees; None when no pixel of the region has two non-zero vectors.
    """
    pair = _pair_region(reference, computed, region)
    if pair is None:
        return None
    a, b = pair
    n = np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1)
    ok = n > 0
    if not ok.any():
        return None
    cos = np.abs(np.einsum("ij,ij->i", a[ok], b[ok])) / n[ok]
    return float(np.mean(_angle_deg(cos)))


def histogram_correlation(reference_values: np.ndarray, computed_values: np.ndarray,
                          *, bins: int = HIST_BINS) -> float | None:
    """Correlation r_SF between the histograms of one velocity component (Sec. 5.1).

    The paper sets the histogram range to [0, max(V*_c)] with 50 bins per frame. Taken
    literally, a range starting at 0 drops every negative value - for V_Y of rising gas
    (Y points down) nearly all of them. We read the range as one of component
    *magnitudes*: both histograms count |V_c| over [0, max |V*_c|] (for a component that
    is non-negative this is exactly the paper's range). Computed values above the range are
    not counted (a histogram with a fixed range, as numpy and MATLAB's BinLimits do).
    r is Pearson's correlation coefficient between the two vectors of bin counts.

    Parameters
    ----------
    reference_values, computed_values : ndarray, 1-D, floating point
        The component c of V* over the reference gas region and of V over the computed gas
        region (m/s; the two may have different lengths).
    bins : int
        Number of bins (50 in the paper).

    Returns
    -------
    float or None
        r in [-1, 1]. None - a flag, never NaN - when it is undefined: an empty input,
        max |V*_c| = 0 (no range), or a histogram with all bins equal (zero variance, e.g.
        all computed values outside the range).

    Raises
    ------
    ValueError
        Non-1-D input, non-finite values, bins < 2.
    """
    if bins < 2:
        raise ValueError(f"bins must be >= 2, got {bins}")
    ref = np.asarray(reference_values, dtype=np.float64)
    got = np.asarray(computed_values, dtype=np.float64)
    for arr, name in ((ref, "reference_values"), (got, "computed_values")):
        if arr.ndim != 1:
            raise ValueError(f"{name} must be 1-D, got shape {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} contains NaN or infinite values")
    if ref.size == 0 or got.size == 0:
        return None
    top = float(np.abs(ref).max())
    if top == 0.0:
        return None
    h_ref, _ = np.histogram(np.abs(ref), bins=bins, range=(0.0, top))
    h_got, _ = np.histogram(np.abs(got), bins=bins, range=(0.0, top))
    a = h_ref - h_ref.mean()
    b = h_got - h_got.mean()
    den = float(np.sqrt((a * a).sum() * (b * b).sum()))
    if den == 0.0:
        return None
    return float(np.clip((a * b).sum() / den, -1.0, 1.0))


def histogram_correlations(reference: np.ndarray, reference_region: np.ndarray,
                           computed: np.ndarray, computed_region: np.ndarray,
                           *, bins: int = HIST_BINS) -> tuple[float | None, ...]:
    """(r_SF,X, r_SF,Y, r_SF,Z) of one frame: :func:`histogram_correlation` per component.

    Parameters
    ----------
    reference, computed : ndarray, shape (H, W, 3), floating point
        V* and V in m/s.
    reference_region, computed_region : ndarray, shape (H, W), bool
        Reference gas mask; segmented gas region & valid velocity.
    """
    ref = _check_field(reference, "reference")
    got = _check_field(computed, "computed")
    rm = _check_mask(reference_region, ref.shape[:2], "reference_region")
    cm = _check_mask(computed_region, got.shape[:2], "computed_region")
    return tuple(histogram_correlation(ref[rm][:, c], got[cm][:, c], bins=bins)
                 for c in range(3))


def segmentation_ratio(segmented: np.ndarray, reference: np.ndarray) -> float | None:
    """SA of Sec. 5.1: segmented gas region over reference gas region, 100 % |Omega_g| / |Omega*|.

    This is the paper's ratio of areas; it does not check that the regions overlap (a
    segmentation of the wrong place with the right size scores 100 %), so the evaluation
    also reports :func:`segmentation_overlap`.

    Returns
    -------
    float or None
        In %, >= 0 (above 100 when the segmentation is larger); None when the reference
        region is empty.
    """
    return _share_of_reference(segmented, reference, overlap_only=False)


def segmentation_overlap(segmented: np.ndarray, reference: np.ndarray) -> float | None:
    """Share of the reference gas region that the segmentation covers, in % (not in the paper).

    100 % |Omega_g ∩ Omega*| / |Omega*|; None when the reference region is empty.
    """
    return _share_of_reference(segmented, reference, overlap_only=True)


def _share_of_reference(segmented: np.ndarray, reference: np.ndarray, *,
                        overlap_only: bool) -> float | None:
    """100 % |Omega_g| / |Omega*| (or |Omega_g ∩ Omega*| / |Omega*|); None for an empty
    reference."""
    seg = np.asarray(segmented)
    ref = _check_mask(reference, seg.shape, "reference")
    seg = _check_mask(seg, ref.shape, "segmented")
    n_ref = int(np.count_nonzero(ref))
    if n_ref == 0:
        return None
    return 100.0 * int(np.count_nonzero(seg & ref if overlap_only else seg)) / n_ref
