"""Message schemas of the appliance's MCAP logs, each defined once, here.

Two kinds:

- Foxglove well-known schemas (protobuf, from ``foxglove-schemas-protobuf``) where one fits:
  ``foxglove.RawImage`` for raw 16-bit frames, ``foxglove.CompressedImage`` for JPEG/PNG
  images, ``foxglove.Grid`` for float fields (flow, disparity, velocity). Foxglove and
  ``rerun mcap convert`` open them as they are. Camera frames (RawImage plus
  ``ogiflow.FrameInfo``) are encoded by :mod:`drivers.camera.mcap_format`, the one owner of
  that encoding (the MCAP replay camera decodes it there, and ``drivers`` cannot import
  ``appliance``); :func:`frame_records` hands its messages to the recorder.
- Our own documented JSON schemas (schema encoding ``jsonschema``, message encoding ``json``)
  for wind samples, wind in the camera frame, stereo pairs, per-frame scene-flow summaries and
  health snapshots, defined and checked in :mod:`appliance.recording.jsonschemas` and
  re-exported here.

Times: ``*_mono_ns`` is the host's ``time.monotonic_ns()`` at arrival (what pairing uses);
``*_wall_ns`` is UNIX time in ns for humans; MCAP ``log_time`` is wall-clock ns at recording.
Camera frame: the left camera's, X right, Y down, Z forward (metres, m/s). Directional angles
(paper footnote 1) are the angles of the velocity vector to the X, Y and Z axes, in degrees:
``arccos(v_i / |v|)``.

:data:`TOPICS` maps each topic the appliance writes to its schema.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.Grid_pb2 import Grid
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField

from appliance.recording.jsonschemas import (
    HEALTH,
    LEAK_EVENT,
    SCENEFLOW_SUMMARY,
    STEREO_PAIR,
    WIND_CAMERA,
    WIND_SAMPLE,
    decode_json,
    encode_json,
    validate_json,
)
from appliance.recording.message import MessageSchema, Record
from drivers.camera import mcap_format
from drivers.camera.base import Frame

__all__ = [
    "COMPRESSED_IMAGE",
    "FRAME_INFO",
    "GRID",
    "HEALTH",
    "LEAK_EVENT",
    "RAW_IMAGE",
    "SCENEFLOW_SUMMARY",
    "STEREO_PAIR",
    "TOPICS",
    "WIND_CAMERA",
    "WIND_SAMPLE",
    "MessageSchema",
    "Record",
    "compressed_image",
    "decode_json",
    "encode_json",
    "frame_records",
    "grid",
    "grid_to_array",
    "validate_json",
]

# --------------------------------------------------------------------------- protobuf


def _proto_schema(message_class: Any) -> MessageSchema:
    desc = message_class.DESCRIPTOR
    # The same FileDescriptorSet builder as the camera frames, so equal schemas are equal bytes.
    data = mcap_format._file_descriptor_set(desc)
    return MessageSchema(desc.full_name, "protobuf", data, "protobuf")


#: 16-bit (or 8-bit) raw camera frames, as :func:`drivers.camera.mcap_format.frame_to_messages`
#: writes them.
RAW_IMAGE = MessageSchema(mcap_format.IMAGE_SCHEMA_NAME, "protobuf",
                          mcap_format.IMAGE_SCHEMA_DATA, "protobuf")
#: Timing and device metadata of each camera frame (beside its RawImage).
FRAME_INFO = MessageSchema(mcap_format.FRAME_INFO_SCHEMA_NAME, "jsonschema",
                           mcap_format.FRAME_INFO_SCHEMA_DATA, "json")
#: JPEG/PNG images (differential images, masks, visualisations).
COMPRESSED_IMAGE = _proto_schema(CompressedImage)
#: Float fields on the pixel grid: flow (u, v), disparity, disparity change, velocity.
GRID = _proto_schema(Grid)


_FRAME_SCHEMAS = {RAW_IMAGE.name: RAW_IMAGE, FRAME_INFO.name: FRAME_INFO}


def frame_records(side: str, frame: Frame, wall_ns: int) -> list[Record]:
    """One camera frame as the recorder's messages: ``/camera/<side>/image`` (RawImage) and
    ``/camera/<side>/frame_info``, encoded by :func:`drivers.camera.mcap_format.frame_to_messages`.

    Parameters
    ----------
    side
        ``left`` or ``right``.
    frame
        The frame as the camera delivered it ((H, W) uint16 or uint8 counts).
    wall_ns
        Wall-clock capture time, UNIX ns (MCAP log time); ``frame.host_ns`` is the publish time.
    """
    return [Record(m.topic, _FRAME_SCHEMAS[m.schema_name], m.data, m.log_time, m.publish_time)
            for m in mcap_format.frame_to_messages(side, frame, wall_ns)]


def _set_stamp(msg: Any, stamp_ns: int) -> None:
    msg.timestamp.seconds, msg.timestamp.nanos = divmod(int(stamp_ns), 1_000_000_000)


def compressed_image(data: bytes, stamp_ns: int, frame_id: str, fmt: str = "jpeg") -> bytes:
    """Serialize encoded image bytes (``jpeg``, ``png``) as ``foxglove.CompressedImage``."""
    msg = CompressedImage(frame_id=frame_id, data=bytes(data), format=fmt)
    _set_stamp(msg, stamp_ns)
    return msg.SerializeToString()


def grid(field: np.ndarray, stamp_ns: int, frame_id: str, names: tuple[str, ...],
         cell_size: float = 1.0) -> bytes:
    """Serialize a float field on the pixel grid as ``foxglove.Grid`` (FLOAT32 cells).

    Parameters
    ----------
    field
        (H, W) or (H, W, C) array, converted to float32; C must equal ``len(names)``.
        Row 0 is the image's top row (Grid's origin is at its pose, x along columns).
    names
        Cell field names, e.g. ``("u", "v")`` for flow in px/frame, ``("d",)`` for disparity
        in px, ``("vx", "vy", "vz")`` for velocity in m/s. NaN marks cells without a value.
    cell_size
        Size of one cell in the grid frame's units (1.0: pixels).
    """
    field = np.asarray(field, dtype="<f4")
    if field.ndim == 2:
        field = field[:, :, None]
    if field.ndim != 3 or field.shape[2] != len(names):
        raise ValueError(f"grid expects (H, W) or (H, W, {len(names)}) for fields {names}, "
                         f"got shape {field.shape}")
    _, w, c = field.shape
    field = np.ascontiguousarray(field)
    msg = Grid(frame_id=frame_id, column_count=w, row_stride=w * c * 4, cell_stride=c * 4,
               data=field.tobytes())
    _set_stamp(msg, stamp_ns)
    msg.cell_size.x = msg.cell_size.y = cell_size
    msg.pose.orientation.w = 1.0
    for i, name in enumerate(names):
        msg.fields.add(name=name, offset=4 * i, type=PackedElementField.FLOAT32)
    return msg.SerializeToString()


def grid_to_array(payload: bytes) -> tuple[np.ndarray, tuple[str, ...], int]:
    """Decode a ``foxglove.Grid`` written by :func:`grid`: ((H, W, C) float32, names, stamp_ns)."""
    msg = Grid()
    msg.ParseFromString(payload)
    c = msg.cell_stride // 4
    if any(f.type != PackedElementField.FLOAT32 for f in msg.fields) or c != len(msg.fields):
        raise ValueError("grid_to_array reads packed FLOAT32 grids only")
    rows = len(msg.data) // msg.row_stride
    arr = np.frombuffer(msg.data, "<f4").reshape(rows, msg.column_count, c).astype(np.float32)
    stamp = msg.timestamp.seconds * 1_000_000_000 + msg.timestamp.nanos
    return arr, tuple(f.name for f in msg.fields), stamp


#: Topic -> schema of everything the appliance writes (one place for names and schemas).
TOPICS: dict[str, MessageSchema] = {
    # Raw frames: encoded by drivers.camera.mcap_format (see frame_records).
    "/camera/left/image": RAW_IMAGE,
    "/camera/left/frame_info": FRAME_INFO,
    "/camera/right/image": RAW_IMAGE,
    "/camera/right/frame_info": FRAME_INFO,
    "/wind/raw": WIND_SAMPLE,
    "/wind/camera": WIND_CAMERA,
    "/pairs": STEREO_PAIR,
    "/cam/left/diff": COMPRESSED_IMAGE,
    "/cam/right/diff": COMPRESSED_IMAGE,
    "/sceneflow/flow": GRID,
    "/sceneflow/disparity": GRID,
    "/sceneflow/velocity": GRID,
    "/sceneflow/mask": COMPRESSED_IMAGE,
    "/sceneflow/summary": SCENEFLOW_SUMMARY,
    "/health": HEALTH,
    "/events": LEAK_EVENT,
}
