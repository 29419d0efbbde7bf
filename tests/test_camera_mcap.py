"""MCAP frame format (recorder side and replay side) and the MCAP replay camera."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from mcap.reader import make_reader
from mcap.writer import Writer

from drivers.camera import CameraError, EndOfStream, Frame, create_camera
from drivers.camera.mcap_format import (
    FRAME_INFO_SCHEMA,
    IMAGE_SCHEMA_DATA,
    ChannelCache,
    FrameLogReader,
    frame_to_messages,
    iter_frames,
)

WALL0 = 1_790_000_000_000_000_000


def _frames(n: int = 12) -> list[tuple[str, Frame]]:
    rng = np.random.default_rng(3)
    out = []
    for i in range(n):
        for side, offset in (("left", 0), ("right", 4_000_000)):
            if side == "left" and i % 5 == 4:
                img = rng.integers(0, 255, (24, 32)).astype(np.uint8)
                fmt = "Mono8"
            else:
                img = rng.integers(0, 2**14, (24, 32)).astype(np.uint16)
                fmt = "Mono14"
            f = Frame(image=img, pixel_format=fmt, host_ns=5_000_000_000 + i * 33_333_333 + offset,
                      seq=i, device_ts_ns=None if side == "right" else 10**15 + i * 33_333_000,
                      device_frame_id=i + 100, lost=int(i == 3),
                      temperatures={"sensor": 31.5 + i} if side == "left" else {})  # fmt: skip
            out.append((side, f))
    return out


def _write(target, frames, chunk_size: int = 1 << 20) -> None:
    writer = Writer(target, chunk_size=chunk_size)
    writer.start(profile="", library="ogiflow-test")
    cache = ChannelCache(writer)
    for side, f in frames:
        cache.write(frame_to_messages(side, f, WALL0 + f.host_ns))
    writer.finish()


def _same(a: Frame, b: Frame) -> None:
    np.testing.assert_array_equal(a.image, b.image)
    assert a.image.dtype == b.image.dtype
    for field in ("pixel_format", "host_ns", "seq", "device_ts_ns", "device_frame_id", "lost",
                  "temperatures"):  # fmt: skip
        assert getattr(a, field) == getattr(b, field), field


def test_round_trip_keeps_every_field(tmp_path: Path) -> None:
    frames = _frames()
    path = tmp_path / "rec.mcap"
    _write(str(path), frames)
    back = list(iter_frames(path))
    assert [s for s, _ in back] == [s for s, _ in frames]
    for (_, a), (_, b) in zip(frames, back, strict=True):
        _same(a, b)


def test_file_is_standard_foxglove_rawimage_with_documented_times(tmp_path: Path) -> None:
    path = tmp_path / "rec.mcap"
    frames = _frames(2)
    _write(str(path), frames)
    with open(path, "rb") as fh:
        records = list(make_reader(fh).iter_messages())
    topics = {c.topic for _, c, _ in records}
    assert topics == {"/camera/left/image", "/camera/right/image", "/camera/left/frame_info",
                      "/camera/right/frame_info"}  # fmt: skip
    schema, channel, msg = next(r for r in records if r[1].topic == "/camera/left/image")
    assert (schema.name, schema.encoding, channel.message_encoding) == (
        "foxglove.RawImage", "protobuf", "protobuf")  # fmt: skip
    # decode with a class built only from the schema in the file, as a foreign tool would
    fds = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
    pool = descriptor_pool.DescriptorPool()
    for fd in fds.file:
        pool.Add(fd)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName("foxglove.RawImage"))
    img = cls.FromString(msg.data)
    assert (img.width, img.height, img.encoding, img.step) == (32, 24, "mono16", 64)
    assert img.timestamp.ToNanoseconds() == WALL0 + frames[0][1].host_ns
    assert msg.log_time == WALL0 + frames[0][1].host_ns  # wall clock
    assert msg.publish_time == frames[0][1].host_ns  # host monotonic
    info_schema, _, info = next(r for r in records if r[1].topic == "/camera/left/frame_info")
    assert info_schema.encoding == "jsonschema"
    assert json.loads(info_schema.data) == FRAME_INFO_SCHEMA
    body = json.loads(info.data)
    assert set(body) <= set(FRAME_INFO_SCHEMA["properties"])
    assert set(FRAME_INFO_SCHEMA["required"]) <= set(body)
    assert RawImage.FromString(msg.data).data == np.ascontiguousarray(frames[0][1].image).tobytes()
    assert IMAGE_SCHEMA_DATA == schema.data


def test_truncated_file_yields_every_complete_chunk(tmp_path: Path) -> None:
    frames = _frames(40)
    buf = io.BytesIO()
    _write(buf, frames, chunk_size=8_000)  # many small chunks
    data = buf.getvalue()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])
    reader = FrameLogReader(cut)
    back = list(reader)
    assert reader.truncated
    assert len(back) > len(frames) // 2  # the completed chunks' frames
    for (_, a), (_, b) in zip(frames, back[:-1], strict=False):
        _same(a, b)
    # the last image may have lost its frame_info to the cut: it is still delivered, with the
    # arrival time its image message carries
    a, b = frames[len(back) - 1][1], back[-1][1]
    np.testing.assert_array_equal(a.image, b.image)
    assert a.host_ns == b.host_ns


def test_not_an_mcap_file_is_a_clear_error(tmp_path: Path) -> None:
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"this is not mcap at all" * 10)
    with pytest.raises(CameraError, match="not an MCAP file"):
        list(iter_frames(bad))
    with pytest.raises(CameraError, match="cannot open recording"):
        list(iter_frames(tmp_path / "missing.mcap"))


def test_replay_camera_keeps_original_timestamps(tmp_path: Path) -> None:
    frames = _frames(6)
    path = tmp_path / "rec.mcap"
    _write(str(path), frames)
    cam = create_camera("replay_mcap", path=path, side="right", pace=False)
    got = []
    with cam:
        while True:
            try:
                got.append(cam.grab(1.0))
            except EndOfStream:
                break
    want = [f for s, f in frames if s == "right"]
    assert len(got) == len(want)
    for a, b in zip(want, got, strict=True):
        _same(a, b)


def test_replay_camera_paced_loops(tmp_path: Path) -> None:
    frames = [(s, f) for s, f in _frames(3) if s == "left"]
    path = tmp_path / "rec.mcap"
    _write(str(path), frames)
    cam = create_camera("replay_mcap", path=path, side="left", pace=True, loop=True)
    with cam:
        got = [cam.grab(1.0) for _ in range(5)]
    assert [f.seq for f in got] == [0, 1, 2, 0, 1]
    with pytest.raises(CameraError, match="no recording"):
        create_camera("replay_mcap", path=tmp_path / "nope.mcap").open()
