"""GigE Vision / GenICam cameras through Aravis 0.8 (PyGObject, ``gi.repository.Aravis``).

Optional back end: this module is imported only when ``backend: aravis`` is chosen. It needs
the Debian package ``gir1.2-aravis-0.8`` and PyGObject in the virtualenv (the ``gige`` extra,
``pygobject<3.51``, which builds against ``libgirepository1.0-dev libcairo2-dev pkg-config``);
when they are missing the import fails with :class:`CameraBackendMissing` saying so.

Per buffer Aravis gives the device timestamp (ns, converted from the camera's tick counter),
the frame (block) id and the host wall-clock time of its arrival; lost frames and the
arrival time on the monotonic timeline follow from them (:mod:`drivers.camera.gige_buffers`).
Buffers Aravis could not complete (missing packets, timeouts) are dropped and counted as lost
too.

Reconnect: when no buffer has completed for ``reconnect_after_s`` (or Aravis signals that
control of the device was lost), the camera object is dropped and re-opened with the same
selector every ``retry_interval_s``, inside :meth:`grab`, so the acquisition loop keeps
running: it sees :class:`CameraDisconnected` while the device is away and frames again when
it is back.
"""

from __future__ import annotations

import logging
import threading
import time

import numpy as np

from drivers.camera.base import (
    PIXEL_FORMATS,
    Camera,
    CameraBackendMissing,
    CameraDisconnected,
    CameraError,
    CameraTimeout,
    Capture,
)
from drivers.camera.gige_buffers import arrival_mono_ns, frame_id_gap

try:
    import gi

    gi.require_version("Aravis", "0.8")
    from gi.repository import Aravis, GLib
except (ImportError, ValueError) as exc:  # ValueError: typelib for Aravis 0.8 not installed
    raise CameraBackendMissing(
        f"Aravis is not available ({exc}): install the Debian package gir1.2-aravis-0.8 and "
        "the Python extra 'ogiflow[gige]' (pygobject<3.51, which needs libgirepository1.0-dev "
        "libcairo2-dev pkg-config to build); tools/install.sh --dev does both"
    ) from exc

log = logging.getLogger(__name__)

#: Aravis' device list is process-global; discovery and opening must not run in two threads
#: at once (re-entrant: opening holds it while discovering).
_discovery_lock = threading.RLock()

#: Pixel formats this back end accepts (unpacked Mono; 10..16 bit arrive as uint16).
SUPPORTED_FORMATS = ("Mono8", "Mono10", "Mono12", "Mono14", "Mono16")


def list_devices() -> list[dict[str, str]]:
    """Discover GigE Vision (and USB3 Vision) devices: id, address, serial, model, vendor."""
    with _discovery_lock:
        Aravis.update_device_list()
        return [
            {
                "id": Aravis.get_device_id(i) or "",
                "address": Aravis.get_device_address(i) or "",
                "serial": Aravis.get_device_serial_nbr(i) or "",
                "model": Aravis.get_device_model(i) or "",
                "vendor": Aravis.get_device_vendor(i) or "",
            }
            for i in range(Aravis.get_n_devices())
        ]


def _has(device: Aravis.Device, feature: str) -> bool:
    """Whether the device implements a GenICam feature (unknown names are just absent)."""
    try:
        return bool(device.is_feature_available(feature))
    except GLib.Error:
        return False


class AravisCamera(Camera):
    """A GigE Vision camera through Aravis.

    Parameters
    ----------
    serial : str or None
        Select the device by serial number (discovery on all interfaces).
    address : str or None
        Select by IP address (or any Aravis device id such as ``"Vendor-Model-Serial"``); no
        discovery needed. With neither, the first device found is used.
    pixel_format : str
        ``Mono16`` (default), ``Mono14``, ``Mono12``, ``Mono10`` or ``Mono8``.
    fps : float or None
        Acquisition frame rate to set (None: leave the camera's setting).
    width, height, x, y : int or None
        Region of interest (None: leave as configured in the camera).
    n_buffers : int
        Buffers in the stream pool (a few frame periods of slack for the grab thread).
    packet_size : int or None
        GVSP packet size in bytes (None: let Aravis negotiate the largest that passes).
    reconnect_after_s : float
        Treat the camera as gone after this long without a completed buffer.
    retry_interval_s : float
        Time between re-open attempts while it is gone.
    temperature_features : sequence of str
        GenICam float features read as temperatures (those the device implements), once
        every ``temperature_interval_s``.
    temperature_interval_s : float
        Seconds between temperature reads (each is a network round trip).
    label : str
        Name for messages.
    """

    backend = "aravis"

    def __init__(
        self,
        serial: str | None = None,
        address: str | None = None,
        *,
        pixel_format: str = "Mono16",
        fps: float | None = 30.0,
        width: int | None = None,
        height: int | None = None,
        x: int | None = None,
        y: int | None = None,
        n_buffers: int = 16,
        packet_size: int | None = None,
        reconnect_after_s: float = 2.0,
        retry_interval_s: float = 1.0,
        temperature_features: tuple[str, ...] | list[str] = ("DeviceTemperature",),
        temperature_interval_s: float = 5.0,
        label: str | None = None,
    ) -> None:
        super().__init__(label=label or serial or address or "aravis")
        if pixel_format not in SUPPORTED_FORMATS:
            raise ValueError(
                f"pixel_format {pixel_format!r} is not supported; use one of {SUPPORTED_FORMATS}"
            )
        if serial is not None and address is not None:
            raise ValueError("give serial or address, not both")
        if n_buffers < 2:
            raise ValueError(f"n_buffers must be >= 2, got {n_buffers}")
        if reconnect_after_s <= 0 or retry_interval_s <= 0:
            raise ValueError("reconnect_after_s and retry_interval_s must be > 0")
        self.serial = serial
        self.address = address
        self.pixel_format = pixel_format
        self.fps = fps
        self.roi = (x, y, width, height)
        self.n_buffers = n_buffers
        self.packet_size = packet_size
        self.reconnect_after_s = reconnect_after_s
        self.retry_interval_s = retry_interval_s
        self.temperature_features = tuple(temperature_features)
        self.temperature_interval_s = temperature_interval_s
        self._cam: Aravis.Camera | None = None
        self._stream: Aravis.Stream | None = None
        self._control_lost = threading.Event()
        self._streaming = False
        self._connected = False
        self._last_frame_mono = 0.0
        self._next_retry = 0.0
        self._last_frame_id: int | None = None
        self._dtype = PIXEL_FORMATS[pixel_format]
        self._temps: dict[str, float] = {}
        self._temp_features: list[str] = []
        self._next_temp = 0.0

    # -- connection ----------------------------------------------------------------------
    def _device_id(self) -> str:
        if self.address is not None:
            return self.address
        devices = list_devices()
        if self.serial is None:
            if not devices:
                raise CameraDisconnected(f"{self.label}: no GigE Vision camera found")
            return devices[0]["id"]
        for d in devices:
            if d["serial"] == self.serial:
                return d["id"]
        found = ", ".join(f"{d['serial']}@{d['address']}" for d in devices) or "none"
        raise CameraDisconnected(f"{self.label}: no camera with serial {self.serial!r} "
                                 f"(found: {found})")

    def _connect(self) -> None:
        """Open and configure the device (not streaming)."""
        # Aravis' device list and discovery are process-global: one open at a time.
        with _discovery_lock:
            device_id = self._device_id()
            try:
                cam = Aravis.Camera.new(device_id)
            except GLib.Error as exc:
                raise CameraDisconnected(f"{self.label}: cannot open {device_id!r}: "
                                         f"{exc.message}") from None
            self._configure(cam, device_id)

    def _configure(self, cam: Aravis.Camera, device_id: str) -> None:
        try:
            available = cam.dup_available_pixel_formats_as_strings() or []
            if self.pixel_format not in available:
                raise CameraError(
                    f"{self.label}: camera does not offer {self.pixel_format} (it offers "
                    f"{', '.join(available)})"
                )
            x, y, w, h = self.roi
            if any(v is not None for v in self.roi):
                cx, cy, cw, ch = cam.get_region()
                cam.set_region(cx if x is None else x, cy if y is None else y,
                               cw if w is None else w, ch if h is None else h)
            cam.set_pixel_format_from_string(self.pixel_format)
            if self.fps is not None:
                cam.set_frame_rate(float(self.fps))
            if cam.is_gv_device():
                if self.packet_size is not None:
                    cam.gv_set_packet_size(int(self.packet_size))
                else:
                    cam.gv_auto_packet_size()
            device = cam.get_device()
            self._temp_features = [f for f in self.temperature_features if _has(device, f)]
            try:
                device.connect("control-lost", self._on_control_lost)
            except TypeError:  # signal absent in this build: the frame timeout still works
                pass
        except GLib.Error as exc:
            raise CameraError(f"{self.label}: configuring {device_id!r} failed: "
                              f"{exc.message}") from None
        self._cam = cam
        self._control_lost.clear()
        self._connected = True
        log.info("%s: opened %s (%s)", self.label, device_id, self.pixel_format)

    def _on_control_lost(self, *_args: object) -> None:
        # Called from an Aravis thread; only set a flag, the grab thread acts on it.
        self._control_lost.set()

    def _start_stream(self) -> None:
        assert self._cam is not None
        try:
            stream = self._cam.create_stream(None, None)
            payload = self._cam.get_payload()
            for _ in range(self.n_buffers):
                stream.push_buffer(Aravis.Buffer.new_allocate(payload))
            self._cam.start_acquisition()
        except GLib.Error as exc:
            raise CameraDisconnected(f"{self.label}: cannot start streaming: "
                                     f"{exc.message}") from None
        self._stream = stream
        self._last_frame_mono = time.monotonic()
        self._last_frame_id = None

    def _stop_acquisition(self) -> None:
        if self._cam is not None:
            try:
                self._cam.stop_acquisition()
            except GLib.Error as exc:  # device already gone: nothing to stop
                log.debug("%s: stop_acquisition: %s", self.label, exc.message)

    def _drop(self) -> None:
        """Forget the device objects (after a loss, or on close)."""
        if self._streaming:
            self._stop_acquisition()
        self._stream = None
        self._cam = None
        self._connected = False

    def _lost(self, why: str) -> CameraDisconnected:
        log.warning("%s: camera lost (%s); reconnecting every %.1f s", self.label, why,
                    self.retry_interval_s)
        self._drop()
        self.stats.disconnects += 1
        self._next_retry = time.monotonic()
        return CameraDisconnected(f"{self.label}: camera lost ({why})")

    def _try_reconnect(self) -> bool:
        now = time.monotonic()
        if now < self._next_retry:
            return False
        self._next_retry = now + self.retry_interval_s
        try:
            self._connect()
            self._start_stream()
        except CameraDisconnected as exc:
            log.debug("%s: reconnect failed: %s", self.label, exc)
            self._drop()
            return False
        self.stats.reconnects += 1
        log.info("%s: reconnected", self.label)
        return True

    # -- Camera hooks --------------------------------------------------------------------
    def _open(self) -> None:
        self._connect()

    def _start(self) -> None:
        self._start_stream()
        self._streaming = True

    def _grab(self, timeout: float) -> Capture:
        deadline = time.monotonic() + timeout
        while True:
            if not self._connected:
                if not self._try_reconnect():
                    wait = min(self._next_retry, deadline) - time.monotonic()
                    if wait > 0:
                        time.sleep(wait)
                    if time.monotonic() >= deadline:
                        raise CameraDisconnected(f"{self.label}: camera away, reconnecting")
                    continue
            if self._control_lost.is_set():
                raise self._lost("control lost")
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise CameraTimeout(f"{self.label}: no frame within {timeout} s")
            assert self._stream is not None
            buf = self._stream.timeout_pop_buffer(max(1, int(min(remaining, 0.2) * 1e6)))
            if buf is None:
                if time.monotonic() - self._last_frame_mono > self.reconnect_after_s:
                    raise self._lost(f"no frame for {self.reconnect_after_s} s")
                continue
            mono_ns = time.monotonic_ns()
            real_ns = time.time_ns()
            try:
                capture = self._to_capture(buf, mono_ns, real_ns)
            finally:
                self._stream.push_buffer(buf)
            if capture is not None:
                return capture

    def _to_capture(self, buf: Aravis.Buffer, mono_ns: int, real_ns: int) -> Capture | None:
        status = buf.get_status()
        frame_id = int(buf.get_frame_id())
        if status != Aravis.BufferStatus.SUCCESS:
            # Incomplete frame: dropped; the id gap of the next good one counts it as lost.
            log.debug("%s: frame %d dropped: %s", self.label, frame_id, status.value_nick)
            self._last_frame_mono = time.monotonic()
            return None
        self._last_frame_mono = time.monotonic()
        w, h = buf.get_image_width(), buf.get_image_height()
        data = buf.get_image_data()
        expected = w * h * self._dtype.itemsize
        if len(data) < expected:
            log.warning("%s: frame %d has %d bytes, expected %d; dropped", self.label,
                        frame_id, len(data), expected)
            return None
        image = np.frombuffer(data, dtype=self._dtype.newbyteorder("<"), count=w * h)
        image = image.reshape(h, w).astype(self._dtype, copy=True)
        lost = frame_id_gap(self._last_frame_id, frame_id)
        self._last_frame_id = frame_id
        host_ns = arrival_mono_ns(int(buf.get_system_timestamp()), mono_ns, real_ns)
        device_ts = int(buf.get_timestamp())
        return Capture(
            image=image,
            pixel_format=self.pixel_format,
            host_ns=host_ns,
            device_ts_ns=device_ts if device_ts > 0 else None,
            device_frame_id=frame_id,
            lost=lost,
            temperatures=self._temperatures(),
        )

    def _temperatures(self) -> dict[str, float]:
        now = time.monotonic()
        if self._temp_features and now >= self._next_temp and self._cam is not None:
            self._next_temp = now + self.temperature_interval_s
            device = self._cam.get_device()
            for name in self._temp_features:
                try:
                    self._temps[name] = float(device.get_float_feature_value(name))
                except GLib.Error as exc:
                    log.debug("%s: reading %s failed: %s", self.label, name, exc.message)
        return self._temps

    def _stop(self) -> None:
        self._stop_acquisition()
        self._streaming = False
        self._stream = None

    def _close(self) -> None:
        self._drop()
