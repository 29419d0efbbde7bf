"""Recovery of MCAP files cut by a crash, and `ogiflow recover`."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.exceptions import EndOfFile
from mcap.reader import make_reader
from mcap.records import Chunk
from mcap.stream_reader import StreamReader, breakup_chunk

from appliance import cli
from appliance.recording import schemas as S
from appliance.recording.recorder import unfinished_files
from appliance.recording.recovery import default_output, recover, recover_unfinished
from drivers.camera.base import Frame
from drivers.camera.mcap_format import decode_image

ROOT = Path(__file__).resolve().parents[1]

CHILD = textwrap.dedent("""
    import dataclasses, sys, time
    from pathlib import Path
    import numpy as np
    from appliance.recording import schemas as S
    from appliance.config import Config, RecordingConfig
    from appliance.recording.metadata import file_metadata
    from appliance.recording.recorder import Recorder
    from drivers.camera.base import Frame
    rc = dataclasses.replace(RecordingConfig(), dir=Path(sys.argv[1]), chunk_kb=16,
                             fsync_s=0.05, quota_gb=None)
    rec = Recorder(rc, file_metadata(Config(), "cal: 1\\n")).start()
    rng = np.random.default_rng(0)
    i = 0
    while True:
        img = rng.integers(0, 65535, (32, 32), dtype=np.uint16)
        img[0, 0] = i
        frame = Frame(image=img, pixel_format="Mono16", host_ns=i, seq=i)
        for r in S.frame_records("left", frame, i):  # as the daemon records frames
            rec.record(r.topic, r.schema, r.payload, r.log_time_ns, r.publish_time_ns)
        i += 1
        if i % 20 == 0:
            print(i, flush=True)
        time.sleep(0.002)
""")


def _complete_chunks(path: Path) -> tuple[int, int]:
    """Complete chunks in a cut file and the messages in them, read with mcap's own reader."""
    chunks = messages = 0
    with open(path, "rb") as f:
        try:
            for record in StreamReader(f, emit_chunks=True).records:
                if isinstance(record, Chunk):
                    chunks += 1
                    messages += sum(type(r).__name__ == "Message"
                                    for r in breakup_chunk(record, validate_crc=True))
        except EndOfFile:
            pass
    return chunks, messages


@pytest.fixture(scope="module")
def cut_file(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, int]:
    """A recording cut by SIGKILL in the middle of writing; returns (file, last count seen)."""
    d = tmp_path_factory.mktemp("kill")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-c", CHILD, str(d)], stdout=subprocess.PIPE,
                            text=True, env=env, cwd=ROOT)
    assert proc.stdout is not None
    last = 0
    deadline = time.monotonic() + 60
    while last < 400 and time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        last = int(line)
    proc.send_signal(signal.SIGKILL)
    proc.wait(10)
    assert last >= 400, "child recorder did not get going"
    (path,) = unfinished_files(d)
    return path, last


def test_cut_file_is_unreadable_by_the_seeking_reader(cut_file: tuple[Path, int]) -> None:
    path, _ = cut_file
    with open(path, "rb") as f, pytest.raises(Exception):  # noqa: B017
        list(make_reader(f).iter_messages())


def test_recover_after_sigkill_keeps_all_but_the_last_chunk(cut_file: tuple[Path, int],
                                                            tmp_path: Path) -> None:
    path, last_printed = cut_file
    chunks_on_disk, messages_on_disk = _complete_chunks(path)
    out = tmp_path / "recovered.mcap"
    report = recover(path, out)
    assert not report.input_was_complete
    assert report.chunks_corrupt == 0
    assert report.chunks_kept == chunks_on_disk
    assert report.messages_kept == messages_on_disk
    assert report.metadata_kept == 3  # recording, config, calibration
    with open(out, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.message_count == messages_on_disk
        counters = [int(decode_image(m.data)[0][0, 0]) for _, ch, m in
                    reader.iter_messages() if ch.topic == "/camera/left/image"]
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
    assert counters == list(range(len(counters)))  # a gap-free prefix
    assert meta["calibration"]["yaml"] == "cal: 1\n"
    # What is lost: the open chunk (~7 frames of 2 KiB + frame info in 16 KiB) and what was
    # still queued.
    frames_per_chunk = messages_on_disk / chunks_on_disk / 2  # image + frame_info per frame
    assert len(counters) >= last_printed - 3 * frames_per_chunk - 20


def test_recover_cli_on_active_file_writes_mcap_beside_it(cut_file: tuple[Path, int],
                                                          tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]
                                                          ) -> None:
    path, _ = cut_file
    copy = tmp_path / path.name
    copy.write_bytes(path.read_bytes())
    assert cli.main(["recover", str(copy)]) == 0
    out = capsys.readouterr().out
    expected = default_output(copy)
    assert expected.name == path.name.removesuffix(".active")
    assert f"{expected}: kept " in out and "cut input" in out
    assert copy.exists()  # the input is never modified
    assert cli.main(["recover", str(copy)]) == cli.EXIT_USAGE  # output exists now
    assert "exists" in capsys.readouterr().err
    assert cli.main(["recover", str(copy), "--force"]) == 0


def _complete_file(path: Path, n: int = 50) -> None:
    from mcap.writer import Writer

    with open(path, "wb") as f:
        w = Writer(f, chunk_size=4096)
        w.start()
        w.add_metadata("m", {"k": "v"})
        sid = w.register_schema(S.RAW_IMAGE.name, "protobuf", S.RAW_IMAGE.data)
        cid = w.register_channel("/x", "protobuf", sid)
        for i in range(n):
            img = np.full((16, 16), i, np.uint16)
            frame = Frame(image=img, pixel_format="Mono16", host_ns=i, seq=i)
            w.add_message(cid, i, S.frame_records("left", frame, i)[0].payload, i)
        w.finish()


def test_recover_complete_file_keeps_everything(tmp_path: Path) -> None:
    src = tmp_path / "a.mcap"
    _complete_file(src)
    report = recover(src)
    assert report.output == tmp_path / "a.recovered.mcap"
    assert report.input_was_complete and report.messages_kept == 50
    assert report.metadata_kept == 1


def test_corrupt_chunk_in_the_middle_is_skipped(tmp_path: Path) -> None:
    src = tmp_path / "a.mcap"
    _complete_file(src, 200)
    data = bytearray(src.read_bytes())
    with open(src, "rb") as f:
        idx = make_reader(f).get_summary().chunk_indexes
    assert len(idx) >= 3
    mid = idx[1]
    data[mid.chunk_start_offset + mid.chunk_length - 20] ^= 0xFF  # inside compressed data
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    report = recover(bad, tmp_path / "out.mcap")
    assert report.chunks_corrupt == 1
    assert report.chunks_kept == len(idx) - 1
    with open(tmp_path / "out.mcap", "rb") as f:
        assert sum(1 for _ in make_reader(f).iter_messages()) == report.messages_kept < 200


def test_not_an_mcap_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "x.mcap"
    src.write_bytes(b"hello world, not mcap")
    with pytest.raises(ValueError, match="not an MCAP file"):
        recover(src)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.mcap"]  # no half-written output
    assert cli.main(["recover", str(src)]) == cli.EXIT_USAGE
    assert "not an MCAP file" in capsys.readouterr().err
    assert cli.main(["recover", str(tmp_path / "missing.mcap")]) == cli.EXIT_USAGE


def test_cut_inside_the_header_gives_an_empty_valid_file(tmp_path: Path) -> None:
    src = tmp_path / "a.mcap"
    _complete_file(src)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(src.read_bytes()[:12])
    report = recover(cut, tmp_path / "o.mcap")
    assert report.messages_kept == 0 and report.truncated_bytes == 4
    with open(tmp_path / "o.mcap", "rb") as f:
        assert list(make_reader(f).iter_messages()) == []


def test_recover_unfinished_at_start(cut_file: tuple[Path, int], tmp_path: Path) -> None:
    path, _ = cut_file
    d = tmp_path / "rec"
    d.mkdir()
    copy = d / path.name
    copy.write_bytes(path.read_bytes())
    junk = d / "ogiflow-20200101T000000000Z-0001.mcap.active"
    junk.write_bytes(b"garbage, not an mcap")
    (report,) = recover_unfinished(d)
    assert report.output == d / path.name.removesuffix(".active")
    assert not copy.exists() and report.output.exists()
    assert junk.exists()  # left in place for a human, the others still recovered
    assert unfinished_files(d) == [junk]
