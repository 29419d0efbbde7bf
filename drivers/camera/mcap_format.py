"""How camera frames are stored in MCAP: encode for the recorder, decode for replay.

Per camera side (``left``/``right``) a frame becomes two messages with the same times:

``/camera/<side>/image``
    ``foxglove.RawImage`` (protobuf; schema = FileDescriptorSet of Foxglove's RawImage.proto
    and its dependencies, so Foxglove and ``rerun mcap convert`` open it as is).
    ``encoding`` ``mono16`` (little-endian uint16 counts, also for Mono10..Mono14) or
    ``mono8``; ``timestamp`` = wall-clock capture time; ``frame_id`` = ``camera_<side>``.
``/camera/<side>/frame_info``
    ``ogiflow.FrameInfo`` (JSON, JSON Schema in :data:`FRAME_INFO_SCHEMA`): ``side``,
    ``host_ns`` (host monotonic arrival), ``device_ts_ns`` (device clock, or null),
    ``device_frame_id`` (or null), ``seq`` (host sequence number), ``lost`` (frames lost
    just before), ``temperatures`` (deg C by sensor), ``pixel_format`` (GenICam name) and
    ``wall_ns`` (the wall-clock time used as log time).

MCAP times: ``log_time`` = wall-clock ns (for people and tools), ``publish_time`` = host
monotonic ns at arrival (what pairing and replay use). The two messages of a frame share
both, which is how the reader joins them.

Reading uses the non-seeking reader in file order, so a file cut by a crash still yields
every frame in its completed chunks (only the open chunk is lost).
"""

from __future__ import annotations

import json
import logging
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from google.protobuf import descriptor_pb2
from google.protobuf.message import DecodeError
from mcap.exceptions import InvalidMagic, McapError
from mcap.reader import NonSeekingReader
from mcap.writer import Writer

from drivers.camera.base import PIXEL_FORMATS, CameraError, Frame

log = logging.getLogger(__name__)

SIDES = ("left", "right")
IMAGE_SCHEMA_NAME = RawImage.DESCRIPTOR.full_name  # "foxglove.RawImage"
FRAME_INFO_SCHEMA_NAME = "ogiflow.FrameInfo"

#: JSON Schema of the ``/camera/<side>/frame_info`` messages.
FRAME_INFO_SCHEMA: dict = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": FRAME_INFO_SCHEMA_NAME,
    "description": "Timing and device metadata of one camera frame (ogiflow).",
    "type": "object",
    "properties": {
        "side": {"type": "string", "enum": list(SIDES)},
        "host_ns": {"type": "integer", "description": "host monotonic time at arrival, ns"},
        "wall_ns": {"type": "integer", "description": "wall-clock time, ns since 1970"},
        "device_ts_ns": {"type": ["integer", "null"], "description": "device clock, ns"},
        "device_frame_id": {"type": ["integer", "null"]},
        "seq": {"type": "integer", "description": "host sequence number of the camera"},
        "lost": {"type": "integer", "description": "frames lost just before this one"},
        "temperatures": {
            "type": "object",
            "additionalProperties": {"type": "number"},
            "description": "deg C by sensor name",
        },
        "pixel_format": {"type": "string", "enum": list(PIXEL_FORMATS)},
    },
    "required": ["side", "host_ns", "seq", "pixel_format"],
}

_ENCODINGS = {np.dtype(np.uint16): ("mono16", 2), np.dtype(np.uint8): ("mono8", 1)}
_DTYPES = {"mono16": np.dtype("<u2"), "16UC1": np.dtype("<u2"), "mono8": np.dtype(np.uint8),
           "8UC1": np.dtype(np.uint8)}  # fmt: skip


def image_topic(side: str) -> str:
    """``/camera/<side>/image``."""
    return f"/camera/{side}/image"


def info_topic(side: str) -> str:
    """``/camera/<side>/frame_info``."""
    return f"/camera/{side}/frame_info"


def _file_descriptor_set(descriptor) -> bytes:
    """Serialized FileDescriptorSet of a protobuf message type and all its imports."""
    fds = descriptor_pb2.FileDescriptorSet()
    seen: set[str] = set()

    def add(fd) -> None:
        if fd.name in seen:
            return
        seen.add(fd.name)
        for dep in fd.dependencies:
            add(dep)
        proto = descriptor_pb2.FileDescriptorProto()
        fd.CopyToProto(proto)
        fds.file.append(proto)

    add(descriptor.file)
    return fds.SerializeToString()


IMAGE_SCHEMA_DATA: bytes = _file_descriptor_set(RawImage.DESCRIPTOR)
FRAME_INFO_SCHEMA_DATA: bytes = json.dumps(FRAME_INFO_SCHEMA, separators=(",", ":")).encode()


@dataclass(frozen=True)
class McapMessage:
    """One message ready for ``mcap.writer.Writer`` (register schema and channel once)."""

    topic: str
    schema_name: str
    schema_encoding: str
    schema_data: bytes
    message_encoding: str
    data: bytes
    log_time: int
    publish_time: int


def frame_to_messages(side: str, frame: Frame, wall_ns: int) -> list[McapMessage]:
    """Encode one frame as its image and frame-info messages.

    Parameters
    ----------
    side : {"left", "right"}
    frame : Frame
    wall_ns : int
        Wall-clock time of the frame in ns since 1970 (``time.time_ns()`` at arrival); used
        as MCAP log time and RawImage timestamp. ``frame.host_ns`` is the publish time.
    """
    if side not in SIDES:
        raise ValueError(f"side must be 'left' or 'right', got {side!r}")
    image = frame.image
    encoding, nbytes = _ENCODINGS[image.dtype]
    h, w = image.shape
    msg = RawImage(
        frame_id=f"camera_{side}",
        width=w,
        height=h,
        encoding=encoding,
        step=w * nbytes,
        data=np.ascontiguousarray(image, dtype=image.dtype.newbyteorder("<")).tobytes(),
    )
    msg.timestamp.FromNanoseconds(int(wall_ns))
    info = {
        "side": side,
        "host_ns": int(frame.host_ns),
        "wall_ns": int(wall_ns),
        "device_ts_ns": frame.device_ts_ns,
        "device_frame_id": frame.device_frame_id,
        "seq": int(frame.seq),
        "lost": int(frame.lost),
        "temperatures": {k: float(v) for k, v in frame.temperatures.items()},
        "pixel_format": frame.pixel_format,
    }
    common = dict(log_time=int(wall_ns), publish_time=int(frame.host_ns))
    return [
        McapMessage(image_topic(side), IMAGE_SCHEMA_NAME, "protobuf", IMAGE_SCHEMA_DATA,
                    "protobuf", msg.SerializeToString(), **common),
        McapMessage(info_topic(side), FRAME_INFO_SCHEMA_NAME, "jsonschema",
                    FRAME_INFO_SCHEMA_DATA, "json",
                    json.dumps(info, separators=(",", ":")).encode(), **common),
    ]  # fmt: skip


class ChannelCache:
    """Registers each schema and channel once per ``Writer`` and writes messages.

    >>> cache = ChannelCache(writer)                      # doctest: +SKIP
    >>> cache.write(frame_to_messages("left", f, wall))   # doctest: +SKIP
    """

    def __init__(self, writer: Writer) -> None:
        self.writer = writer
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}

    def channel_id(self, m: McapMessage) -> int:
        """The channel id of ``m.topic``, registering schema and channel on first use."""
        if m.topic not in self._channels:
            if m.schema_name not in self._schemas:
                self._schemas[m.schema_name] = self.writer.register_schema(
                    name=m.schema_name, encoding=m.schema_encoding, data=m.schema_data
                )
            self._channels[m.topic] = self.writer.register_channel(
                topic=m.topic, message_encoding=m.message_encoding,
                schema_id=self._schemas[m.schema_name],
            )  # fmt: skip
        return self._channels[m.topic]

    def write(self, messages: list[McapMessage]) -> None:
        """Add the messages to the file."""
        for m in messages:
            self.writer.add_message(
                channel_id=self.channel_id(m), log_time=m.log_time, data=m.data,
                publish_time=m.publish_time,
            )  # fmt: skip


def decode_image(data: bytes) -> tuple[np.ndarray, int]:
    """RawImage bytes -> ((H, W) uint8/uint16 image, timestamp ns); ValueError if malformed."""
    msg = RawImage()
    try:
        msg.ParseFromString(data)
    except DecodeError as exc:
        raise ValueError(f"not a RawImage ({exc})") from None
    dtype = _DTYPES.get(msg.encoding)
    if dtype is None:
        raise ValueError(f"unsupported RawImage encoding {msg.encoding!r}")
    w, h, step = msg.width, msg.height, msg.step
    if w == 0 or h == 0 or step < w * dtype.itemsize or len(msg.data) < step * h:
        raise ValueError(f"RawImage {w}x{h} step {step} with {len(msg.data)} bytes is inconsistent")
    rows = np.frombuffer(msg.data, dtype=np.uint8, count=step * h).reshape(h, step)
    image = rows[:, : w * dtype.itemsize].copy().view(dtype).reshape(h, w)
    return image.astype(dtype.newbyteorder("="), copy=False), msg.timestamp.ToNanoseconds()


class FrameLogReader:
    """Iterate ``(side, Frame)`` over the camera messages of an MCAP file, in file order.

    Attributes after iteration: ``truncated`` (the file ended inside a record or chunk, e.g.
    after a crash; everything before was delivered), ``skipped`` (malformed messages).
    """

    def __init__(self, source: str | Path | IO[bytes], sides: tuple[str, ...] = SIDES) -> None:
        self.source = source
        self.sides = tuple(sides)
        self.truncated = False
        self.skipped = 0

    def __iter__(self) -> Iterator[tuple[str, Frame]]:
        if isinstance(self.source, (str, Path)):
            try:
                stream: IO[bytes] = open(self.source, "rb")
            except OSError as exc:
                raise CameraError(f"cannot open recording {self.source}: {exc}") from None
            try:
                yield from self._iter(stream)
            finally:
                stream.close()
        else:
            yield from self._iter(self.source)

    def _iter(self, stream: IO[bytes]) -> Iterator[tuple[str, Frame]]:
        topics = [image_topic(s) for s in self.sides] + [info_topic(s) for s in self.sides]
        images: dict[tuple[str, int], np.ndarray] = {}
        infos: dict[tuple[str, int], dict] = {}
        bare_seq = dict.fromkeys(self.sides, 0)
        reader = NonSeekingReader(stream)
        # File order (log_time_order=False): sorting would read the whole file first.
        messages = reader.iter_messages(topics=topics, log_time_order=False)
        try:
            for _schema, channel, message in messages:
                side = channel.topic.split("/")[2]
                key = (side, message.publish_time)
                try:
                    if channel.topic.endswith("/image"):
                        images[key] = decode_image(message.data)[0]
                    else:
                        infos[key] = json.loads(message.data)
                except (ValueError, UnicodeDecodeError) as exc:
                    self.skipped += 1
                    log.warning("%s at %d: skipped: %s", channel.topic, message.publish_time, exc)
                    continue
                if key in images and key in infos:
                    frame = self._frame(images.pop(key), infos.pop(key), message.publish_time)
                    if frame is not None:
                        yield side, frame
                # An image whose frame_info never came (a file from another writer): once
                # two newer images of its side are waiting, deliver it with what it has.
                waiting = sorted(k for k in images if k[0] == side)
                for k in waiting[:-2]:
                    yield side, self._bare(images.pop(k), k, bare_seq)
        except InvalidMagic as exc:
            raise CameraError(f"{self.source}: not an MCAP file ({exc})") from None
        except (McapError, struct.error, EOFError) as exc:
            # A file cut by a crash or power loss: the open chunk is lost, the rest was read.
            self.truncated = True
            log.warning("%s: recording ends early (%s: %s); frames up to there were read",
                        self.source, type(exc).__name__, exc)  # fmt: skip
        for key in sorted(images, key=lambda k: k[1]):
            yield key[0], self._bare(images[key], key, bare_seq)

    def _frame(self, image: np.ndarray, info: dict, publish: int) -> Frame | None:
        try:
            temps = info.get("temperatures") or {}
            return Frame(
                image=image,
                pixel_format=str(info.get("pixel_format") or _default_format(image)),
                host_ns=int(info.get("host_ns", publish)),
                seq=int(info["seq"]),
                device_ts_ns=_opt_int(info.get("device_ts_ns")),
                device_frame_id=_opt_int(info.get("device_frame_id")),
                lost=int(info.get("lost", 0)),
                temperatures={str(k): float(v) for k, v in temps.items()},
            )
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            self.skipped += 1
            log.warning("frame at %d: bad frame_info: %s", publish, exc)
            return None

    @staticmethod
    def _bare(image: np.ndarray, key: tuple[str, int], seqs: dict[str, int]) -> Frame:
        """A frame known only from its image message: arrival = publish time."""
        side, publish = key
        seq = seqs[side]
        seqs[side] = seq + 1
        return Frame(image=image, pixel_format=_default_format(image), host_ns=publish, seq=seq)


def _default_format(image: np.ndarray) -> str:
    return "Mono16" if image.dtype == np.uint16 else "Mono8"


def _opt_int(v: object) -> int | None:
    return None if v is None else int(v)  # type: ignore[arg-type]


def iter_frames(
    source: str | Path | IO[bytes], sides: tuple[str, ...] = SIDES
) -> Iterator[tuple[str, Frame]]:
    """``(side, Frame)`` for every camera frame in an MCAP recording, in file order.

    Truncated files (crash while recording) yield every frame of their completed chunks and
    then stop with a warning; use :class:`FrameLogReader` to know whether that happened.
    """
    return iter(FrameLogReader(source, sides))
