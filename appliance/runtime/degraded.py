"""Which cameras deliver: stereo, degraded to one camera, or a single-camera site.

A camera of the pair that delivers nothing for ``cameras.lost_after_s`` is *lost*: the
pairing thread then hands the other camera's frames on alone (single-camera chain, the same
leak events), and when the lost camera delivers again stereo resumes by itself. A site
configured with one camera (``cameras.right: null``) is single-camera from the start.

Pure bookkeeping, no threads of its own: the pairing thread calls :meth:`CameraWatch.frame`
and :meth:`CameraWatch.check`; the health thread reads :meth:`CameraWatch.status`.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass

SIDES = ("left", "right")

#: The modes of :attr:`CameraWatch.mode`.
STEREO, DEGRADED, SINGLE_CAMERA = "stereo", "degraded", "single_camera"


@dataclass
class _Side:
    present: bool
    last_ns: int | None = None  # host monotonic ns of the newest frame
    lost: bool = False
    lost_since_ns: int | None = None  # host monotonic ns of its last frame before the loss
    losses: int = 0


class CameraWatch:
    """Lost and returned cameras, and the seconds spent on one camera.

    Parameters
    ----------
    present : dict
        ``{"left": bool, "right": bool}``: the configured cameras.
    lost_after_s : float
        A present camera silent for longer than this is lost, s.
    wall_ns : callable
        Host monotonic ns -> UNIX ns (for the status).

    A camera that never delivers is lost ``lost_after_s`` after the first frame of the
    other one (opening a camera may take longer than that; no frame at all is a stall, not
    a lost camera).
    """

    def __init__(self, present: dict[str, bool], lost_after_s: float,
                 wall_ns: Callable[[int], int]) -> None:
        self.lost_after_ns = int(lost_after_s * 1e9)
        self.wall_ns = wall_ns
        self._sides = {s: _Side(bool(present[s])) for s in SIDES}
        self._first_ns: int | None = None
        self._single_site = not all(present.values())
        self._degraded_ns = 0  # finished stretches on one camera of a pair
        self._degraded_from: int | None = None  # monotonic ns the current one began
        self._lock = threading.Lock()

    # ------------------------------------------------------------------ pairing thread

    def frame(self, side: str, now_ns: int) -> bool:
        """A frame of ``side`` arrived at host monotonic ``now_ns``; True when this frame
        brings a lost camera back (the caller re-establishes its clock model)."""
        s = self._sides[side]
        s.last_ns = now_ns if s.last_ns is None else max(s.last_ns, now_ns)
        if self._first_ns is None:
            self._first_ns = now_ns
        if not s.lost:
            return False
        with self._lock:
            s.lost, s.lost_since_ns = False, None
            self._end_degraded(now_ns)
        return True

    def check(self, now_ns: int) -> list[str]:
        """Mark the cameras silent for longer than ``lost_after_s`` as lost; returns the
        sides lost by this call."""
        out: list[str] = []
        if self._first_ns is None:
            return out
        for side, s in self._sides.items():
            last = self._first_ns if s.last_ns is None else s.last_ns
            if s.present and not s.lost and now_ns - last > self.lost_after_ns:
                with self._lock:
                    s.lost, s.lost_since_ns = True, last
                    s.losses += 1
                    if not self._single_site and self._degraded_from is None:
                        self._degraded_from = now_ns
                out.append(side)
        return out

    def _end_degraded(self, now_ns: int) -> None:
        if self._degraded_from is not None and not any(s.lost for s in self._sides.values()):
            self._degraded_ns += now_ns - self._degraded_from
            self._degraded_from = None

    # ------------------------------------------------------------------ readers

    @property
    def mode(self) -> str:
        """``stereo``, ``degraded`` (a camera of the pair lost) or ``single_camera``."""
        if self._single_site:
            return SINGLE_CAMERA
        return DEGRADED if any(s.lost for s in self._sides.values()) else STEREO

    @property
    def survivor(self) -> str | None:
        """The camera whose frames go on alone (None: stereo, or no camera delivers)."""
        alive = [side for side, s in self._sides.items() if s.present and not s.lost]
        return alive[0] if len(alive) == 1 else None

    def lost(self, side: str) -> bool:
        """Whether ``side`` is lost now."""
        return self._sides[side].lost

    def degraded_s(self, now_ns: int) -> float:
        """Seconds a camera of the pair was lost so far (0 on a single-camera site)."""
        with self._lock:
            running = 0 if self._degraded_from is None else now_ns - self._degraded_from
            return (self._degraded_ns + running) / 1e9

    def losses(self, side: str) -> int:
        """How often ``side`` was lost."""
        return self._sides[side].losses

    def status(self) -> dict[str, dict[str, object]]:
        """Per camera: ``configured``, ``lost`` and ``lost_since_wall_ns`` (UNIX ns of its
        last frame before the loss, None while it delivers), for the health snapshot."""
        with self._lock:
            return {side: {"configured": s.present, "lost": s.lost,
                           "lost_since_wall_ns": (None if s.lost_since_ns is None
                                                  else int(self.wall_ns(s.lost_since_ns)))}
                    for side, s in self._sides.items()}
