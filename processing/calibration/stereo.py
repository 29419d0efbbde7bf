"""Geometric calibration of the stereo pair from views of a planar target.

Steps (Zhang's method as implemented by OpenCV):

1. detect the target in every left and right image (:mod:`.pattern`), keep the views where
   both cameras see it and number the points the same way in both;
2. calibrate each camera alone (``cv2.calibrateCamera``);
3. calibrate the pair with the intrinsics fixed (``cv2.stereoCalibrate`` with
   ``CALIB_FIX_INTRINSIC``), giving R, T and the RMS reprojection error of every view;
4. drop the worst view while it is an outlier (RMS above ``median + k * 1.4826 * MAD`` of
   all views and above ``outlier_floor_px``), recalibrating after each drop;
5. refine everything jointly (``cv2.stereoCalibrate`` with ``CALIB_USE_INTRINSIC_GUESS``)
   and rectify (:func:`.rectify.stereo_rectification`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from processing.calibration.errors import (
    ImageSizeError,
    PatternNotFoundError,
    PoorCalibrationError,
    TooFewViewsError,
)
from processing.calibration.model import StereoCalibration
from processing.calibration.pattern import (
    PatternSpec,
    detect_pattern,
    is_point_symmetric,
    object_points,
    orient_like,
)
from processing.calibration.rectify import stereo_rectification

#: Fewest stereo views a calibration is computed from (after dropping outliers).
DEFAULT_MIN_VIEWS = 6

_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)


@dataclass(frozen=True)
class ViewReport:
    """Outcome for one stereo view (one left/right image pair).

    Attributes
    ----------
    name : str
        The view's name (the image file name).
    rms_left_px, rms_right_px : float
        RMS reprojection error of the view in each camera, pixels: from the final
        calibration for kept views, at the time of dropping for dropped ones.
    kept : bool
        Whether the view contributes to the calibration.
    reason : str
        Why it was dropped ("" when kept).
    """

    name: str
    rms_left_px: float
    rms_right_px: float
    kept: bool
    reason: str = ""

    @property
    def rms_px(self) -> float:
        """RMS over both cameras, pixels."""
        return float(np.sqrt(0.5 * (self.rms_left_px**2 + self.rms_right_px**2)))


@dataclass(frozen=True)
class StereoCalibrationResult:
    """A calibration and the account of how it was obtained.

    Attributes
    ----------
    calibration : StereoCalibration
    views : list of ViewReport
        Every view where both cameras saw the target, kept or dropped.
    not_found : list of str
        Views skipped because the target was not found, e.g. ``"img07.png (right)"``.
    rms_left_px, rms_right_px : float
        Single-camera calibration RMS over the kept views, pixels.
    """

    calibration: StereoCalibration
    views: list[ViewReport]
    not_found: list[str] = field(default_factory=list)
    rms_left_px: float = 0.0
    rms_right_px: float = 0.0

    @property
    def dropped(self) -> list[ViewReport]:
        """Views dropped as outliers."""
        return [v for v in self.views if not v.kept]


@dataclass(frozen=True)
class _Fit:
    K1: np.ndarray
    D1: np.ndarray
    K2: np.ndarray
    D2: np.ndarray
    R: np.ndarray
    T: np.ndarray
    rms: float
    per_view: np.ndarray  # (n, 2) RMS per view, left and right
    rms_left: float
    rms_right: float


def _single_flags(fix_k3: bool) -> int:
    return cv2.CALIB_FIX_K3 if fix_k3 else 0


def _fit(
    obj: list[np.ndarray],
    left: list[np.ndarray],
    right: list[np.ndarray],
    image_size: tuple[int, int],
    fix_k3: bool,
    joint: bool,
) -> _Fit:
    flags = _single_flags(fix_k3)
    rms_l, K1, D1, *_ = cv2.calibrateCameraExtended(
        obj, left, image_size, None, None, flags=flags, criteria=_CRITERIA)
    rms_r, K2, D2, *_ = cv2.calibrateCameraExtended(
        obj, right, image_size, None, None, flags=flags, criteria=_CRITERIA)
    stereo_flags = (cv2.CALIB_USE_INTRINSIC_GUESS if joint else cv2.CALIB_FIX_INTRINSIC) | flags
    rms, K1, D1, K2, D2, R, T, _, _, _, _, per_view = cv2.stereoCalibrateExtended(
        obj, left, right, K1, D1, K2, D2, image_size, None, None,
        flags=stereo_flags, criteria=_CRITERIA)
    return _Fit(K1, D1.ravel(), K2, D2.ravel(), R, T.ravel(), float(rms),
                np.asarray(per_view, np.float64).reshape(-1, 2), float(rms_l), float(rms_r))


def outlier_threshold(rms: np.ndarray, k: float, floor_px: float) -> float:
    """``max(floor_px, median + k * 1.4826 * MAD)`` of per-view RMS values (pixels).

    The 1.4826 makes the MAD a standard-deviation estimate for Gaussian scatter; the floor
    keeps a set of uniformly good views (all ~0.1 px) from losing its slightly worse half.
    """
    med = float(np.median(rms))
    mad = float(np.median(np.abs(rms - med)))
    return max(float(floor_px), med + k * 1.4826 * mad)


def calibrate_stereo_points(
    spec: PatternSpec,
    names: Sequence[str],
    left_points: Sequence[np.ndarray],
    right_points: Sequence[np.ndarray],
    image_size: tuple[int, int],
    *,
    outlier_k: float = 3.0,
    outlier_floor_px: float = 0.5,
    min_views: int = DEFAULT_MIN_VIEWS,
    fix_k3: bool = True,
    joint_refine: bool = True,
    alpha: float = 0.0,
    not_found: Sequence[str] = (),
    max_rms_px: float = 1.0,
) -> StereoCalibrationResult:
    """Calibrate the pair from detected target points (steps 2-5 of the module doc).

    Parameters
    ----------
    spec : PatternSpec
        Target geometry (gives the 3D points and the scale: T comes out in metres).
    names : sequence of str, length N
        View names, used in reports and errors.
    left_points, right_points : sequence of numpy.ndarray, each shape (P, 2), float32
        Detected points in each camera, same numbering in both.
    image_size : (width, height)
        Pixels.
    outlier_k, outlier_floor_px : float
        Outlier rule, see :func:`outlier_threshold`.
    min_views : int
        Fewest views to calibrate from.
    fix_k3 : bool
        Keep the 6th-order radial term k3 at zero (a 320x240 lens seen in ~15 views does not
        constrain it; freeing it trades bias for variance).
    joint_refine : bool
        Final joint refinement of intrinsics and extrinsics (otherwise intrinsics stay as
        calibrated per camera).
    alpha : float
        Rectification free scaling, see :func:`.rectify.stereo_rectification`.
    not_found : sequence of str
        Views skipped before (recorded in the result and in errors).
    max_rms_px : float
        Refuse a calibration whose final stereo RMS exceeds this (pixels): many views that
        are all equally bad (wrong spacing, blurred, moving target) escape the outlier rule.

    Returns
    -------
    StereoCalibrationResult

    Raises
    ------
    TooFewViewsError
        Fewer than ``min_views`` views, before or after dropping outliers.
    PoorCalibrationError
        Final RMS above ``max_rms_px``.
    """
    if not len(names) == len(left_points) == len(right_points):
        raise ValueError("names, left_points and right_points must have the same length")
    if len(names) < min_views:
        raise TooFewViewsError(_too_few_message(len(names), min_views, not_found))
    obj_one = object_points(spec)
    live, dropped, obj, lp, rp, fit = _drop_outlier_views(
        obj_one, names, left_points, right_points, image_size, fix_k3=fix_k3,
        outlier_k=outlier_k, outlier_floor_px=outlier_floor_px, min_views=min_views,
        not_found=not_found)
    if joint_refine:
        # Measured on 8 rendered chessboard sets (14 views, 320x240): worst focal-length
        # error 0.28-1.04 % with the per-camera intrinsics kept, 0.02-0.39 % after the joint
        # refinement (both cameras' views then constrain each intrinsic set).
        fit = _fit(obj, lp, rp, image_size, fix_k3, joint=True)
    if not fit.rms <= max_rms_px:
        raise PoorCalibrationError(
            f"stereo reprojection RMS {fit.rms:.2f} px over views "
            f"{', '.join(names[i] for i in live)} exceeds {max_rms_px:.2f} px: check the "
            "pattern spacing, focus and that the target did not move between the left and "
            "right frames")
    meta = {
        "pattern": {"kind": spec.kind, "rows": spec.rows, "cols": spec.cols,
                    "spacing_m": spec.spacing_m},
        "views_used": [names[i] for i in live],
        "views_dropped": [names[i] for i in sorted(dropped)],
        "views_without_pattern": list(not_found),
        "rms_left_px": fit.rms_left,
        "rms_right_px": fit.rms_right,
        "fix_k3": fix_k3,
        "joint_refine": joint_refine,
    }
    calib = stereo_rectification(fit.K1, fit.D1, fit.K2, fit.D2, fit.R, fit.T, image_size,
                                 alpha=alpha, rms_px=fit.rms, meta=meta)
    return StereoCalibrationResult(calib, _view_reports(names, live, dropped, fit),
                                   list(not_found), fit.rms_left, fit.rms_right)


def _drop_outlier_views(
    obj_one: np.ndarray, names: Sequence[str], left_points: Sequence[np.ndarray],
    right_points: Sequence[np.ndarray], image_size: tuple[int, int], *, fix_k3: bool,
    outlier_k: float, outlier_floor_px: float, min_views: int, not_found: Sequence[str],
) -> tuple[list[int], dict[int, tuple[float, float, str]], list[np.ndarray],
           list[np.ndarray], list[np.ndarray], _Fit]:
    """Fit per camera and drop the worst view while it is an outlier (step 4).

    Returns the kept view indices, the dropped ones (left RMS, right RMS, reason), the
    object, left and right points of the kept views as OpenCV wants them, and their fit.
    """
    live = list(range(len(names)))
    dropped: dict[int, tuple[float, float, str]] = {}
    while True:
        obj = [obj_one] * len(live)
        lp = [np.asarray(left_points[i], np.float32).reshape(-1, 1, 2) for i in live]
        rp = [np.asarray(right_points[i], np.float32).reshape(-1, 1, 2) for i in live]
        fit = _fit(obj, lp, rp, image_size, fix_k3, joint=False)
        view_rms = np.sqrt(0.5 * (fit.per_view**2).sum(axis=1))
        limit = outlier_threshold(view_rms, outlier_k, outlier_floor_px)
        worst = int(np.argmax(view_rms))
        if view_rms[worst] <= limit:
            return live, dropped, obj, lp, rp, fit
        if len(live) - 1 < min_views:
            bad = [names[live[j]] for j in np.flatnonzero(view_rms > limit)]
            raise TooFewViewsError(
                f"views {', '.join(bad)} reproject with RMS above {limit:.2f} px but dropping "
                f"them leaves fewer than {min_views} views; take more views"
                + (f" (target not found in: {', '.join(not_found)})" if not_found else ""))
        dropped[live[worst]] = (float(fit.per_view[worst, 0]), float(fit.per_view[worst, 1]),
                                f"RMS {view_rms[worst]:.2f} px > limit {limit:.2f} px")
        del live[worst]


def _view_reports(names: Sequence[str], live: list[int],
                  dropped: dict[int, tuple[float, float, str]], fit: _Fit) -> list[ViewReport]:
    """One report per view, kept (with the final fit's RMS) or dropped (with why)."""
    reports = []
    for i, name in enumerate(names):
        if i in dropped:
            rl, rr, why = dropped[i]
            reports.append(ViewReport(name, rl, rr, kept=False, reason=why))
        else:
            j = live.index(i)
            reports.append(ViewReport(name, float(fit.per_view[j, 0]),
                                      float(fit.per_view[j, 1]), kept=True))
    return reports


def _too_few_message(n: int, min_views: int, not_found: Sequence[str]) -> str:
    msg = f"only {n} usable stereo view(s), at least {min_views} needed"
    if not_found:
        msg += f"; target not found in: {', '.join(not_found)}"
    return msg


def calibrate_stereo_images(
    spec: PatternSpec,
    views: Sequence[tuple[str, np.ndarray, np.ndarray]],
    *,
    on_view: Callable[[str, str | None, str | None], None] | None = None,
    **kwargs: object,
) -> StereoCalibrationResult:
    """Detect the target in every image pair and calibrate (all steps of the module doc).

    Parameters
    ----------
    spec : PatternSpec
        Target geometry.
    views : sequence of (name, left, right)
        Image pairs, each image shape (H, W), uint8/uint16/float; all of one size.
    on_view : callable, optional
        Called after each pair's detection with (name, left variant, right variant); a
        variant names the contrast variant that showed the target (e.g.
        ``"stretch-inverted"``) or is None when the target was not found. For progress
        reports: detection takes up to ~1 s per image when the target is absent.
    **kwargs
        Passed to :func:`calibrate_stereo_points`.

    Raises
    ------
    ImageSizeError
        Images of different sizes (the offending names are given).
    PatternNotFoundError
        The target is in no image at all.
    TooFewViewsError
        Fewer than ``min_views`` pairs show the target in both images.
    """
    if not views:
        raise TooFewViewsError("no stereo views given")
    size_of: dict[tuple[int, int], list[str]] = {}
    for name, left, right in views:
        for side, img in (("left", left), ("right", right)):
            h, w = np.asarray(img).shape[:2]
            size_of.setdefault((w, h), []).append(f"{name} ({side})")
    if len(size_of) > 1:
        detail = "; ".join(f"{w}x{h}: {', '.join(v[:6])}{' ...' if len(v) > 6 else ''}"
                           for (w, h), v in sorted(size_of.items(), key=lambda kv: -len(kv[1])))
        raise ImageSizeError(f"calibration images differ in size: {detail}")
    image_size = next(iter(size_of))
    names: list[str] = []
    lpts: list[np.ndarray] = []
    rpts: list[np.ndarray] = []
    not_found: list[str] = []
    seen_any = False
    for name, left, right in views:
        dl = detect_pattern(left, spec)
        dr = detect_pattern(right, spec)
        seen_any |= dl is not None or dr is not None
        if on_view is not None:
            on_view(name, dl[1] if dl else None, dr[1] if dr else None)
        if dl is None or dr is None:
            sides = [s for s, d in (("left", dl), ("right", dr)) if d is None]
            not_found.append(f"{name} ({' and '.join(sides)})")
            continue
        pl, pr = dl[0], dr[0]
        if is_point_symmetric(spec):
            pr = orient_like(pl, pr)
        names.append(name)
        lpts.append(pl)
        rpts.append(pr)
    if not seen_any:
        raise PatternNotFoundError(
            f"the {spec.kind} target ({_describe(spec)}) was found in none of the "
            f"{2 * len(views)} images (both polarities and local contrast equalisation "
            "tried); check --pattern, --rows and --cols")
    return calibrate_stereo_points(spec, names, lpts, rpts, image_size,
                                   not_found=not_found, **kwargs)  # type: ignore[arg-type]


def _describe(spec: PatternSpec) -> str:
    what = "inner corners" if spec.kind == "chessboard" else "circles"
    return f"{spec.rows} rows x {spec.cols} cols of {what}"
