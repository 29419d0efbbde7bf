"""Temporal reuse between triples of one stream: what a chain call leaves for the next.

Consecutive triples (t0, t1, t2), (t1, t2, t3) share two frames and one differential image,
and the gas moves little from one triple to the next. The live chain exploits both:

- the previous triple's flow w_L and disparities d_L, d'_L start the solvers (a *warm
  start*) on fewer pyramid levels and iterations (``ChainParameters.warm_flow_options``,
  ``warm_disparity_options``) instead of SGM and a full pyramid;
- each raw frame is radiometrically corrected and rectified once, not once per triple it
  belongs to (:attr:`ChainState.frames`, keyed by camera and capture time);
- the registration shift between two consecutive frames of a camera is estimated once
  (:mod:`processing.chain.shifts`);
- the normalisation scale is tracked across triples; the first one of a stream is taken
  again from the registered, gated differences; a triple whose differences ask for far more
  than the tracked scale is a scene change and starts cold.

:class:`ChainState` owns this life cycle; :func:`processing.chain.compute_scene_flow` asks it
at each step what to do.

D(t1, t2) of one triple is D(t0, t1) of the next only on the same pixel grid (the
registration warps t1 and t2 onto t0): when the triple left t1 where it was (a zero, rejected
or unestimated t0 -> t1 shift) the next triple takes D(t1) raw and denoised from here
(:meth:`ChainState.exchange_differences`, about 1.2 ms of a warm 320x240 triple), from the
other worker's triple through :attr:`ChainState.images` with two workers; otherwise it is
computed anew.

A warm start is taken only when this triple follows the previous one of the same
:class:`ChainState` exactly ``stride`` frames later, as proved by the shared capture times
(stride 1: (t1, t2) of the previous are (t0, t1) of this one; stride 2: t2 of the previous
is t0 of this one). Anything else - a dropped frame, a restart, a reordered or repeated
triple - is a cold start: full pyramid and the configured initial disparity. A scheduled
restart (``cold_every``) may keep the flow (``ChainParameters.restart_keeps_flow``). With
two workers taking every other triple (the daemon), each worker's state has stride 2.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Hashable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from processing.chain.images import ImageKey, ImageShare, difference_key
from processing.chain.scene_change import is_scene_change
from processing.chain.shifts import KnownShift, LocalShiftMemo, ShiftMemo
from processing.preprocess.differential import PreprocessedTriple, SecondDifference
from processing.preprocess.normalisation import DiffScaleTracker, pooled_quantile

#: Strides whose succession the shared capture times can prove (see the module docstring).
STRIDES = (1, 2)

#: While the registration of a camera pauses (``ChainParameters.registration_pause_after``),
#: one shift in this many is still estimated: at 30 Hz a probe every third of a second.
PROBE_EVERY = 10

Times = tuple[float, float, float]


@dataclass(frozen=True)
class WarmStart:
    """The previous fields a warm-started call begins from (w_L, d_L, d'_L), px, of the
    triple ``steps`` frames back (the state's stride)."""

    flow: np.ndarray
    disparity: np.ndarray
    change: np.ndarray
    steps: int = 1


@dataclass
class ChainState:
    """What one call leaves for the next call on the following triple of the same stream.

    The daemon keeps one per worker; offline evaluation may pass None to the chain, which
    then uses a fresh state that it throws away (every triple cold).

    Attributes
    ----------
    stride : int
        Frames between the first frames of two triples this state sees in succession: 1
        when one process handles every triple, 2 when two workers alternate.
    scale : DiffScaleTracker or None
        Tracked normalisation scale of the differential images.
    previous_flow, previous_disparity, previous_change : ndarray or None
        w_L (H, W, 2), d_L and d'_L (H, W) of the previous triple, px.
    previous_mask : ndarray or None
        The previous triple's gas mask (H, W), bool (the active region starts from it).
    previous_times : (float, float, float) or None
        Capture times of the previous triple, s.
    shifts : ShiftMemo
        Registration shifts already estimated (this process's, or shared between workers).
    shifts_reused : int
        How many shifts came from ``shifts`` instead of being estimated.
    rejected_run : dict
        Per camera: how many of its shifts in a row were rejected (each shift counted once,
        in capture order; :meth:`known_shifts` pauses the registration after enough).
    shifts_paused : int
        How many shifts were taken as rejected without an estimate (a paused registration).
    warm_starts, cold_starts : int
        How many calls started warm and cold (for the benchmark and the tests).
    warm_run : int
        Warm starts since the last cold start (for ``ChainParameters.cold_every``).
    restart_flow : ndarray or None
        The previous triple's w_L (H, W, 2) px when this triple's cold start is a scheduled
        restart (``cold_every``) of a run that follows on, else None.
    change_run : int
        Consecutive triples whose d' the kept ``previous_change`` averages
        (:func:`processing.stereo.coherence.history_weight`); 0 after a reset.
    frames : dict
        Corrected and rectified frames of the last triple by (camera, capture time), camera
        0 = left, 1 = right (:meth:`corrected_frames`).
    frames_reused : int
        How many frames came from ``frames`` instead of being corrected again.
    differences : dict
        Per camera: the key (:func:`processing.chain.images.difference_key`, as in
        ``images``) and the (raw, denoised) D(t1) of the last triple that left its t1
        unmoved (:meth:`exchange_differences`).
    differences_reused : int
        How many D(t0) came from ``differences`` or ``images`` instead of being computed
        again.
    images : ImageShare or None
        Differential images shared with the other workers of the stream
        (:mod:`processing.chain.images`); None: this state's own only.
    """

    stride: int = 1
    scale: DiffScaleTracker | None = None
    previous_flow: np.ndarray | None = None
    previous_disparity: np.ndarray | None = None
    previous_change: np.ndarray | None = None
    previous_mask: np.ndarray | None = None
    previous_times: Times | None = None
    shifts: ShiftMemo = field(default_factory=LocalShiftMemo)
    shifts_reused: int = 0
    rejected_run: dict[int, int] = field(default_factory=dict)
    shifts_paused: int = 0
    _counted_until: dict[int, float] = field(default_factory=dict, repr=False)
    _paused_for: dict[int, int] = field(default_factory=dict, repr=False)
    warm_starts: int = 0
    cold_starts: int = 0
    warm_run: int = 0
    restart_flow: np.ndarray | None = None
    change_run: int = 0
    frames: dict[tuple[int, float], np.ndarray] = field(default_factory=dict)
    frames_reused: int = 0
    differences: dict[int, tuple[ImageKey, tuple[np.ndarray, np.ndarray]]] = field(
        default_factory=dict)
    differences_reused: int = 0
    images: ImageShare | None = None

    def __post_init__(self) -> None:
        if self.stride not in STRIDES:
            raise ValueError(f"stride must be one of {STRIDES}, got {self.stride!r}")

    def follows(self, times: Times) -> bool:
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
        self.previous_mask = None
        self.previous_times = None
        self.change_run = 0
        self.frames.clear()
        self.differences.clear()
        self.rejected_run.clear()
        self._counted_until.clear()
        self._paused_for.clear()

    # -- normalisation scale -------------------------------------------------------------

    def scale_to_use(self, fixed: float | None) -> float | None:
        """This triple's normalisation scale: ``fixed``, else the tracked one, else None
        (a first scale must be taken from the triple itself)."""
        if fixed is not None:
            return fixed
        return None if self.scale is None else self.scale.scale

    def scale_target(self, measured: Sequence[np.ndarray], first: bool) -> float | None:
        """The scale this triple's raw differences ask for (once: the scene-change test and
        the tracker use it); for a ``first`` scale, the quantile the tracker starts from."""
        if first:
            return pooled_quantile(measured)
        return None if self.scale is None else self.scale.target(*measured)

    def scene_change(self, target: float | None, measured: Sequence[np.ndarray]) -> bool:
        """Whether the whole picture changed at once in this triple
        (:func:`processing.chain.scene_change.is_scene_change` against the tracked scale;
        ``target``: what its raw differential images ``measured`` ask for,
        :meth:`scale_target`). False before the state has a tracked scale."""
        return is_scene_change(None if self.scale is None else self.scale.scale, target,
                               measured)

    # -- warm start ----------------------------------------------------------------------

    def warm_start(self, times: Times, enabled: bool, cold_every: int = 0,
                   scene_change: bool = False) -> WarmStart | None:
        """The warm start for a triple at ``times``, or None when it must start cold.

        ``cold_every`` > 0 makes every ``cold_every``-th triple of an unbroken warm run start
        cold anyway: a warm start cannot leave a wrong state (a d' pinned by a warm object in
        the first triple stayed wrong for the whole run, measured), a cold start can, so the
        restarts bound how long an error lives; such a restart leaves the previous flow in
        ``restart_flow``. A scene change always starts cold. Counts the decision in
        ``warm_starts`` / ``cold_starts``.
        """
        self.restart_flow = None
        if scene_change:
            self.cold_starts += 1
            return None
        follows = (enabled and self.follows(times) and self.previous_flow is not None
                   and self.previous_disparity is not None and self.previous_change is not None)
        scheduled = cold_every > 0 and self.warm_run + 1 >= cold_every
        if follows and scheduled:
            self.restart_flow = self.previous_flow
        if not follows or scheduled:
            self.cold_starts += 1
            self.warm_run = 0
            return None
        self.warm_starts += 1
        self.warm_run += 1
        assert self.previous_flow is not None and self.previous_disparity is not None
        assert self.previous_change is not None
        return WarmStart(self.previous_flow, self.previous_disparity, self.previous_change,
                         self.stride)

    def change_history(self, follows: bool) -> tuple[np.ndarray | None, int]:
        """The previous triple's d'_L (None unless this triple ``follows`` it) and the frames
        between the two triples (the stride), for the temporal coherence of d'."""
        return (self.previous_change if follows else None), self.stride

    def change_triples(self, follows: bool) -> int:
        """How many triples the d' history of :meth:`change_history` averages (0: none)."""
        return self.change_run if follows and self.previous_change is not None else 0

    # -- frames and shifts ---------------------------------------------------------------

    def known_shifts(self, times: Times, pause_after: int = 0
                     ) -> tuple[tuple[KnownShift | None, KnownShift | None], ...]:
        """Per camera (left, right): the t0 -> t1 and t1 -> t2 shifts already in the memo,
        or ((0, 0), rejected) for a shift not to be estimated because that camera's last
        ``pause_after`` (> 0) shifts were rejected (every :data:`PROBE_EVERY`-th is
        estimated all the same; the memo gets the paused ones, so that the other worker
        agrees); None: to be estimated."""
        out = []
        for cam in (0, 1):
            pair: list[KnownShift | None] = []
            for k in (0, 1):
                hit = self.shifts.get(cam, times[k], times[k + 1])
                self.shifts_reused += hit is not None
                if hit is None and pause_after > 0 \
                        and self.rejected_run.get(cam, 0) >= pause_after:
                    paused = self._paused_for.get(cam, 0)
                    if paused < PROBE_EVERY - 1:
                        hit = ((0.0, 0.0), True)
                        self.shifts.put(cam, times[k], times[k + 1], *hit)
                        self.shifts_paused += 1
                    self._paused_for[cam] = 0 if hit is None else paused + 1
                pair.append(hit)
            out.append((pair[0], pair[1]))
        return tuple(out)

    def remember_shifts(self, times: Times, known: Sequence[Sequence[KnownShift | None]],
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
                else:
                    self.shifts.put(cam, times[k], times[k + 1], pre.shifts[k],
                                    pre.rejected[k])
                if times[k + 1] > self._counted_until.get(cam, -np.inf):
                    self._counted_until[cam] = times[k + 1]
                    self.rejected_run[cam] = self.rejected_run.get(cam, 0) + 1 \
                        if rejected[k] else 0
            out.append(dataclasses.replace(pre, rejected_shifts=sum(rejected),
                                           rejected=(rejected[0], rejected[1])))
        return out

    def exchange_differences(self, times: Times, seconds: Sequence[SecondDifference],
                             settings: Hashable) -> tuple[tuple[np.ndarray, np.ndarray] | None,
                                                          tuple[np.ndarray, np.ndarray] | None]:
        """Per camera (left, right): this triple's D(t0) raw and denoised when the previous
        triple (this state's, or another worker's through ``images``) computed it as its
        D(t1), for ``diff0`` of
        :func:`processing.preprocess.differential.complete_triple`; None: compute it.

        ``seconds`` are this triple's registered frames and D(t1) per camera, ``settings``
        whatever else the differences depend on (the gas radiance, the contrast floor, the
        denoising weight). D(t0) is looked up, this triple's D(t1) shared, and a D(t0) not
        found looked up once more: a worker whose D(t0) the other one is computing at the
        same moment mostly finds it then, and the table's oldest entry, which a worker that
        fell behind may need, is read before this triple's entries replace it. The D(t1)
        are then kept for this state's next triple. A D(t1) is kept and shared only when
        it lies on t1's own grid (the triple's t0 -> t1 shift is (0, 0)); otherwise the
        camera's older one is forgotten.
        """
        keys = [difference_key(cam, times[0], times[1], second.shifts[0], settings)
                for cam, second in enumerate(seconds)]
        found = [self._known_difference(cam, key) for cam, key in enumerate(keys)]
        mine = []
        for cam, second in enumerate(seconds):
            s01, s12 = second.shifts
            entry = None
            if s01 == (0.0, 0.0):
                entry = (difference_key(cam, times[1], times[2], s12, settings),
                         (second.raw1, second.denoised1))
                if self.images is not None:
                    self.images.put(*entry)
            mine.append(entry)
        for cam, key in enumerate(keys):
            if found[cam] is None:
                found[cam] = self._known_difference(cam, key)
            self.differences_reused += found[cam] is not None
            if mine[cam] is None:
                self.differences.pop(cam, None)
            else:
                self.differences[cam] = mine[cam]  # type: ignore[assignment]
        return found[0], found[1]

    def _known_difference(self, cam: int, key: ImageKey
                          ) -> tuple[np.ndarray, np.ndarray] | None:
        """The difference under ``key``: this state's kept one, else the shared table's."""
        hit = self.differences.get(cam)
        if hit is not None and hit[0] == key:
            return hit[1]
        shared = None if self.images is None else self.images.get(key, 2)
        return None if shared is None else (shared[0], shared[1])

    def corrected_frames(self, camera: int, raw: Sequence[np.ndarray], times: Times,
                         correct: Callable[[np.ndarray], np.ndarray]) -> list[np.ndarray]:
        """``correct`` applied to the three raw frames of one camera, each frame only once.

        Frames of this camera seen in the previous call (same capture time) come from
        ``frames``; afterwards the cache holds exactly this triple's frames.
        """
        out = []
        for f, t in zip(raw, times, strict=True):
            img = self.frames.get((camera, t))
            if img is None:
                img = correct(f)
            else:
                self.frames_reused += 1
            out.append(img)
        for key in [k for k in self.frames if k[0] == camera]:
            del self.frames[key]
        self.frames.update({(camera, t): img for t, img in zip(times, out, strict=True)})
        return out

    def frames_of(self, times: Times) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """The left and right corrected frames of the triple at ``times``, as
        :meth:`corrected_frames` left them."""
        return ([self.frames[(0, t)] for t in times], [self.frames[(1, t)] for t in times])

    # -- end of a triple -----------------------------------------------------------------

    def finish(self, *, times: Times, scale: float, fixed_scale: float | None,
               forgetting: float, measured: Sequence[np.ndarray], target: float | None,
               scene_change: bool, flow: np.ndarray, disparity: np.ndarray,
               change: np.ndarray, mask: np.ndarray | None = None,
               change_triples: int = 1) -> None:
        """Leave this triple for the next: the tracked scale moves towards ``target``; the
        fields are kept for a warm start unless the triple was a scene change (then the
        next triple starts cold too: these fields are not gas). ``change_triples``: how
        many triples ``change`` averages (this one and its history's)."""
        if fixed_scale is None:
            if self.scale is None:
                self.scale = DiffScaleTracker(scale, forgetting=forgetting)
            self.scale.update(*measured, target=target)
        if scene_change:
            self.reset()
            return
        self.previous_flow = flow
        self.previous_disparity = disparity
        self.previous_change = change
        self.change_run = change_triples
        self.previous_mask = mask
        self.previous_times = times


def solver_options(base: Mapping[str, Any], warm: Mapping[str, Any],
                   is_warm: bool) -> dict[str, Any]:
    """Keyword arguments of one solver: ``base``, overridden by ``warm`` on a warm start."""
    return {**base, **warm} if is_warm else dict(base)
