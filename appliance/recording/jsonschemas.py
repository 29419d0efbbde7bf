"""Our own JSON message schemas and their checks (MCAP schema encoding ``jsonschema``,
message encoding ``json``): wind samples, wind in the camera frame, stereo pairs, per-frame
scene-flow summaries and health snapshots.

The JSON Schema text is stored in every file's schema record, so a file documents itself.
Messages are checked with the ``jsonschema`` package (Draft 2020-12). Conventions (times,
camera frame, directional angles) are those of :mod:`appliance.recording.schemas`.
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Mapping
from typing import Any

import jsonschema
import numpy as np

from appliance.recording.message import MessageSchema

__all__ = [
    "HEALTH",
    "LEAK_EVENT",
    "SCENEFLOW_SUMMARY",
    "STEREO_PAIR",
    "WIND_CAMERA",
    "WIND_SAMPLE",
    "decode_json",
    "encode_json",
    "validate_json",
]


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
        "emission_rate_g_s": {**_NUM_OR_NULL, "description": "emission rate of this frame "
                              "(mean over its curtains), g/s; null: undefined, see reason"},
        "emission_rate_kg_h": {**_NUM_OR_NULL, "description": "the same in kg/h"},
        "emission_reason": {"type": "string", "description": "why the frame has no rate"},
        "emission_window_rate_g_s": {**_NUM_OR_NULL, "description": "mean rate over the "
                                     "window ending at this frame, g/s"},
        "emission_window_rate_kg_h": {**_NUM_OR_NULL, "description": "the same in kg/h"},
        "emission_window_uncertainty_g_s": {**_NUM_OR_NULL, "minimum": 0, "description":
                                            "one standard uncertainty of the window rate"},
        "emission_window_s": {**_NUM, "minimum": 0, "description": "window length, s"},
        "emission_window_frames": {**_INT, "minimum": 0,
                                   "description": "frames with a rate in the window"},
        "emission_window_out_of_plane_deg": {**_NUM_OR_NULL, "minimum": 0, "maximum": 90,
                                             "description": "mean angle of the gas's motion "
                                             "out of the image plane over the window, deg"},
        "emission_window_flags": {"type": "array", "items": {"type": "string"},
                                  "description": "qualifiers of the window rate, e.g. "
                                  "line_of_sight (motion mostly along the view: rate weak)"},
        "emission_true_rate_g_s": {**_NUM_OR_NULL, "description": "simulated runs: the "
                                   "simulator's true release rate at this frame, g/s"},
    },
    ["t_mono_ns", "t_wall_ns", "pair_index", "gas_pixels", "mean_velocity_m_s", "speed_m_s",
     "angles_deg", "c_usf", "valid", "flags"],
)

_XY_OR_NULL = {"type": ["array", "null"], "items": _NUM, "minItems": 2, "maxItems": 2}
LEAK_EVENT = _json_schema(
    "ogiflow.LeakEvent",
    "Leak event change",
    "A leak event started, is ongoing (update) or ended (appliance.runtime.events). Times "
    "are UNIX seconds of the daemon's clock; rates in g/s; positions in the left image (px) "
    "and the left camera frame (m).",
    {
        "t_wall_ns": {**_INT, "description": "time of the frame that caused the change"},
        "kind": {"enum": ["start", "update", "end"]},
        "id": {**_INT, "minimum": 1},
        "start_t_s": _NUM, "start_frame": _INT,
        "end_t_s": _NUM_OR_NULL, "end_frame": _INT_OR_NULL,
        "end_reason": {"type": "string"},
        "source_xy": _XY_OR_NULL, "source_xyz_m": _VEC3_OR_NULL,
        "peak_rate_g_s": _NUM_OR_NULL, "mean_rate_g_s": _NUM_OR_NULL,
        "mean_velocity_m_s": _VEC3_OR_NULL, "mean_wind_m_s": _VEC3_OR_NULL,
        "confidence": {**_NUM, "minimum": 0, "maximum": 1},
        "frames": {**_INT, "minimum": 0}, "positive_frames": {**_INT, "minimum": 0},
    },
    ["t_wall_ns", "kind", "id", "start_t_s", "start_frame", "confidence"],
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
        "mode": {"enum": ["stereo", "degraded", "single_camera"],
                 "description": "stereo, degraded (a camera of the pair lost: the other "
                                "runs the single-camera chain) or single_camera (site)"},
        "cameras": {"type": "object", "additionalProperties": {
            "type": "object",
            "properties": {
                "configured": {"type": "boolean"},
                "lost": {"type": "boolean", "description": "silent for cameras.lost_after_s"},
                "lost_since_wall_ns": {**_INT_OR_NULL,
                                       "description": "UNIX ns of its last frame before "
                                                      "the loss"},
            },
            "required": ["configured", "lost", "lost_since_wall_ns"],
            "additionalProperties": False}},
    },
    ["t_mono_ns", "t_wall_ns", "uptime_s", "streams", "latencies", "counters", "gauges",
     "stalled"],
)

# --------------------------------------------------------------------------- JSON helpers

def _is_integer(_checker: Any, value: Any) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


def _is_number(_checker: Any, value: Any) -> bool:
    # JSON has no NaN or infinity: a non-finite number is refused here, not at encoding.
    return (isinstance(value, (int, float, np.integer, np.floating))
            and not isinstance(value, bool) and math.isfinite(float(value)))


def _is_array(_checker: Any, value: Any) -> bool:
    return isinstance(value, (list, tuple, np.ndarray))


#: Draft 2020-12 with numpy scalars counted as JSON numbers and tuples as arrays (what the
#: daemon hands over before ``json.dumps`` converts them).
_Validator = jsonschema.validators.extend(
    jsonschema.Draft202012Validator,
    type_checker=jsonschema.Draft202012Validator.TYPE_CHECKER.redefine_many(
        {"integer": _is_integer, "number": _is_number, "array": _is_array}),
)


@functools.cache
def _validator(schema: MessageSchema) -> Any:
    return _Validator(schema.json_schema)


def validate_json(schema: MessageSchema, obj: Any) -> list[str]:
    """Problems of ``obj`` against a JSON ``schema`` (empty list: valid), each as
    ``<schema name>.<field path>: <problem>``, e.g.
    ``ogiflow.SceneFlowSummary.gas_pixels: -1 is less than the minimum of 0``."""
    errors = sorted(_validator(schema).iter_errors(obj), key=lambda e: list(e.absolute_path))
    out = []
    for e in errors:
        path = "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in e.absolute_path)
        message = e.message
        if (e.validator == "type" and isinstance(e.instance, float)
                and not math.isfinite(e.instance)):
            message = f"{e.instance} is not a JSON number (use null for no value)"
        out.append(f"{schema.name}{path}: {message}")
    return out


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
