"""Message schemas of the appliance's MCAP logs, each defined once, here.

Two kinds:

- Foxglove well-known schemas (protobuf, from ``foxglove-schemas-protobuf``) where one fits:
  ``foxglove.RawImage`` for raw 16-bit frames, ``foxglove.CompressedImage`` for JPEG/PNG
  images, ``foxglove.Grid`` for float fields (flow, disparity, velocity). Foxglove and
  ``rerun mcap convert`` open them as they are.
- Our own documented JSON schemas (schema encoding ``jsonschema``, message encoding ``json``)
  for wind samples, wind in the camera frame, stereo pairs, per-frame scene-flow summaries and
  health snapshots. The JSON Schema text is stored in every file's schema record, so a file
  documents itself.

Times: ``*_mono_ns`` is the host's ``time.monotonic_ns()`` at arrival (what pairing uses);
``*_wall_ns`` is UNIX time in ns for humans; MCAP ``log_time`` is wall-clock ns at recording.
Camera frame: the left camera's, X right, Y down, Z forward (metres, m/s). Directional angles
(paper footnote 1) are the angles of the velocity vector to the X, Y and Z axes, in degrees:
``arccos(v_i / |v|)``.

:data:`TOPICS` maps each topic the appliance writes to its schema.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.Grid_pb2 import Grid
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from google.protobuf import descriptor_pb2
from google.protobuf.descriptor import FileDescriptor

__all__ = [
    "COMPRESSED_IMAGE",
    "GRID",
    "HEALTH",
    "RAW_IMAGE",
    "SCENEFLOW_SUMMARY",
    "STEREO_PAIR",
    "TOPICS",
    "WIND_CAMERA",
    "WIND_SAMPLE",
    "MessageSchema",
    "compressed_image",
    "decode_json",
    "encode_json",
    "grid",
    "grid_to_array",
    "raw_image",
    "raw_image_to_array",
    "validate_json",
]


@dataclass(frozen=True)
class MessageSchema:
    """One schema as stored in an MCAP schema record, plus its channels' message encoding.

    Attributes
    ----------
    name
        Schema name (``foxglove.RawImage``, ``ogiflow.WindSample``).
    encoding
        MCAP schema encoding: ``protobuf`` (a serialized FileDescriptorSet) or ``jsonschema``.
    data
        Schema bytes as written to the file.
    message_encoding
        Encoding of the messages on channels of this schema: ``protobuf`` or ``json``.
    """

    name: str
    encoding: str
    data: bytes
    message_encoding: str

    @property
    def json_schema(self) -> dict[str, Any]:
        """The JSON Schema as a dict (JSON schemas only)."""
        if self.encoding != "jsonschema":
            raise TypeError(f"{self.name} is not a JSON schema")
        return json.loads(self.data)


# --------------------------------------------------------------------------- protobuf


def _file_descriptor_set(file: FileDescriptor) -> bytes:
    """Serialized FileDescriptorSet of ``file`` and everything it imports (dependencies first)."""
    fds = descriptor_pb2.FileDescriptorSet()
    seen: set[str] = set()

    def add(fd: FileDescriptor) -> None:
        if fd.name in seen:
            return
        for dep in fd.dependencies:
            add(dep)
        seen.add(fd.name)
        fd.CopyToProto(fds.file.add())

    add(file)
    return fds.SerializeToString()


def _proto_schema(message_class: Any) -> MessageSchema:
    desc = message_class.DESCRIPTOR
    return MessageSchema(desc.full_name, "protobuf", _file_descriptor_set(desc.file), "protobuf")


#: 16-bit (or 8-bit) raw camera frames.
RAW_IMAGE = _proto_schema(RawImage)
#: JPEG/PNG images (differential images, masks, visualisations).
COMPRESSED_IMAGE = _proto_schema(CompressedImage)
#: Float fields on the pixel grid: flow (u, v), disparity, disparity change, velocity.
GRID = _proto_schema(Grid)

_RAW_ENCODINGS = {
    (np.dtype(np.uint8), 1): "mono8",
    (np.dtype(np.uint16), 1): "mono16",
    (np.dtype(np.float32), 1): "32FC1",
}


def _set_stamp(msg: Any, stamp_ns: int) -> None:
    msg.timestamp.seconds, msg.timestamp.nanos = divmod(int(stamp_ns), 1_000_000_000)


def raw_image(image: np.ndarray, stamp_ns: int, frame_id: str) -> bytes:
    """Serialize a frame as ``foxglove.RawImage``.

    Parameters
    ----------
    image
        (H, W) uint16 (``mono16``), uint8 (``mono8``) or float32 (``32FC1``), little-endian.
    stamp_ns
        Capture time, UNIX ns.
    frame_id
        Camera frame name, e.g. ``cam_left``.
    """
    image = np.asarray(image)
    if image.ndim != 2:
        raise ValueError(f"raw_image expects a (H, W) array, got shape {image.shape}")
    dtype = image.dtype.newbyteorder("=") if image.dtype.byteorder == ">" else image.dtype
    key = (np.dtype(dtype), 1)
    if key not in _RAW_ENCODINGS:
        raise ValueError(f"raw_image: unsupported dtype {image.dtype} (uint8, uint16, float32)")
    data = np.ascontiguousarray(image, dtype=np.dtype(dtype).newbyteorder("<"))
    msg = RawImage(frame_id=frame_id, width=image.shape[1], height=image.shape[0],
                   encoding=_RAW_ENCODINGS[key], step=data.strides[0], data=data.tobytes())
    _set_stamp(msg, stamp_ns)
    return msg.SerializeToString()


def raw_image_to_array(payload: bytes) -> tuple[np.ndarray, int, str]:
    """Decode a ``foxglove.RawImage`` written by :func:`raw_image`: (image, stamp_ns, frame_id)."""
    msg = RawImage()
    msg.ParseFromString(payload)
    dtypes = {"mono8": "<u1", "mono16": "<u2", "32FC1": "<f4"}
    if msg.encoding not in dtypes:
        raise ValueError(f"unsupported RawImage encoding {msg.encoding!r}")
    dtype = np.dtype(dtypes[msg.encoding])
    rows = np.frombuffer(msg.data, np.uint8).reshape(msg.height, msg.step)
    image = rows[:, : msg.width * dtype.itemsize].copy().view(dtype).reshape(msg.height,
                                                                              msg.width)
    stamp = msg.timestamp.seconds * 1_000_000_000 + msg.timestamp.nanos
    return image.astype(dtype.newbyteorder("=")), stamp, msg.frame_id


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


# --------------------------------------------------------------------------- JSON schemas

_INT = {"type": "integer"}
_NUM = {"type": "number"}
_NUM_OR_NULL = {"type": ["number", "null"]}
_INT_OR_NULL = {"type": ["integer", "null"]}
_VEC3 = {"type": "array", "items": _NUM, "minItems": 3, "maxItems": 3}
_VEC3_OR_NULL = {"type": ["array", "null"], "items": _NUM, "minItems": 3, "maxItems": 3}
_TIMES = {
    "t_mono_ns": {**_INT, "description": "host time.monotonic_ns() at arrival"},
    "t_wall_ns": {**_INT, "description": "host wall clock at arrival, UNIX ns"},
}


def _json_schema(name: str, title: str, description: str, properties: dict[str, Any],
                 required: list[str]) -> MessageSchema:
    doc = {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": title,
        "description": description,
        "type": "object",
        "properties": properties,
        "required": required,
        "additionalProperties": False,
    }
    return MessageSchema(name, "jsonschema", json.dumps(doc, indent=1).encode(), "json")


WIND_SAMPLE = _json_schema(
    "ogiflow.WindSample",
    "Wind sample",
    "One decoded anemometer sample in the sensor's own axes, as it arrived.",
    {
        **_TIMES,
        "t_device": {**_NUM_OR_NULL,
                     "description": "sensor's own time or counter if it sends one"},
        "sensor": {"type": "string", "description": "protocol/back end, e.g. gill"},
        "u": {**_NUM_OR_NULL, "description": "wind along the sensor's x axis, m/s "
                                            "(null: axis failed or not measured)"},
        "v": {**_NUM_OR_NULL, "description": "wind along the sensor's y axis, m/s "
                                            "(null: axis failed or not measured)"},
        "w": {**_NUM_OR_NULL, "description": "wind along the sensor's z axis, m/s "
                                            "(null: axis failed or not measured)"},
        "speed_of_sound_m_s": _NUM_OR_NULL,
        "sonic_temperature_c": _NUM_OR_NULL,
        "status": {"type": ["integer", "string", "null"],
                   "description": "sensor status/diagnostic word (0 or 'OK' = good)"},
        "valid": {"type": "boolean", "description": "false when the sensor flags the sample"},
    },
    ["t_mono_ns", "t_wall_ns", "sensor", "u", "v", "w", "valid"],
)

WIND_CAMERA = _json_schema(
    "ogiflow.WindCamera",
    "Wind in the camera frame",
    "Anemometer wind rotated into the left camera frame (X right, Y down, Z forward) with the "
    "site's mounting rotation, interpolated at a stereo pair's time.",
    {
        **_TIMES,
        "pair_index": _INT_OR_NULL,
        "velocity_m_s": {**_VEC3, "description": "(vx, vy, vz) m/s in the camera frame"},
        "speed_m_s": {**_NUM, "minimum": 0},
        "angles_deg": {**_VEC3_OR_NULL,
                       "description": "directional angles to X, Y, Z (paper footnote 1); "
                                      "null when the speed is 0"},
        "interpolated": {"type": "boolean",
                         "description": "true when interpolated between two samples"},
    },
    ["t_mono_ns", "t_wall_ns", "velocity_m_s", "speed_m_s", "angles_deg", "interpolated"],
)

STEREO_PAIR = _json_schema(
    "ogiflow.StereoPair",
    "Stereo pair",
    "A left and a right frame paired by nearest arrival time within the tolerance.",
    {
        "pair_index": {**_INT, "minimum": 0},
        "left_seq": {**_INT, "description": "left camera frame sequence number"},
        "right_seq": {**_INT, "description": "right camera frame sequence number"},
        "t_left_mono_ns": _INT,
        "t_right_mono_ns": _INT,
        "t_mono_ns": {**_INT, "description": "pair time (mean of both arrivals)"},
        "t_wall_ns": _INT,
        "dt_ns": {**_INT, "description": "t_right - t_left"},
        "t_left_device_ns": _INT_OR_NULL,
        "t_right_device_ns": _INT_OR_NULL,
    },
    ["pair_index", "left_seq", "right_seq", "t_left_mono_ns", "t_right_mono_ns", "t_mono_ns",
     "t_wall_ns", "dt_ns"],
)

SCENEFLOW_SUMMARY = _json_schema(
    "ogiflow.SceneFlowSummary",
    "Scene-flow summary of one frame",
    "Per-frame result of the scene-flow chain over the segmented gas region (paper Sec. 4). "
    "When 'valid' is false the numbers must not be used; 'flags' says why.",
    {
        **_TIMES,
        "pair_index": {**_INT, "description": "index of the middle pair t1 of (t0, t1, t2)"},
        "gas_pixels": {**_INT, "minimum": 0, "description": "pixels in the gas mask (Eq. 9)"},
        "mean_velocity_m_s": {**_VEC3_OR_NULL,
                              "description": "mean 3D gas velocity (Eq. 4), camera frame"},
        "speed_m_s": {**_NUM_OR_NULL, "minimum": 0},
        "angles_deg": {**_VEC3_OR_NULL,
                       "description": "directional angles to X, Y, Z (paper footnote 1)"},
        "c_usf": {**_NUM_OR_NULL, "description": "frame quality c_USF (Eq. 8)"},
        "latency_ms": {**_NUM_OR_NULL, "description": "arrival of t2 to result"},
        "skipped_pairs": {**_INT, "minimum": 0,
                          "description": "pairs skipped before this one (worker behind)"},
        "valid": {"type": "boolean"},
        "flags": {"type": "array", "items": {"type": "string"},
                  "description": "quality flags, e.g. no_gas, low_quality"},
    },
    ["t_mono_ns", "t_wall_ns", "pair_index", "gas_pixels", "mean_velocity_m_s", "speed_m_s",
     "angles_deg", "c_usf", "valid", "flags"],
)

_STREAM_STATS = {
    "type": "object",
    "properties": {
        "count": {**_INT, "description": "items since start"},
        "rate_hz": {**_NUM, "description": "items per second over the last interval"},
        "drops": {**_INT, "description": "items lost or skipped since start"},
        "last_age_s": {**_NUM_OR_NULL, "description": "seconds since the last item"},
    },
    "required": ["count", "rate_hz", "drops", "last_age_s"],
    "additionalProperties": False,
}
_LATENCY_STATS = {
    "type": "object",
    "properties": {"count": _INT, "mean_ms": _NUM_OR_NULL, "max_ms": _NUM_OR_NULL},
    "required": ["count", "mean_ms", "max_ms"],
    "additionalProperties": False,
}

HEALTH = _json_schema(
    "ogiflow.Health",
    "Health snapshot",
    "Periodic state of the appliance: per-stream rates and drops, latencies, counters "
    "(unpaired frames, skipped pairs, serial errors, queue drops, ring overwrites), gauges "
    "(ring occupancy, disk free) and whether acquisition is stalled.",
    {
        **_TIMES,
        "uptime_s": _NUM,
        "streams": {"type": "object", "additionalProperties": _STREAM_STATS},
        "latencies": {"type": "object", "additionalProperties": _LATENCY_STATS},
        "counters": {"type": "object", "additionalProperties": _INT},
        "gauges": {"type": "object", "additionalProperties": _NUM_OR_NULL},
        "stalled": {"type": "boolean", "description": "no new frame for health.stall_s"},
    },
    ["t_mono_ns", "t_wall_ns", "uptime_s", "streams", "latencies", "counters", "gauges",
     "stalled"],
)

#: Topic -> schema of everything the appliance writes (one place for names and schemas).
TOPICS: dict[str, MessageSchema] = {
    # Raw frames: written by drivers.camera.mcap_format (image + frame_info per frame).
    "/camera/left/image": RAW_IMAGE,
    "/camera/right/image": RAW_IMAGE,
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
}


# --------------------------------------------------------------------------- JSON helpers

_JSON_TYPES: dict[str, Any] = {
    "object": Mapping, "array": (list, tuple), "string": str, "boolean": bool,
    "null": type(None),
}


def _type_ok(value: Any, name: str) -> bool:
    if name == "integer":
        return isinstance(value, (int, np.integer)) and not isinstance(value, bool)
    if name == "number":
        return (isinstance(value, (int, float, np.integer, np.floating))
                and not isinstance(value, bool) and math.isfinite(float(value)))
    return isinstance(value, _JSON_TYPES[name])


def _validate(value: Any, schema: Mapping[str, Any], path: str, errors: list[str]) -> None:
    """The subset of JSON Schema our schemas use: type, properties, required,
    additionalProperties, items, minItems/maxItems, minimum."""
    types = schema.get("type")
    if types is not None:
        names = [types] if isinstance(types, str) else types
        if not any(_type_ok(value, n) for n in names):
            errors.append(f"{path}: expected {' or '.join(names)}, got {value!r:.60}")
            return
    if value is None:
        return
    if "minimum" in schema and isinstance(value, (int, float)) and value < schema["minimum"]:
        errors.append(f"{path}: must be >= {schema['minimum']}, got {value!r}")
    if isinstance(value, Mapping):
        props = schema.get("properties", {})
        for key in schema.get("required", []):
            if key not in value:
                errors.append(f"{path}.{key}: missing")
        extra = schema.get("additionalProperties", True)
        for key, item in value.items():
            if key in props:
                _validate(item, props[key], f"{path}.{key}", errors)
            elif extra is False:
                errors.append(f"{path}.{key}: not in the schema")
            elif isinstance(extra, Mapping):
                _validate(item, extra, f"{path}.{key}", errors)
    elif isinstance(value, (list, tuple)):
        if "minItems" in schema and len(value) < schema["minItems"]:
            errors.append(f"{path}: needs at least {schema['minItems']} items")
        if "maxItems" in schema and len(value) > schema["maxItems"]:
            errors.append(f"{path}: takes at most {schema['maxItems']} items")
        if "items" in schema:
            for i, item in enumerate(value):
                _validate(item, schema["items"], f"{path}[{i}]", errors)


def validate_json(schema: MessageSchema, obj: Any) -> list[str]:
    """Problems of ``obj`` against a JSON ``schema`` (empty list: valid)."""
    errors: list[str] = []
    _validate(obj, schema.json_schema, schema.name, errors)
    return errors


def _default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON serializable: {type(value).__name__}")


def encode_json(schema: MessageSchema, obj: Mapping[str, Any], validate: bool = True) -> bytes:
    """Serialize one message of a JSON ``schema`` (compact UTF-8 JSON).

    Raises
    ------
    ValueError
        With ``validate``, when ``obj`` does not match the schema (naming the fields). Non-finite
        numbers are refused either way: JSON has none (use null).
    """
    if validate:
        errors = validate_json(schema, obj)
        if errors:
            raise ValueError("; ".join(errors))
    return json.dumps(obj, separators=(",", ":"), allow_nan=False, default=_default).encode()


def decode_json(payload: bytes) -> Any:
    """Parse one JSON message."""
    return json.loads(payload)
