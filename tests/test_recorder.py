"""MCAP recorder: content, metadata, rotation, quota, fsync, non-blocking drops."""

from __future__ import annotations

import dataclasses
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.exceptions import EndOfFile
from mcap.reader import make_reader
from mcap.records import Message
from mcap.stream_reader import StreamReader

from appliance.config import Config, RecordingConfig, load_config
from appliance.recording import schemas as S
from appliance.recording.metadata import file_metadata
from appliance.recording.recorder import Recorder, closed_files, unfinished_files
from drivers.camera.base import Frame
from drivers.camera.mcap_format import decode_image


def _rc(tmp_path: Path, **kw: object) -> RecordingConfig:
    base = {"dir": tmp_path / "rec", "fsync_s": 0.5, "quota_gb": None}
    base.update(kw)
    return dataclasses.replace(RecordingConfig(), **base)  # type: ignore[arg-type]


def _frame(i: int, side: str = "left", shape: tuple[int, int] = (240, 320)) -> list[S.Record]:
    """Camera frame i (counter in pixel (0, 0)) as the daemon records it: image + frame_info."""
    img = np.random.default_rng(i).integers(0, 65535, shape, dtype=np.uint16)
    img[0, 0] = i
    frame = Frame(image=img, pixel_format="Mono16", host_ns=1_000 + i, seq=i)
    return S.frame_records(side, frame, 1_700_000_000_000_000_000 + i)


def _record(rec: Recorder, records: list[S.Record]) -> bool:
    return all([rec.record(r.topic, r.schema, r.payload, r.log_time_ns, r.publish_time_ns)
                for r in records])


def _counter(image_payload: bytes) -> int:
    return int(decode_image(image_payload)[0][0, 0])


def _wind(i: int) -> bytes:
    return S.encode_json(S.WIND_SAMPLE, {"t_mono_ns": i, "t_wall_ns": i, "sensor": "gill",
                                         "u": 1.0, "v": 0.5, "w": -0.1, "valid": True})


def _read_all(path: Path) -> tuple[list[tuple[str, bytes]], dict[str, dict[str, str]], object]:
    with open(path, "rb") as f:
        reader = make_reader(f)
        msgs = [(ch.topic, m.data) for _, ch, m in reader.iter_messages()]
        meta = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        summary = reader.get_summary()
    return msgs, meta, summary


def _count_messages_of_cut_file(path: Path) -> int:
    """Messages in the complete records of a file that is still open (no footer yet)."""
    n = 0
    with open(path, "rb") as f:
        try:
            for record in StreamReader(f).records:
                n += isinstance(record, Message)
        except EndOfFile:
            pass
    return n


def test_records_every_message_with_metadata(tmp_path: Path) -> None:
    cfg = Config()
    cal = "camera_matrix_left: [[400, 0, 160], [0, 400, 120], [0, 0, 1]]\n"
    rec = Recorder(_rc(tmp_path), file_metadata(cfg, cal)).start()
    for i in range(20):
        assert _record(rec, _frame(i))
        assert _record(rec, _frame(100 + i, "right"))
        assert rec.record("/wind/raw", S.WIND_SAMPLE, _wind(i), 10 + i, 5 + i)
    assert rec.close()
    (path,) = closed_files(tmp_path / "rec")
    assert unfinished_files(tmp_path / "rec") == []
    msgs, meta, summary = _read_all(path)
    assert len(msgs) == 100
    left = [d for t, d in msgs if t == "/camera/left/image"]
    assert [_counter(d) for d in left] == list(range(20))
    assert {t for t, _ in msgs} == {"/camera/left/image", "/camera/left/frame_info",
                                    "/camera/right/image", "/camera/right/frame_info",
                                    "/wind/raw"}
    # schemas registered once per file: three distinct schemas for five channels
    assert len(summary.schemas) == 3 and len(summary.channels) == 5
    assert summary.chunk_indexes[0].compression == "zstd"
    assert meta["recording"]["software"] == "ogiflow"
    assert {"host", "software_version", "start_time_utc"} <= set(meta["recording"])
    assert load_config(None) == cfg
    assert "rotate_mb" in meta["config"]["yaml"]
    assert meta["calibration"]["yaml"] == cal
    st = rec.stats()
    assert (st.messages_written, st.messages_dropped, st.files_closed) == (100, 0, 1)


def test_rotation_by_size_reregisters_channels(tmp_path: Path) -> None:
    rec = Recorder(_rc(tmp_path, rotate_mb=0.4, chunk_kb=64), {"config": {"yaml": "x"}}).start()
    for i in range(40):
        _record(rec, _frame(i))
        rec.record("/wind/raw", S.WIND_SAMPLE, _wind(i), i)
        time.sleep(0.002)
    rec.close()
    files = closed_files(tmp_path / "rec")
    assert len(files) >= 3
    total = 0
    seen = []
    for path in files:
        msgs, meta, summary = _read_all(path)
        assert meta["config"] == {"yaml": "x"} and "recording" in meta
        assert {c.topic for c in summary.channels.values()} <= {
            "/camera/left/image", "/camera/left/frame_info", "/wind/raw"}
        assert path.stat().st_size < 0.4e6 + 2 * 64 * 1024 + 200_000
        total += len(msgs)
        seen += [_counter(d) for t, d in msgs if t == "/camera/left/image"]
    assert total == 120
    assert seen == list(range(40))  # order kept across files


def test_rotation_by_time(tmp_path: Path) -> None:
    """An injected clock: one new file per 10 s of it, whatever the machine's speed."""
    now = [0.0]
    rec = Recorder(_rc(tmp_path, rotate_s=10.0, fsync_s=100.0), clock=lambda: now[0]).start()
    for i in range(12):
        rec.record("/wind/raw", S.WIND_SAMPLE, _wind(i), i)
        t_end = time.monotonic() + 10
        while rec.stats().queue_depth and time.monotonic() < t_end:  # written before the step
            time.sleep(0.005)
        now[0] += 4.0  # a rotation after every third message
        time.sleep(0.3)  # one housekeeping tick of the writer (at most 0.2 s) sees it
    rec.close()
    files = closed_files(tmp_path / "rec")
    assert 3 <= len(files) <= 5
    assert sum(len(_read_all(p)[0]) for p in files) == 12


def test_quota_deletes_oldest_closed_files_only(tmp_path: Path) -> None:
    d = tmp_path / "rec"
    d.mkdir()
    old = [d / f"ogiflow-20240101T00000{i}000Z-{i + 1:04d}.mcap" for i in range(5)]
    for p in old:
        p.write_bytes(b"\0" * 1_000_000)
    foreign = d / "notes.mcap"
    foreign.write_bytes(b"\0" * 3_000_000)
    crashed = d / "ogiflow-20230101T000000000Z-0001.mcap.active"
    crashed.write_bytes(b"\0" * 10)
    rec = Recorder(_rc(tmp_path, quota_gb=0.0025, rotate_mb=1.0)).start()
    # 5 MB of closed files + the new one > 2.5 MB: the three oldest go at start.
    assert [p.exists() for p in old] == [False, False, False, True, True]
    assert foreign.exists() and crashed.exists()
    assert rec.current_file is not None and rec.current_file.exists()
    rec.close()
    assert rec.stats().files_deleted == 3
    assert unfinished_files(d) == [crashed]


def test_quota_applies_after_rotation(tmp_path: Path) -> None:
    rec = Recorder(_rc(tmp_path, quota_gb=0.0012, rotate_mb=0.5, chunk_kb=64)).start()
    for i in range(60):
        _record(rec, _frame(i))
        time.sleep(0.002)
    rec.close()
    st = rec.stats()
    assert st.files_deleted >= 1
    files = closed_files(tmp_path / "rec")
    assert sum(p.stat().st_size for p in files[:-1]) <= 1.2e6


def test_periodic_fsync_makes_chunks_readable_before_close(tmp_path: Path) -> None:
    rec = Recorder(_rc(tmp_path, fsync_s=0.1)).start()
    for i in range(5):
        rec.record("/wind/raw", S.WIND_SAMPLE, _wind(i), i)
    active = rec.current_file
    assert active is not None and active.name.endswith(".mcap.active")
    deadline = time.monotonic() + 10
    n = 0
    while n < 5 and time.monotonic() < deadline:
        time.sleep(0.1)
        n = _count_messages_of_cut_file(active)
    rec.close()
    assert n == 5


def test_full_queue_drops_and_counts_without_blocking(tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    rec = Recorder(_rc(tmp_path, queue_size=16))
    gate = threading.Event()
    real_write = rec._write

    def stalled_write(item: object) -> None:  # a disk that hangs
        gate.wait(30)
        real_write(item)  # type: ignore[arg-type]

    monkeypatch.setattr(rec, "_write", stalled_write)
    rec.start()
    payload = _wind(0)
    done = threading.Event()
    accepted = []

    def producer() -> None:
        accepted.extend(rec.record("/wind/raw", S.WIND_SAMPLE, payload, i) for i in range(5000))
        done.set()

    t = threading.Thread(target=producer)
    t.start()
    t.join(20)  # bounded: the producer must finish while the writer is stuck
    assert done.is_set(), "record() blocked on a stalled writer"
    st = rec.stats()
    assert st.messages_dropped == 5000 - sum(accepted)
    assert 16 <= sum(accepted) <= 17  # the queue bound (+1 the stuck writer holds)
    assert st.drops_by_topic == {"/wind/raw": st.messages_dropped}
    gate.set()
    rec.close()
    assert rec.stats().messages_written == sum(accepted)


def test_byte_bound_also_drops(tmp_path: Path) -> None:
    rec = Recorder(_rc(tmp_path), queue_bytes=1000)
    rec._accepting = True  # not started: nothing drains, so the bound is exact
    assert rec.record("/a", S.WIND_SAMPLE, b"x" * 600, 0)
    assert not rec.record("/a", S.WIND_SAMPLE, b"x" * 600, 0)
    assert rec.stats().messages_dropped == 1


def test_default_queue_never_fills_at_stereo_rate(tmp_path: Path) -> None:
    """2 x 30 Hz 320x240 uint16 frames paced in real time for 1 s: nothing dropped."""
    rec = Recorder(_rc(tmp_path)).start()
    frames = [_frame(i) for i in range(4)]
    start = time.monotonic()
    for i in range(30):
        _record(rec, frames[i % 4])
        _record(rec, frames[(i + 1) % 4])
        time.sleep(max(0.0, start + (i + 1) / 30 - time.monotonic()))
    rec.close()
    st = rec.stats()
    assert st.messages_dropped == 0 and st.messages_written == 120
    assert st.queue_peak < RecordingConfig().queue_size // 10


def test_record_after_close_is_counted(tmp_path: Path) -> None:
    rec = Recorder(_rc(tmp_path)).start()
    rec.close()
    assert not rec.record("/wind/raw", S.WIND_SAMPLE, _wind(0), 0)
    assert rec.stats().messages_dropped == 1


def test_start_fails_clearly_on_unusable_dir(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(OSError):
        Recorder(_rc(tmp_path, dir=blocker / "rec")).start()


def test_full_disk_pauses_then_resumes_and_every_file_stays_readable(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """ENOSPC in the writer: recording pauses (stats say so, messages are counted as
    dropped), resumes in a new file once space is back, and no file is left unreadable."""
    from tests.faults import FullDisk

    disk = FullDisk(monkeypatch)
    rec = Recorder(_rc(tmp_path, chunk_kb=16)).start()

    def wait_for(cond: object, what: str) -> None:
        t_end = time.monotonic() + 30
        while not cond():  # type: ignore[operator]
            assert time.monotonic() < t_end, what
            rec.record("/health", S.WIND_SAMPLE, _wind(0), 1)
            time.sleep(0.02)

    for i in range(40):
        rec.record("/wind/raw", S.WIND_SAMPLE, _wind(i), i)
    disk.full.set()
    wait_for(lambda: rec.stats().paused, "the recorder did not pause on ENOSPC")
    assert "No space left on device" in rec.stats().last_error
    disk.full.clear()
    wait_for(lambda: not rec.stats().paused, "the recorder did not resume")
    for i in range(40, 60):
        rec.record("/wind/raw", S.WIND_SAMPLE, _wind(i), i)
    assert rec.close()
    st = rec.stats()
    assert disk.failed_writes >= 1 and st.write_errors >= 1
    assert unfinished_files(tmp_path / "rec") == []
    files = closed_files(tmp_path / "rec")
    assert len(files) >= 2  # the paused file and the one recording resumed in
    samples = []
    for path in files:
        msgs, _meta, summary = _read_all(path)  # the seeking reader accepts every file
        assert summary is not None
        samples += [m for t, m in msgs if t == "/wind/raw"]
    # Each sample is in a file, counted as dropped, or was in the chunk the full disk cut.
    missing = 60 - len(samples) - st.drops_by_topic.get("/wind/raw", 0)
    assert 0 <= missing <= st.messages_lost_in_cut_files
    assert samples[-1] == _wind(59)  # recording did resume
