"""Message schemas: Foxglove protobuf encoders, documented JSON schemas, and that Rerun's MCAP
importer understands what the recorder writes."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import cv2
import jsonschema
import numpy as np
import pytest
from google.protobuf import descriptor_pb2

from appliance.config import Config, RecordingConfig
from appliance.recording import schemas as S
from appliance.recording.metadata import file_metadata
from appliance.recording.recorder import Recorder, closed_files
from drivers.camera.base import Frame
from drivers.camera.mcap_format import decode_image


def test_camera_frames_are_recorded_with_the_daemons_encoder() -> None:
    rng = np.random.default_rng(0)
    for img, fmt in ((rng.integers(0, 65535, (24, 32), dtype=np.uint16), "Mono16"),
                     (rng.integers(0, 255, (24, 32), dtype=np.uint8), "Mono8")):
        frame = Frame(image=img, pixel_format=fmt, host_ns=5_000, seq=7, device_ts_ns=123)
        image, info = S.frame_records("right", frame, 1_234_567_890_123)
        assert (image.topic, image.schema) == ("/camera/right/image", S.RAW_IMAGE)
        assert (info.topic, info.schema) == ("/camera/right/frame_info", S.FRAME_INFO)
        assert S.TOPICS[image.topic] is S.RAW_IMAGE and S.TOPICS[info.topic] is S.FRAME_INFO
        assert image.log_time_ns == info.log_time_ns == 1_234_567_890_123
        assert image.publish_time_ns == info.publish_time_ns == 5_000
        back, stamp = decode_image(image.payload)
        assert np.array_equal(back, img) and back.dtype == img.dtype
        assert stamp == 1_234_567_890_123
        meta = json.loads(info.payload)
        assert S.validate_json(S.FRAME_INFO, meta) == []
        assert (meta["seq"], meta["device_ts_ns"], meta["pixel_format"]) == (7, 123, fmt)


def test_grid_round_trip_and_shape_check() -> None:
    field = np.random.default_rng(1).normal(size=(24, 32, 3)).astype(np.float32)
    field[0, 0] = np.nan
    back, names, stamp = S.grid_to_array(S.grid(field, 7, "cam_left", ("vx", "vy", "vz")))
    assert names == ("vx", "vy", "vz") and stamp == 7
    np.testing.assert_array_equal(back, field)
    back2, names2, _ = S.grid_to_array(S.grid(field[..., 0], 7, "cam_left", ("d",)))
    assert back2.shape == (24, 32, 1) and names2 == ("d",)
    with pytest.raises(ValueError, match=r"\(H, W, 2\)"):
        S.grid(field, 0, "cam_left", ("u", "v"))


def test_protobuf_schemas_are_self_contained_descriptor_sets() -> None:
    for schema, deps in ((S.RAW_IMAGE, {"google/protobuf/timestamp.proto"}),
                         (S.GRID, {"foxglove/Pose.proto", "foxglove/PackedElementField.proto",
                                   "foxglove/Vector2.proto"})):
        fds = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
        names = [f.name for f in fds.file]
        assert deps <= set(names)
        assert names[-1] == f"foxglove/{schema.name.split('.')[1]}.proto"  # deps first
        assert schema.encoding == schema.message_encoding == "protobuf"


def test_json_schemas_document_and_check_messages() -> None:
    for schema in (S.WIND_SAMPLE, S.WIND_CAMERA, S.STEREO_PAIR, S.SCENEFLOW_SUMMARY, S.HEALTH):
        doc = schema.json_schema
        assert schema.encoding == "jsonschema" and schema.message_encoding == "json"
        assert doc["description"] and doc["required"] and doc["additionalProperties"] is False
        assert set(doc["required"]) <= set(doc["properties"])
    summary = {"t_mono_ns": 1, "t_wall_ns": 2, "pair_index": 5, "gas_pixels": 812,
               "mean_velocity_m_s": [0.9, -0.1, 0.2], "speed_m_s": 0.93,
               "angles_deg": [14.6, 96.2, 77.6], "c_usf": 0.81, "latency_ms": 95.0,
               "skipped_pairs": 0, "valid": True, "flags": []}
    assert json.loads(S.encode_json(S.SCENEFLOW_SUMMARY, summary)) == summary
    no_gas = {**summary, "gas_pixels": 0, "mean_velocity_m_s": None, "speed_m_s": None,
              "angles_deg": None, "c_usf": None, "valid": False, "flags": ["no_gas"]}
    S.encode_json(S.SCENEFLOW_SUMMARY, no_gas)
    bad = {**summary, "speed_m_s": float("nan"), "gas_pixels": -1, "colour": "red"}
    del bad["valid"]
    with pytest.raises(ValueError) as exc:
        S.encode_json(S.SCENEFLOW_SUMMARY, bad)
    text = str(exc.value)
    for part in ("SceneFlowSummary.speed_m_s: nan is not a JSON number (use null",
                 "SceneFlowSummary.gas_pixels: -1 is less than the minimum of 0",
                 "('colour' was unexpected)", "'valid' is a required property"):
        assert part in text
    with pytest.raises(ValueError, match=r"WindCamera.velocity_m_s: \[1, 2\] is too short"):
        S.encode_json(S.WIND_CAMERA, {"t_mono_ns": 1, "t_wall_ns": 1, "velocity_m_s": [1, 2],
                                      "speed_m_s": 1.0, "angles_deg": None,
                                      "interpolated": False})
    # numpy scalars and arrays serialize as plain JSON
    pair = {"pair_index": np.int64(3), "left_seq": 3, "right_seq": 4, "t_left_mono_ns": 1,
            "t_right_mono_ns": 2, "t_mono_ns": 1, "t_wall_ns": 5, "dt_ns": np.int64(1)}
    assert json.loads(S.encode_json(S.STEREO_PAIR, pair))["pair_index"] == 3


def test_every_topic_has_a_schema() -> None:
    assert S.TOPICS["/camera/left/image"] is S.RAW_IMAGE
    assert S.TOPICS["/health"] is S.HEALTH
    assert all(isinstance(v, S.MessageSchema) for v in S.TOPICS.values())
    for schema in {v for v in S.TOPICS.values() if v.encoding == "jsonschema"}:
        jsonschema.Draft202012Validator.check_schema(schema.json_schema)  # valid schemas


def test_rerun_mcap_import_reads_our_files(tmp_path: Path) -> None:
    """`rerun mcap convert` turns our Foxglove images into Rerun images (docs/design.md)."""
    rc = dataclasses.replace(RecordingConfig(), dir=tmp_path / "rec", quota_gb=None)
    rec = Recorder(rc, file_metadata(Config())).start()
    rng = np.random.default_rng(0)
    for i in range(3):
        t = 1_700_000_000_000_000_000 + i * 33_333_333
        img = rng.integers(0, 65535, (24, 32), dtype=np.uint16)
        frame = Frame(image=img, pixel_format="Mono16", host_ns=i, seq=i)
        for r in S.frame_records("left", frame, t):
            rec.record(r.topic, r.schema, r.payload, r.log_time_ns, r.publish_time_ns)
        jpg = cv2.imencode(".jpg", (img >> 8).astype(np.uint8))[1].tobytes()
        rec.record("/cam/left/diff", S.COMPRESSED_IMAGE, S.compressed_image(jpg, t, "cam_left"),
                   t)
        rec.record("/sceneflow/flow", S.GRID, S.grid(rng.random((24, 32, 2)), t, "cam_left",
                                                      ("u", "v")), t)
    rec.close()
    (path,) = closed_files(tmp_path / "rec")
    out = tmp_path / "out.rrd"
    conv = subprocess.run([sys.executable, "-m", "rerun", "mcap", "convert", str(path), "-o",
                           str(out)], capture_output=True, text=True, timeout=120)
    assert conv.returncode == 0, conv.stderr
    printed = subprocess.run([sys.executable, "-m", "rerun", "rrd", "print", str(out)],
                             capture_output=True, text=True, timeout=120).stdout
    assert "/camera/left/image" in printed and "Image:format" in printed
    assert "/cam/left/diff" in printed and "EncodedImage:blob" in printed
