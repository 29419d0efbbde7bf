"""What the operator's page shows, fed like a live view and encoded in its own thread.

Producers (the publisher in the results thread, the leak monitor) call :meth:`PageHub.push`
with the same items as the Rerun view (:class:`~appliance.live.items.LiveFrame`,
:class:`~appliance.live.status.OperatorStatus`); the pairing thread calls
:meth:`PageHub.push_camera` with the camera's newest frame. Each returns at once.

The picture is the camera's newest frame, not the processed triple's: the chain's latency
(one triple at a time, longer on a loaded box) would otherwise be most of what the operator
waits for, and a box that processes a third of its triples would show pictures a second or
more old. The gas overlay on it is the newest processed result's, and the page states how
much older than the picture that result is (``overlay_capture_ns``); an overlay more than
:data:`OVERLAY_MAX_AGE_S` older than the picture, or of the other camera, is not drawn. Without
a camera feed (no :meth:`PageHub.push_camera` yet) the processed results' own frames are the
pictures.

The newest picture and the newest status each wait in a slot of their own (an older one not
yet encoded is replaced and counted), so a busy machine shows fewer pictures, never older
ones. The hub's thread draws the operator's picture (:func:`appliance.live.colour.operator_bgr`),
encodes it as JPEG, keeps the last :data:`FRAMES_KEPT` of them for ``/frame/<seq>.jpg`` and
hands each frame notice and status to the server's broadcast callback, which puts them on
every client's own queue (:mod:`appliance.page.server`).
"""

from __future__ import annotations

import collections
import json
import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from appliance.live.colour import encode_jpeg, operator_arrows, operator_bgr
from appliance.live.items import LiveFrame
from appliance.live.status import OperatorStatus
from appliance.threads import NamedThread

__all__ = ["FRAMES_KEPT", "OVERLAY_MAX_AGE_S", "EncodedFrame", "HubStats", "PageHub",
           "json_text"]

log = logging.getLogger("ogiflow.page")

#: Encoded pictures kept for ``/frame/<seq>.jpg``: a browser fetches the one it was told of
#: within a second; at 5 pictures/s these 8 cover 1.6 s (~20 kB each at 320x240).
FRAMES_KEPT = 8
#: Velocity arrows drawn on the page's picture (as on the Rerun operator tab).
PAGE_ARROWS = 100

#: A gas overlay older than this (s, before the picture's capture) is not drawn on it: the
#: plume has moved on, and the leak state in words is what holds then.
OVERLAY_MAX_AGE_S = 3.0

#: ``broadcast(kind, json_text)``: called from the hub's thread for every new message.
Broadcast = Callable[[str, str], None]


def _plain(obj: Any) -> Any:
    """JSON-able copy: NaN and infinities become null (JSON has none; a browser's
    ``JSON.parse`` rejects them), numpy scalars and arrays plain numbers and lists."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _plain(obj.tolist())
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def json_text(obj: Any) -> str:
    """Compact JSON of ``obj`` (:func:`_plain`; anything else as its string)."""
    return json.dumps(_plain(obj), separators=(",", ":"), default=str, allow_nan=False)


@dataclass(frozen=True)
class EncodedFrame:
    """One picture for the page.

    Attributes
    ----------
    seq : int
        Its number (1, 2, ...), the name of ``/frame/<seq>.jpg``.
    frame : int
        The camera's frame number (camera pictures) or the pair index of the processed
        result (without a camera feed).
    t_capture_ns : int
        Capture time of the picture's frame, UNIX ns (what the page's frame age counts from).
    jpeg : bytes
    t_result_ns : int
        When the picture's frame reached the page (the appliance's clock), UNIX ns: the age
        at that moment is the acquisition's (or, without a camera feed, the processing's)
        share, the rest is the page's.
    width, height : int
        Picture size, px (the source marker's coordinates are in these pixels).
    camera : str
        Which camera took it ("left", or the survivor while one camera is lost).
    overlay_capture_ns : int or None
        Capture time of the triple whose gas overlay is drawn, UNIX ns; None: no overlay
        (none yet, older than :data:`OVERLAY_MAX_AGE_S`, or of the other camera).
    """

    seq: int
    frame: int
    t_capture_ns: int
    jpeg: bytes
    t_result_ns: int
    width: int
    height: int
    camera: str = "left"
    overlay_capture_ns: int | None = None

    def notice(self) -> dict[str, Any]:
        """The ``frame`` message (no picture: the page fetches ``url``)."""
        return {"seq": self.seq, "frame": self.frame, "t_capture_ns": self.t_capture_ns,
                "t_result_ns": self.t_result_ns, "camera": self.camera,
                "overlay_capture_ns": self.overlay_capture_ns,
                "width": self.width, "height": self.height, "url": f"/frame/{self.seq}.jpg",
                "bytes": len(self.jpeg)}


@dataclass(frozen=True)
class CameraPicture:
    """A camera's frame waiting to be drawn: its own copy of the image (H, W) counts, the
    camera, its frame number and its capture time (UNIX ns)."""

    image: np.ndarray
    camera: str
    frame: int
    t_capture_ns: int


@dataclass
class HubStats:
    """Counters of the hub."""

    frames_pushed: int = 0
    #: Pictures replaced in the slot before the hub's thread encoded them.
    frames_replaced: int = 0
    frames_encoded: int = 0
    #: Camera frames taken as pictures, and pictures drawn without a gas overlay.
    camera_frames: int = 0
    without_overlay: int = 0
    statuses: int = 0
    errors: int = 0


class PageHub:
    """The page's producer side and encoder thread (module docstring).

    Parameters
    ----------
    max_image_hz : float
        Pictures encoded at most this often (``live.page.max_image_hz``).
    jpeg_quality : int
    clock : callable
        The appliance's wall clock, UNIX ns (the clock of the capture times): every message
        carries its send time ``sent_ns`` from it, from which the page estimates the
        appliance's clock and so the age of what it shows whatever the browser's clock says.
    """

    def __init__(self, max_image_hz: float = 5.0, jpeg_quality: int = 75,
                 clock: Callable[[], int] = time.time_ns) -> None:
        self.jpeg_quality = int(jpeg_quality)
        self.clock = clock
        self._period_ns = int(1e9 / max_image_hz)
        self._cond = threading.Condition()
        self._frame: LiveFrame | CameraPicture | None = None
        self._frame_t_ns = 0
        #: The newest processed result with a gas mask: drawn over camera pictures.
        self._overlay: LiveFrame | None = None
        self._camera_fed = False
        self._status: OperatorStatus | None = None
        self._frames: collections.OrderedDict[int, EncodedFrame] = collections.OrderedDict()
        self._status_dict: dict[str, Any] | None = None
        self._seq = 0
        self._last_picture_ns = 0
        self._stats = HubStats()
        self._stop = False
        self._thread: threading.Thread | None = None
        self.broadcast: Broadcast | None = None

    # ------------------------------------------------------------------ producers

    def push(self, item: Any) -> bool:
        """Take a frame with a picture (when one is due) or a status; never waits.

        Frames without the raw left picture (most results) and other items are not taken
        (False): the page's text comes from the status, not from every result. Once cameras
        feed the hub (:meth:`push_camera`), a frame's gas mask becomes the overlay of the
        next camera pictures instead of a picture of its own.
        """
        if isinstance(item, OperatorStatus):
            with self._cond:
                self._status = item
                self._cond.notify()
            return True
        if not isinstance(item, LiveFrame):
            return False
        now = time.monotonic_ns()
        with self._cond:
            if self._camera_fed:
                # every result carries its gas mask: the overlay needs no full fields
                if item.gas_mask is None:
                    return False
                self._overlay = item
                return True
            if item.raw_left is None:
                return False
            if item.gas_mask is not None:
                self._overlay = item
            if not self._picture_due(now):
                return False
            self._fill_slot(item)
        return True

    def push_camera(self, camera: str, image: np.ndarray, frame: int,
                    t_capture_ns: int) -> bool:
        """Take a camera's newest frame as the next picture when one is due; never waits.

        Parameters
        ----------
        camera : str
            "left", or the surviving camera while the other is lost.
        image : ndarray, shape (H, W)
            Raw counts; copied when taken (the camera reuses its buffers).
        frame : int
            The camera's frame number.
        t_capture_ns : int
            Capture time, UNIX ns (the appliance's clock).
        """
        with self._cond:
            if not self._picture_due(time.monotonic_ns()):
                return False
            self._camera_fed = True
        # Copied outside the lock: the hub's thread never waits on the pairing thread's copy.
        picture = CameraPicture(np.array(image, copy=True), camera, int(frame),
                                int(t_capture_ns))
        with self._cond:
            self._stats.camera_frames += 1
            self._fill_slot(picture)
        return True

    def _picture_due(self, now: int) -> bool:
        """Whether a picture is due at ``now`` (monotonic ns); if so its time is taken.
        Call with the lock held."""
        if self._thread is None or now - self._last_picture_ns < self._period_ns:
            return False
        self._last_picture_ns = now
        return True

    def _fill_slot(self, picture: LiveFrame | CameraPicture) -> None:
        """Put ``picture`` into the slot (replacing one not yet encoded) and wake the
        hub's thread. Call with the lock held."""
        self._stats.frames_pushed += 1
        self._stats.frames_replaced += self._frame is not None
        self._frame = picture
        self._frame_t_ns = self.clock()
        self._cond.notify()

    def wants_pictures(self) -> bool:
        """Whether a picture of a result is due; the daemon then asks the workers for full
        fields. Never with a camera feed: the gas overlay is every result's mask, which
        travels without the fields (at 320x240 the page's own requests had made about half
        of the 9-10 full-field results a second)."""
        with self._cond:
            now = time.monotonic_ns()
            if self._thread is None or self._camera_fed:
                return False
            return self._frame is None and now - self._last_picture_ns >= self._period_ns

    # ------------------------------------------------------------------ readers

    def frame(self, seq: int) -> EncodedFrame | None:
        """Picture ``seq`` while it is among the last :data:`FRAMES_KEPT`."""
        with self._cond:
            return self._frames.get(seq)

    def newest_frame(self) -> EncodedFrame | None:
        with self._cond:
            return next(reversed(self._frames.values()), None)

    def status(self) -> dict[str, Any]:
        """``/status.json``: the newest status and the newest picture's notice."""
        with self._cond:
            status = self._status_dict
            newest = next(reversed(self._frames.values()), None)
        out = dict(status) if status is not None else {
            "t_wall_ns": self.clock(), "starting": True,
            "leak": {"state": "NO LEAK", "event": None, "since_t_s": None, "for_s": None,
                     "words": "NO LEAK"}}
        out["newest_frame"] = None if newest is None else newest.notice()
        out["sent_ns"] = self.clock()
        return out

    def stats(self) -> HubStats:
        with self._cond:
            return HubStats(**self._stats.__dict__)

    # ------------------------------------------------------------------ thread

    def start(self) -> PageHub:
        with self._cond:
            self._thread = NamedThread(target=self._run, name="page-encoder",
                                       daemon=True)
        self._thread.start()
        return self

    def close(self, timeout: float = 2.0) -> None:
        with self._cond:
            self._stop = True
            self._cond.notify()
            thread, self._thread = self._thread, None
        if thread is not None:
            thread.join(timeout)

    def _run(self) -> None:
        while True:
            with self._cond:
                while not (self._stop or self._frame is not None or self._status is not None):
                    self._cond.wait()
                if self._stop:
                    return
                frame, self._frame = self._frame, None
                t_result = self._frame_t_ns
                status, self._status = self._status, None
            try:  # the status first: it is what the operator reads
                if status is not None:
                    self._publish_status(status)
                if frame is not None:
                    self._publish_frame(frame, t_result)
            except Exception as exc:  # a bad item must not end the page
                with self._cond:
                    self._stats.errors += 1
                    n = self._stats.errors
                if n in (1, 10, 100) or n % 1000 == 0:
                    log.warning("operator page: %s: %s (%d errors)", type(exc).__name__,
                                exc, n)

    def _publish_status(self, status: OperatorStatus) -> None:
        d = status.to_dict()
        with self._cond:
            self._status_dict = d
            self._stats.statuses += 1
        self._send("status", d)

    def _publish_frame(self, f: LiveFrame | CameraPicture, t_result_ns: int) -> None:
        if isinstance(f, CameraPicture):
            with self._cond:
                overlay = self._overlay
            raw, camera, t, number = f.image, f.camera, f.t_capture_ns, f.frame
            overlay = _overlay_for(overlay, camera, raw.shape, t)
        else:
            assert f.raw_left is not None
            raw, camera, overlay, number = np.asarray(f.raw_left), f.camera, f, int(f.frame)
            t = f.raw_capture_ns if f.raw_capture_ns is not None else f.t_capture_ns
        if overlay is None:
            bgr = operator_bgr(raw, None, None)
        else:
            bgr = operator_bgr(raw, overlay.gas_mask,
                               operator_arrows(overlay.pixels, overlay.velocity3d, PAGE_ARROWS))
        jpeg = encode_jpeg(bgr, self.jpeg_quality)
        with self._cond:
            self._seq += 1
            enc = EncodedFrame(self._seq, number, int(t), jpeg, int(t_result_ns),
                               int(raw.shape[1]), int(raw.shape[0]), camera,
                               None if overlay is None else _capture_ns(overlay))
            self._stats.without_overlay += overlay is None
            self._frames[enc.seq] = enc
            while len(self._frames) > FRAMES_KEPT:
                self._frames.popitem(last=False)
            self._stats.frames_encoded += 1
        self._send("frame", enc.notice())

    def _send(self, kind: str, payload: dict[str, Any]) -> None:
        if self.broadcast is not None:
            self.broadcast(kind, json_text({**payload, "sent_ns": self.clock()}))


def _capture_ns(f: LiveFrame) -> int:
    """Capture time of a processed result's picture (its triple's first frame), UNIX ns."""
    return int(f.raw_capture_ns if f.raw_capture_ns is not None else f.t_capture_ns)


def _overlay_for(overlay: LiveFrame | None, camera: str, shape: tuple[int, ...],
                 t_capture_ns: int) -> LiveFrame | None:
    """The result whose gas is drawn on a camera picture, or None: none yet, of the other
    camera or another size, or older than :data:`OVERLAY_MAX_AGE_S` before the picture."""
    if overlay is None or overlay.gas_mask is None or overlay.camera != camera:
        return None
    if overlay.gas_mask.shape != shape[:2]:
        return None
    if t_capture_ns - _capture_ns(overlay) > OVERLAY_MAX_AGE_S * 1e9:
        return None
    return overlay
