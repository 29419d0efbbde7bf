"""Tests of the ``ogiflow-synthetic/1`` format and of ``ogiflow simulate``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from appliance import cli
from processing.synthetic.sequences import preset
from processing.synthetic.storage import (
    FORMAT,
    SequenceFormatError,
    SyntheticFrame,
    frame_path,
    iter_frames,
    list_sequences,
    read_frame,
    read_sequence_meta,
    write_sequence,
)

H, W = 6, 8


def _frame(i: int, rng: np.random.Generator) -> SyntheticFrame:
    vel = rng.normal(0, 1, (H, W, 3)).astype(np.float32)
    vel[0, 0] = np.nan
    return SyntheticFrame(
        index=i, t_s=0.001 * i,
        left=rng.integers(0, 65535, (H, W), dtype=np.uint16),
        right=rng.integers(0, 65535, (H, W), dtype=np.uint16),
        gt_velocity=vel,
        gt_position=rng.normal(2, 0.1, (H, W, 3)).astype(np.float32),
        gt_mask=rng.random((H, W)) > 0.5,
        column_density_ppm_m=rng.random((H, W)).astype(np.float32) * 500,
        jitter_left_px=np.array([0.1, -0.2]), jitter_right_px=np.zeros(2),
    )


def _meta(n: int) -> dict:
    meta = preset("table2_1", n_frames=n).meta()
    meta["camera"].update(width=W, height=H)
    return meta


def _write(tmp_path: Path, n: int = 3) -> tuple[Path, list[SyntheticFrame]]:
    rng = np.random.default_rng(0)
    frames = [_frame(i, rng) for i in range(n)]
    return write_sequence(tmp_path / "seq", _meta(n), frames), frames


def test_round_trip(tmp_path: Path) -> None:
    d, frames = _write(tmp_path)
    meta = read_sequence_meta(d)
    assert meta["format"] == FORMAT and meta["n_frames"] == 3
    assert meta["camera"]["s_px"] == 780.0 and meta["wind_m_s"] == [0.1, -1.5, -0.1]
    back = list(iter_frames(d))
    assert [f.index for f in back] == [0, 1, 2]
    for a, b in zip(frames, back, strict=True):
        for key, arr in a.arrays().items():
            np.testing.assert_array_equal(getattr(b, key), arr)
            assert np.asarray(getattr(b, key)).dtype == arr.dtype
    assert list_sequences(tmp_path) == [d]
    assert not list((tmp_path / "seq").glob("*.part"))
    # rewriting with fewer frames leaves no stale frame files behind
    write_sequence(d, _meta(2), frames[:2])
    assert sorted(p.name for p in d.glob("frame_*")) == ["frame_00000.npz", "frame_00001.npz"]


def test_missing_and_bad_meta(tmp_path: Path) -> None:
    with pytest.raises(SequenceFormatError, match="not a sequence directory"):
        read_sequence_meta(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(SequenceFormatError, match=r"meta\.json: missing"):
        read_sequence_meta(tmp_path / "empty")
    d, _ = _write(tmp_path)
    (d / "meta.json").write_text("{not json")
    with pytest.raises(SequenceFormatError, match="not valid JSON"):
        read_sequence_meta(d)
    meta = _meta(3)
    meta["format"] = "something/9"
    (d / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(SequenceFormatError, match="format"):
        read_sequence_meta(d)
    meta = _meta(3)
    del meta["frame_interval_s"]
    (d / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(SequenceFormatError, match="frame_interval_s"):
        read_sequence_meta(d)


def test_bad_frame_files(tmp_path: Path) -> None:
    d, frames = _write(tmp_path)
    with pytest.raises(IndexError):
        read_frame(d, 3)
    frame_path(d, 1).unlink()
    with pytest.raises(SequenceFormatError, match=r"frame_00001\.npz: missing"):
        read_frame(d, 1)
    raw = frame_path(d, 0).read_bytes()
    frame_path(d, 0).write_bytes(raw[: len(raw) // 2])  # truncated by a crash
    with pytest.raises(SequenceFormatError, match="unreadable or truncated"):
        read_frame(d, 0)
    arrays = frames[2].arrays()
    arrays["left"] = arrays["left"].astype(np.float32)
    np.savez(frame_path(d, 2), **arrays)
    with pytest.raises(SequenceFormatError, match="left is float32"):
        read_frame(d, 2)
    del arrays["gt_mask"]
    np.savez(frame_path(d, 2), **arrays)
    with pytest.raises(SequenceFormatError, match="gt_mask"):
        read_frame(d, 2)


def test_write_checks_frame_count_and_order(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    with pytest.raises(ValueError, match="n_frames=3"):
        write_sequence(tmp_path / "a", _meta(3), [_frame(0, rng), _frame(1, rng)])
    assert not (tmp_path / "a" / "meta.json").exists()  # an unfinished sequence has no meta
    with pytest.raises(ValueError, match="in order"):
        write_sequence(tmp_path / "b", _meta(2), [_frame(1, rng), _frame(0, rng)])


def test_simulate_command_writes_readable_sequences(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["simulate", "--out", str(tmp_path), "--grid-scale", "0.2", "--frames", "2",
            "--spinup-steps", "8"]
    assert cli.main(args) == 0
    out, err = capsys.readouterr()
    assert "table2_3: 2 frames" in out and "2/2 frames" in err
    seqs = list_sequences(tmp_path)
    assert [p.name for p in seqs] == ["table2_1", "table2_2", "table2_3"]
    meta = read_sequence_meta(seqs[0])
    assert meta["simulation"]["grid_zyx"] == [20, 20, 20]
    assert meta["statistics"]["n_frames"] == 2
    f = read_frame(seqs[0], 1)
    assert f.left.shape == (240, 320) and f.gt_mask.any()
    # existing output is never overwritten silently
    assert cli.main(args) == 2
    assert "--force" in capsys.readouterr().err


def test_simulate_command_rejects_bad_input(capsys: pytest.CaptureFixture[str],
                                            tmp_path: Path) -> None:
    assert cli.main(["simulate", "--out", str(tmp_path), "--preset", "nope"]) == 2
    assert "unknown preset 'nope'" in capsys.readouterr().err
    assert cli.main(["simulate", "--out", str(tmp_path), "--frames", "0"]) == 2
    assert "--frames" in capsys.readouterr().err
