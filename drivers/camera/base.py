"""The camera interface: one frame type, one error hierarchy, one base class.

Every back end (Aravis GigE Vision, OpenCV, replay, simulated) is a subclass of
:class:`Camera`. The base class owns the life cycle (open -> start -> grab ... -> stop ->
close), the host sequence number, host arrival stamping and the counters; a back end
overrides the small ``_open``/``_start``/``_grab``/``_stop``/``_close`` methods (the pattern of
python-can's ``BusABC._recv_internal``).

Time: ``Frame.host_ns`` is ``time.monotonic_ns()`` taken when the frame reached the host (or,
for replay, the value recorded at the original arrival). Pairing and clock estimation work on
this monotonic timeline (see ``appliance.runtime.clock``); wall-clock time is only logged alongside.
"""

from __future__ import annotations

import abc
import enum
import time
from dataclasses import dataclass, field
from types import TracebackType

import numpy as np

#: Pixel formats a frame may carry, with the numpy dtype of its image.
PIXEL_FORMATS: dict[str, np.dtype] = {
    "Mono8": np.dtype(np.uint8),
    "Mono10": np.dtype(np.uint16),
    "Mono12": np.dtype(np.uint16),
    "Mono14": np.dtype(np.uint16),
    "Mono16": np.dtype(np.uint16),
}


class CameraError(Exception):
    """Any camera failure; the message names the camera and the problem."""


class CameraTimeout(CameraError, TimeoutError):
    """No frame arrived within the timeout given to :meth:`Camera.grab`."""


class CameraDisconnected(CameraError):
    """The device is gone (unplugged, powered off, network lost); the back end keeps trying
    to reconnect on later calls to :meth:`Camera.grab` where it can."""


class EndOfStream(CameraError):
    """A finite source (file, folder, recording) has delivered its last frame."""


class CameraBackendMissing(CameraError, ImportError):
    """The optional packages a back end needs are not installed (the message says which)."""


@dataclass(frozen=True)
class Frame:
    """One image as it arrived from a camera.

    Attributes
    ----------
    image : numpy.ndarray
        (H, W) ``uint16`` counts (Mono10..Mono16, unpacked, little-endian values) or ``uint8``
        for 8-bit sources (Mono8). Not copied again by consumers; treat as read-only.
    pixel_format : str
        GenICam pixel format name, one of :data:`PIXEL_FORMATS` (e.g. ``"Mono16"``).
    host_ns : int
        ``time.monotonic_ns()`` when the frame reached the host (replay: as recorded).
    seq : int
        Host sequence number: 0, 1, 2, ... per camera since ``start()``; restarts of the
        device do not reset it (replay keeps the recorded number).
    device_ts_ns : int or None
        The device's own timestamp of the frame in ns, on the device clock (None when the
        device has no clock, e.g. V4L2 or video files).
    device_frame_id : int or None
        The device's frame (block) id; GigE Vision 1.x ids are 16 bit and wrap.
    lost : int
        Frames the device or transport reported lost immediately before this frame (gaps in
        the device frame id, incomplete buffers dropped by the driver).
    temperatures : dict of str to float
        Camera temperatures in degrees Celsius by sensor name, where the device exposes them
        (read at a low rate; the latest reading is repeated).
    """

    image: np.ndarray
    pixel_format: str
    host_ns: int
    seq: int
    device_ts_ns: int | None = None
    device_frame_id: int | None = None
    lost: int = 0
    temperatures: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.pixel_format not in PIXEL_FORMATS:
            raise ValueError(
                f"unknown pixel format {self.pixel_format!r}; expected one of "
                f"{sorted(PIXEL_FORMATS)}"
            )
        expected = PIXEL_FORMATS[self.pixel_format]
        if self.image.ndim != 2 or self.image.dtype != expected:
            raise ValueError(
                f"a {self.pixel_format} frame needs a 2-D {expected} image, got "
                f"{self.image.ndim}-D {self.image.dtype} of shape {self.image.shape}"
            )


@dataclass(frozen=True)
class Capture:
    """What a back end's ``_grab`` returns; the base class turns it into a :class:`Frame`.

    ``host_ns`` None means "stamp now"; ``seq`` None means "next host sequence number"
    (replay sets both to keep the recorded values).
    """

    image: np.ndarray
    pixel_format: str
    host_ns: int | None = None
    device_ts_ns: int | None = None
    device_frame_id: int | None = None
    lost: int = 0
    temperatures: dict[str, float] = field(default_factory=dict)
    seq: int | None = None


class State(enum.Enum):
    """Life-cycle state of a camera."""

    CLOSED = "closed"
    OPEN = "open"
    STREAMING = "streaming"


@dataclass
class CameraStats:
    """Counters a camera keeps since ``open()`` (read them any time; plain ints)."""

    frames: int = 0
    lost: int = 0
    timeouts: int = 0
    disconnects: int = 0
    reconnects: int = 0
    skipped: int = 0  # unreadable or malformed inputs a replay/file back end skipped


class Camera(abc.ABC):
    """Base class of every camera back end.

    Parameters
    ----------
    label : str
        Name used in messages and logs (e.g. ``"left"``).

    Notes
    -----
    Use as a context manager or call ``open()``, ``start()``, ``grab()`` repeatedly, then
    ``stop()`` and ``close()``. ``grab`` is meant to be called from one acquisition thread per
    camera; the methods are not re-entrant.
    """

    #: Registry name of the back end (set by subclasses).
    backend: str = ""

    def __init__(self, *, label: str = "camera") -> None:
        self.label = label
        self.state = State.CLOSED
        self.stats = CameraStats()
        self._seq = 0

    # -- public life cycle ---------------------------------------------------------------
    def open(self) -> None:
        """Connect to the device or source and configure it (not yet streaming)."""
        if self.state is not State.CLOSED:
            raise CameraError(f"{self.label}: open() called while {self.state.value}")
        self.stats = CameraStats()
        self._open()
        self.state = State.OPEN

    def start(self) -> None:
        """Start streaming; host sequence numbers restart at 0."""
        if self.state is not State.OPEN:
            raise CameraError(
                f"{self.label}: start() needs an open camera, it is {self.state.value}"
            )
        self._seq = 0
        self._start()
        self.state = State.STREAMING

    def grab(self, timeout: float = 1.0) -> Frame:
        """Return the next frame, waiting at most ``timeout`` seconds.

        Raises
        ------
        CameraTimeout
            No frame within ``timeout``.
        CameraDisconnected
            The device is gone; later calls keep trying to reconnect where the back end can.
        EndOfStream
            A finite source is exhausted.
        """
        if self.state is not State.STREAMING:
            raise CameraError(
                f"{self.label}: grab() needs a started camera, it is {self.state.value}"
            )
        if not timeout > 0:
            raise ValueError(f"timeout must be > 0 s, got {timeout}")
        try:
            cap = self._grab(timeout)
        except CameraTimeout:
            self.stats.timeouts += 1
            raise
        host_ns = time.monotonic_ns() if cap.host_ns is None else cap.host_ns
        seq = self._seq if cap.seq is None else cap.seq
        self._seq = seq + 1
        self.stats.frames += 1
        self.stats.lost += cap.lost
        return Frame(
            image=cap.image,
            pixel_format=cap.pixel_format,
            host_ns=host_ns,
            seq=seq,
            device_ts_ns=cap.device_ts_ns,
            device_frame_id=cap.device_frame_id,
            lost=cap.lost,
            temperatures=dict(cap.temperatures),
        )

    def stop(self) -> None:
        """Stop streaming (the camera stays open and may be started again)."""
        if self.state is State.STREAMING:
            self._stop()
            self.state = State.OPEN

    def close(self) -> None:
        """Stop if needed and release the device; safe to call twice."""
        if self.state is State.STREAMING:
            self.stop()
        if self.state is State.OPEN:
            self._close()
            self.state = State.CLOSED

    def __enter__(self) -> Camera:
        self.open()
        self.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.label!r} {self.state.value}>"

    # -- what a back end implements ------------------------------------------------------
    @abc.abstractmethod
    def _open(self) -> None:
        """Connect and configure."""

    def _start(self) -> None:  # noqa: B027 - optional hook
        """Begin streaming (default: nothing to do)."""

    @abc.abstractmethod
    def _grab(self, timeout: float) -> Capture:
        """Wait up to ``timeout`` s for the next frame; raise CameraTimeout if none."""

    def _stop(self) -> None:  # noqa: B027 - optional hook
        """End streaming (default: nothing to do)."""

    @abc.abstractmethod
    def _close(self) -> None:
        """Release the device."""
