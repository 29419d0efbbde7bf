"""Temporal reuse between triples of one stream: what a chain call leaves for the next.

Consecutive triples (t0, t1, t2), (t1, t2, t3) share two frames and one differential image,
and the gas moves little from one triple to the next. The live chain exploits both:

- the previous triple's flow w_L and disparities d_L, d'_L start the solvers (a *warm
  start*) on fewer pyramid levels and iterations (``ChainParameters.warm_flow_options``,
  ``warm_disparity_options``) instead of SGM and a full pyramid;
- each raw frame is radiometrically corrected and rectified once, not once per triple it
  belongs to (:attr:`ChainState.frames`, keyed by camera and capture time);
- the registration shift between two consecutive frames of a camera is estimated once
  (:class:`ShiftMemo`, keyed by the frames' capture times): at stride 1 the t1 -> t2 shift
  of one triple is the t0 -> t1 shift of the next; the daemon's workers share one memo, so
  that with two workers alternating each triple estimates one shift per camera, not two;
- the normalisation scale is tracked across triples.

The differential image D(t1, t2) of one triple is D(t0, t1) of the next only on the same
pixel grid: :mod:`processing.preprocess` registers t1 and t2 onto t0, so the next triple
needs it on the t1 grid. Re-using it would save one subtraction, one warp and one
denoising per camera (about 2 % of a warm triple, measured) at the price of an
interpolation; it is not done.

A warm start is taken only when this triple follows the previous one of the same
:class:`ChainState` exactly ``stride`` frames later, as proved by the shared capture times
(stride 1: (t1, t2) of the previous are (t0, t1) of this one; stride 2: t2 of the previous
is t0 of this one). Anything else - a dropped frame, a restart, a reordered or repeated
triple - is a cold start: full pyramid and the configured initial disparity. With two
workers taking every other triple (the daemon), each worker's state has stride 2.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from processing.normalisation import DiffScaleTracker
from processing.preprocess import PreprocessedTriple

#: Strides whose succession the shared capture times can prove (see the module docstring).
STRIDES = (1, 2)

#: A registration shift (dx, dy) in px and whether it was rejected (then it is (0, 0)).
KnownShift = tuple[tuple[float, float], bool]


class ShiftMemo(Protocol):
    """Registration shifts between two frames of one camera, keyed by their capture times.

    A shift depends only on the two (corrected) frames, so whoever estimated it first can
    hand it to every later triple containing the same two frames; results are identical.
    """

    def get(self, camera: int, t_from: float, t_to: float) -> KnownShift | None:
        """The shift of frame ``t_to`` relative to frame ``t_from`` (s), or None."""

    def put(self, camera: int, t_from: float, t_to: float, shift: tuple[float, float],
            rejected: bool) -> None:
        """Remember a shift estimated by this process."""


class LocalShiftMemo:
    """A :class:`ShiftMemo` of one process: the last ``capacity`` shifts in a dict."""

    def __init__(self, capacity: int = 16) -> None:
        self.capacity = capacity
        self._items: dict[tuple[int, float, float], KnownShift] = {}

    def get(self, camera: int, t_from: float, t_to: float) -> KnownShift | None:
        return self._items.get((camera, t_from, t_to))

    def put(self, camera: int, t_from: float, t_to: float, shift: tuple[float, float],
            rejected: bool) -> None:
        self._items[(camera, t_from, t_to)] = ((float(shift[0]), float(shift[1])), rejected)
        while len(self._items) > self.capacity:
            del self._items[next(iter(self._items))]  # dicts keep insertion order


@dataclass
class ChainState:
    """What one call leaves for the next call on the following triple of the same stream.

    The daemon keeps one per worker; offline evaluation may pass None (every triple cold).

    Attributes
    ----------
    stride : int
        Frames between the first frames of two triples this state sees in succession: 1
        when one process handles every triple, 2 when two workers alternate.
    scale : DiffScaleTracker or None
        Tracked normalisation scale of the differential images.
    previous_flow, previous_disparity, previous_change : ndarray or None
        w_L (H, W, 2), d_L and d'_L (H, W) of the previous triple, px.
    previous_times : (float, float, float) or None
        Capture times of the previous triple, s.
    shifts : ShiftMemo
        Registration shifts already estimated (this process's, or shared between workers).
    shifts_reused : int
        How many shifts came from ``shifts`` instead of being estimated.
    warm_starts, cold_starts : int
        How many calls started warm and cold (for the benchmark and the tests).
    warm_run : int
        Warm starts since the last cold start (for ``ChainParameters.cold_every``).
    frames : dict
        Corrected and rectified frames of the last triple by (camera, capture time), camera
        0 = left, 1 = right (:func:`corrected_frame`).
    frames_reused : int
        How many frames came from ``frames`` instead of being corrected again.
    """

    stride: int = 1
    scale: DiffScaleTracker | None = None
    previous_flow: np.ndarray | None = None
    previous_disparity: np.ndarray | None = None
    previous_change: np.ndarray | None = None
    previous_times: tuple[float, float, float] | None = None
    shifts: ShiftMemo = field(default_factory=LocalShiftMemo)
    shifts_reused: int = 0
    warm_starts: int = 0
    cold_starts: int = 0
    warm_run: int = 0
    frames: dict[tuple[int, float], np.ndarray] = field(default_factory=dict)
    frames_reused: int = 0

    def __post_init__(self) -> None:
        if self.stride not in STRIDES:
            raise ValueError(f"stride must be one of {STRIDES}, got {self.stride!r}")

    def follows(self, times: tuple[float, float, float]) -> bool:
        """True when ``times`` is the triple ``stride`` frames after the previous one."""
        prev = self.previous_times
        if prev is None:
            return False
        if self.stride == 1:
            return prev[1:] == times[:2]
        return prev[2] == times[0]

    def reset(self) -> None:
        """Forget the previous triple (the next call starts cold); keeps the scale."""
        self.previous_flow = self.previous_disparity = self.previous_change = None
        self.previous_times = None
        self.frames.clear()


@dataclass(frozen=True)
class WarmStart:
    """The previous fields a warm-started call begins from (w_L, d_L, d'_L), px."""

    flow: np.ndarray
    disparity: np.ndarray
    change: np.ndarray


def warm_start(state: ChainState | None, times: tuple[float, float, float],
               enabled: bool, cold_every: int = 0) -> WarmStart | None:
    """The warm start for a triple at ``times``, or None when it must start cold.

    ``cold_every`` > 0 makes every ``cold_every``-th triple of an unbroken warm run start
    cold anyway: a warm start cannot leave a wrong state (a d' pinned by a warm object in
    the first triple stayed wrong for the whole run, measured), a cold start can, so the
    restarts bound how long an error lives. Counts the decision in the state's
    ``warm_starts`` / ``cold_starts``.
    """
    if state is None:
        return None
    ok = (enabled and state.follows(times) and state.previous_flow is not None
          and state.previous_disparity is not None and state.previous_change is not None
          and not (cold_every > 0 and state.warm_run + 1 >= cold_every))
    if not ok:
        state.cold_starts += 1
        state.warm_run = 0
        return None
    state.warm_starts += 1
    state.warm_run += 1
    assert state.previous_flow is not None and state.previous_disparity is not None
    assert state.previous_change is not None
    return WarmStart(state.previous_flow, state.previous_disparity, state.previous_change)


def known_shifts(state: ChainState | None, times: tuple[float, float, float]
                 ) -> tuple[tuple[KnownShift | None, KnownShift | None], ...]:
    """Per camera (left, right): the t0 -> t1 and t1 -> t2 shifts already in the memo."""
    if state is None:
        return ((None, None), (None, None))
    out = tuple((state.shifts.get(cam, times[0], times[1]),
                 state.shifts.get(cam, times[1], times[2])) for cam in (0, 1))
    state.shifts_reused += sum(k is not None for pair in out for k in pair)
    return out


def remember_shifts(state: ChainState | None, times: tuple[float, float, float],
                    known: Sequence[Sequence[KnownShift | None]],
                    estimated: Sequence[PreprocessedTriple]) -> list[PreprocessedTriple]:
    """Put the shifts this triple estimated into the memo; return the two cameras'
    pre-processing results with the known shifts' rejections counted too (a triple is
    flagged the same whether it estimated a shift or took it from the memo)."""
    out = []
    for cam, (pre, pair) in enumerate(zip(estimated, known, strict=True)):
        rejected = list(pre.rejected)
        for k, hit in enumerate(pair):
            if hit is not None:
                rejected[k] = hit[1]
            elif state is not None:
                state.shifts.put(cam, times[k], times[k + 1], pre.shifts[k], pre.rejected[k])
        out.append(dataclasses.replace(pre, rejected_shifts=sum(rejected),
                                       rejected=(rejected[0], rejected[1])))
    return out


def solver_options(base: Mapping[str, Any], warm: Mapping[str, Any],
                   is_warm: bool) -> dict[str, Any]:
    """Keyword arguments of one solver: ``base``, overridden by ``warm`` on a warm start."""
    return {**base, **warm} if is_warm else dict(base)


def remember(state: ChainState, *, times: tuple[float, float, float], flow: np.ndarray,
             disparity: np.ndarray, change: np.ndarray) -> None:
    """Store this triple's results in ``state`` for the next call."""
    state.previous_flow = flow
    state.previous_disparity = disparity
    state.previous_change = change
    state.previous_times = times


def corrected_frames(state: ChainState | None, camera: int, raw: Sequence[np.ndarray],
                     times: tuple[float, float, float],
                     correct: Callable[[np.ndarray], np.ndarray]) -> list[np.ndarray]:
    """``correct`` applied to the three raw frames of one camera, each frame only once.

    Frames of this camera seen in the previous call (same capture time) come from
    ``state.frames``; afterwards the cache holds exactly this triple's frames. Without a
    state every frame is corrected.
    """
    if state is None:
        return [correct(f) for f in raw]
    out = []
    for f, t in zip(raw, times, strict=True):
        img = state.frames.get((camera, t))
        if img is None:
            img = correct(f)
        else:
            state.frames_reused += 1
        out.append(img)
    for key in [k for k in state.frames if k[0] == camera]:
        del state.frames[key]
    state.frames.update({(camera, t): img for t, img in zip(times, out, strict=True)})
    return out
