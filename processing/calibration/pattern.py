"""Detection of calibration patterns in 8- or 16-bit infrared images.

A heated calibration target seen by a 3.2-3.4 um OGI camera has low, uneven contrast (the
heater warms the centre more than the rim, the background radiates too), 16-bit raw counts
of which only a few hundred are used, and a polarity that depends on the target: a printed
chessboard on a heated plate shows its black (high-emissivity) squares *bright*, a cut-out
circle grid in front of a warm plate shows hot circles on a cold background or the reverse.
The detector therefore

1. maps the counts to 8 bit by a robust percentile stretch (:func:`to_gray8`),
2. tries the stretched image, a CLAHE-equalised version (local contrast) and both of their
   inverses (:func:`candidate_images`),
3. runs OpenCV's detector for the pattern kind on each candidate until one succeeds, and
4. refines chessboard corners to sub-pixel accuracy.

Pattern geometry follows OpenCV: for a chessboard, ``rows`` x ``cols`` count *inner corners*
(where four squares meet), not squares; for circle grids they count circles. For the
asymmetric grid, ``cols`` counts the circles in one row and ``spacing`` is the distance
between neighbouring circles in a row divided by two (OpenCV's convention: the circle at
grid position (i, j) sits at ((2 j + i mod 2) * spacing, i * spacing)).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

PatternKind = Literal["chessboard", "circles", "acircles"]
PATTERN_KINDS: tuple[str, ...] = ("chessboard", "circles", "acircles")


@dataclass(frozen=True)
class PatternSpec:
    """Geometry of a planar calibration target.

    Parameters
    ----------
    kind : {"chessboard", "circles", "acircles"}
        Chessboard, symmetric circle grid or asymmetric circle grid.
    rows, cols : int
        Chessboard: inner corners per column and per row (OpenCV's convention; a board of
        10 x 7 squares has 9 x 6 inner corners). Circle grids: circles per column and per row.
    spacing_m : float
        Chessboard: square side; symmetric circles: centre distance; asymmetric circles: half
        the centre distance within a row (OpenCV's convention). Metres.
    """

    kind: PatternKind
    rows: int
    cols: int
    spacing_m: float

    def __post_init__(self) -> None:
        if self.kind not in PATTERN_KINDS:
            raise ValueError(f"pattern kind {self.kind!r} is not one of {', '.join(PATTERN_KINDS)}")
        if self.rows < 2 or self.cols < 2:
            raise ValueError(f"pattern needs at least 2 x 2 points, got rows={self.rows} "
                             f"cols={self.cols}")
        if self.kind == "chessboard" and self.rows < 3 and self.cols < 3:
            raise ValueError("a chessboard needs at least 3 inner corners along one side")
        if self.kind == "acircles" and self.rows % 2 == 0:
            # Measured: with an even row count OpenCV may number the grid in a mirrored
            # order, which no camera pose can explain and which ruins the calibration.
            raise ValueError(f"an asymmetric circle grid needs an odd number of rows "
                             f"(e.g. OpenCV's 4 x 11 board: cols=4, rows=11), got rows={self.rows}")
        if not np.isfinite(self.spacing_m) or self.spacing_m <= 0:
            raise ValueError(f"pattern spacing must be positive, got {self.spacing_m} m")

    @property
    def pattern_size(self) -> tuple[int, int]:
        """OpenCV's ``patternSize`` = (points per row, points per column)."""
        return (self.cols, self.rows)

    @property
    def n_points(self) -> int:
        """Number of detected points per view."""
        return self.rows * self.cols


def object_points(spec: PatternSpec) -> np.ndarray:
    """Pattern points in the target's own frame, in OpenCV's detection order.

    Parameters
    ----------
    spec : PatternSpec
        Target geometry.

    Returns
    -------
    numpy.ndarray, shape (rows * cols, 3), float32
        (X, Y, 0) in metres; row-major (X runs along a row, i.e. over ``cols``).
    """
    i, j = np.meshgrid(np.arange(spec.rows), np.arange(spec.cols), indexing="ij")
    if spec.kind == "acircles":
        x = (2 * j + i % 2) * spec.spacing_m
    else:
        x = j * spec.spacing_m
    y = i * spec.spacing_m
    pts = np.stack([x.ravel(), y.ravel(), np.zeros(spec.n_points)], axis=1)
    return pts.astype(np.float32)


def to_gray8(image: np.ndarray, low_pct: float = 0.5, high_pct: float = 99.5) -> np.ndarray:
    """Map an IR frame of any integer or float dtype to 8 bit by a percentile stretch.

    A min/max stretch would let a few hot or dead pixels squeeze the target into a handful of
    grey levels; percentiles ignore them.

    Parameters
    ----------
    image : numpy.ndarray, shape (H, W) or (H, W, 3)
        Raw counts (uint8, uint16, any float). Colour images are converted to grey.
    low_pct, high_pct : float
        Percentiles mapped to 0 and 255.

    Returns
    -------
    numpy.ndarray, shape (H, W), uint8
    """
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] in (3, 4):
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    if img.ndim != 2:
        raise ValueError(f"expected a single-channel image (H, W), got shape {img.shape}")
    data = img.astype(np.float64)
    finite = np.isfinite(data)
    if not finite.any():
        raise ValueError("image has no finite pixel")
    lo, hi = np.percentile(data[finite], [low_pct, high_pct])
    if hi <= lo:
        return np.zeros(img.shape, np.uint8)
    out = (np.where(finite, data, lo) - lo) * (255.0 / (hi - lo))
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def candidate_images(gray8: np.ndarray) -> Iterator[tuple[str, np.ndarray]]:
    """Yield the contrast variants tried in turn: stretched, CLAHE, then their inverses.

    CLAHE on tiles of about 1/4 of the image evens out the radial temperature fall-off of a
    heated plate without amplifying pixel noise much (clip limit 3).
    """
    clahe = cv2.createCLAHE(clipLimit=3.0, tileGridSize=(4, 4)).apply(gray8)
    yield "stretch", gray8
    yield "clahe", clahe
    yield "stretch-inverted", 255 - gray8
    yield "clahe-inverted", 255 - clahe


def _blob_detector(image_shape: tuple[int, int], spec: PatternSpec) -> cv2.SimpleBlobDetector:
    """A dark-blob detector sized for circles that fill part of a small IR frame."""
    params = cv2.SimpleBlobDetector_Params()
    params.blobColor = 0  # dark circles; bright ones are found in the inverted candidate
    params.filterByArea = True
    params.minArea = 10.0  # circles need >= ~4 px diameter; smaller areas are noise blobs
    params.maxArea = float(image_shape[0] * image_shape[1]) / max(spec.n_points, 1)
    params.filterByCircularity = True
    params.minCircularity = 0.5  # circles seen at up to ~60 deg tilt are ellipses
    params.filterByConvexity = True
    params.minConvexity = 0.8
    params.filterByInertia = True
    params.minInertiaRatio = 0.2
    # The default (10 px) merges neighbouring circles of a small or tilted grid.
    params.minDistBetweenBlobs = 2.0
    params.minThreshold = 10
    params.maxThreshold = 245
    params.thresholdStep = 10
    return cv2.SimpleBlobDetector_create(params)


def _subpix_window(corners: np.ndarray, spec: PatternSpec) -> int:
    """Half-size of the cornerSubPix window: half the median corner spacing, 2-6 px.

    A window reaching the next corner pulls the estimate towards it; one smaller than the
    blur averages too little noise.
    """
    grid = corners.reshape(spec.rows, spec.cols, 2)
    d_row = np.median(np.linalg.norm(np.diff(grid, axis=1), axis=2))
    d_col = np.median(np.linalg.norm(np.diff(grid, axis=0), axis=2))
    return int(np.clip(0.5 * min(d_row, d_col), 2, 6))


def _refine_corners(img: np.ndarray, corners: np.ndarray, spec: PatternSpec) -> np.ndarray:
    corners = np.ascontiguousarray(corners, np.float32).reshape(-1, 1, 2)
    win = _subpix_window(corners, spec)
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4)
    return cv2.cornerSubPix(img, corners, (win, win), (-1, -1), criteria)


def _find_chessboard(img: np.ndarray, spec: PatternSpec, *, use_sb: bool = True
                     ) -> np.ndarray | None:
    # Measured on 28 rendered IR views (320x240, squares of 10-20 px, both polarities):
    # the sector-based findChessboardCornersSB found the board in all 28 whatever the
    # polarity or contrast variant, the classic detector in 10-18. SB's own corners were off
    # by 0.16 px RMS (which biased the focal length by ~1 %), cornerSubPix with a window of
    # half the corner spacing brings them to ~0.1 px, so every detection is refined that way.
    if use_sb:
        ok, corners = cv2.findChessboardCornersSB(
            img, spec.pattern_size, flags=cv2.CALIB_CB_NORMALIZE_IMAGE)
        if ok:
            return _refine_corners(img, corners, spec)
    ok, corners = cv2.findChessboardCorners(
        img, spec.pattern_size,
        flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE,
    )
    return _refine_corners(img, corners, spec) if ok else None


def _find_circles(img: np.ndarray, spec: PatternSpec) -> np.ndarray | None:
    grid = cv2.CALIB_CB_ASYMMETRIC_GRID if spec.kind == "acircles" else cv2.CALIB_CB_SYMMETRIC_GRID
    detector = _blob_detector(img.shape[:2], spec)
    # Pixel noise of a low-contrast target breaks circles into speckle at the thresholds the
    # blob detector sweeps; a light blur (sigma 1 px) keeps them whole and does not move
    # the centre of a symmetric blob.
    smooth = cv2.GaussianBlur(img, (0, 0), 1.0)
    ok, centers = cv2.findCirclesGrid(smooth, spec.pattern_size, None, grid, detector)
    if ok:
        return centers
    # The default grid finder failed on 6 of 42 rendered views tilted by 43-52 deg although
    # every circle was detected; the clustering finder found all 6. It is slow when noise
    # gives hundreds of blobs, so it runs only when the blob count is plausible.
    n_blobs = len(detector.detect(smooth))
    if spec.n_points <= n_blobs <= 2 * spec.n_points:
        ok, centers = cv2.findCirclesGrid(
            smooth, spec.pattern_size, None, grid | cv2.CALIB_CB_CLUSTERING, detector)
        if ok:
            return centers
    return None


def detect_pattern(
    image: np.ndarray, spec: PatternSpec
) -> tuple[np.ndarray, str] | None:
    """Find the calibration pattern in one IR frame.

    Parameters
    ----------
    image : numpy.ndarray, shape (H, W)
        Raw frame, uint8, uint16 or float.
    spec : PatternSpec
        Target geometry.

    Returns
    -------
    (points, variant) or None
        ``points``: shape (rows * cols, 2), float32, pixel coordinates (x right, y down, origin
        at the centre of the top-left pixel) in the order of :func:`object_points`;
        ``variant``: which contrast variant found it (e.g. ``"clahe-inverted"``).
        ``None`` when no variant shows the pattern.
    """
    gray8 = to_gray8(image)
    for variant, img in candidate_images(gray8):
        if spec.kind == "chessboard":
            # SB does not care about polarity and costs ~0.5 s when it fails (e.g. wrong
            # --rows): run it on the two non-inverted variants only.
            pts = _find_chessboard(img, spec, use_sb=not variant.endswith("inverted"))
        else:
            pts = _find_circles(img, spec)
        if pts is not None and len(pts) == spec.n_points:
            pts = pts.reshape(-1, 2).astype(np.float32)
            if grid_irregularity(pts, spec) > MAX_GRID_IRREGULARITY:
                continue  # a wrong blob or corner got into the grid; try the next variant
            if is_point_symmetric(spec):
                pts = right_handed(pts, spec)
            return pts, variant
    return None


def grid_irregularity(points: np.ndarray, spec: PatternSpec) -> float:
    """Largest second difference along grid lines relative to the local point spacing.

    On a plane seen through a lens, neighbouring grid points are nearly evenly spaced along
    every grid line, so ``p[k-1] - 2 p[k] + p[k+1]`` is a small fraction of the spacing
    (perspective and distortion give <= 0.21 at the tilts and lenses we tried). A point taken from
    a wrong blob or a corner pulled to a neighbouring edge gives a large value.

    Parameters
    ----------
    points : numpy.ndarray, shape (rows * cols, 2)
    spec : PatternSpec

    Returns
    -------
    float
        max |second difference| / spacing over all triples (0 when the grid has no triple).
    """
    grid = points.reshape(spec.rows, spec.cols, 2).astype(np.float64)
    lines = []
    if spec.cols >= 3:
        lines.append(grid)  # along rows
    col_step = 2 if spec.kind == "acircles" else 1  # same-parity rows line up
    if spec.rows >= 2 * col_step + 1:
        lines.append(np.swapaxes(grid[::col_step], 0, 1))  # along columns
    worst = 0.0
    for g in lines:
        d1 = np.diff(g, axis=1)
        d2 = np.diff(g, n=2, axis=1)
        spacing = 0.5 * (np.linalg.norm(d1[:, :-1], axis=2) + np.linalg.norm(d1[:, 1:], axis=2))
        worst = max(worst, float((np.linalg.norm(d2, axis=2) / np.maximum(spacing, 1e-9)).max()))
    return worst


#: Detections whose :func:`grid_irregularity` exceeds this are rejected (measured on correct
#: detections of rendered targets at up to 50 deg tilt and k1 = -0.25: <= 0.21; wrong
#: ones measured 0.48 and more).
MAX_GRID_IRREGULARITY = 0.3


def right_handed(points: np.ndarray, spec: PatternSpec) -> np.ndarray:
    """Renumber a rectangular grid so that its row and column directions form a right turn.

    A rectangular grid has no mark telling its front from its back, so the detector may
    number it mirrored (rows running right-to-left where the other camera's run
    left-to-right). Both numberings fit one camera (the mirrored one as a pose seen from
    behind), but the stereo pair needs the same physical point under the same number in
    both cameras. With x right and y down, the row direction turned by +90 deg must point
    along the columns; otherwise each row is reversed.

    Parameters
    ----------
    points : numpy.ndarray, shape (rows * cols, 2)
        Detected grid, row-major.
    spec : PatternSpec

    Returns
    -------
    numpy.ndarray, shape (rows * cols, 2)
    """
    grid = points.reshape(spec.rows, spec.cols, 2)
    along_row = grid[:, -1].mean(axis=0) - grid[:, 0].mean(axis=0)
    along_col = grid[-1].mean(axis=0) - grid[0].mean(axis=0)
    cross = along_row[0] * along_col[1] - along_row[1] * along_col[0]
    if cross < 0:
        grid = grid[:, ::-1]
    return np.ascontiguousarray(grid.reshape(-1, 2))


def is_point_symmetric(spec: PatternSpec) -> bool:
    """True when a 180 deg turn of the target maps its point set onto itself.

    Holds for every rectangular grid (chessboard, symmetric circles); an asymmetric circle
    grid with an odd number of rows (enforced by :class:`PatternSpec`) has no such symmetry,
    so its numbering is unique.
    """
    return spec.kind != "acircles"


def orient_like(reference: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Reverse ``points`` if its grid runs opposite to ``reference``'s.

    A chessboard with an even x even or odd x odd number of inner corners, and every circle
    grid, looks the same after a 180 deg turn, so the detector may number the points from
    opposite ends in the left and the right image. Reversing the order is exactly that turn.
    For a horizontal stereo pair the first-to-last direction agrees within 90 deg. Call it
    only when :func:`is_point_symmetric` holds for the target.

    Parameters
    ----------
    reference, points : numpy.ndarray, shape (N, 2)
        Detected points of the same view in the two cameras.

    Returns
    -------
    numpy.ndarray, shape (N, 2)
        ``points`` or ``points[::-1]``.
    """
    d_ref = reference[-1] - reference[0]
    d_pts = points[-1] - points[0]
    if float(np.dot(d_ref, d_pts)) < 0.0:
        return np.ascontiguousarray(points[::-1])
    return points
