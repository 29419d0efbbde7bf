"""Folders a user names are searched through symlinked folders, once each, without looping."""

from __future__ import annotations

import os
from pathlib import Path

from appliance.evaluation.emission import find_emission_sequences
from appliance.evaluation.footage import find_sets
from appliance.paths import walk
from appliance.reprocess.jobs import expand_inputs
from processing.synthetic.storage import META_NAME


def _linked_archive(tmp_path: Path) -> tuple[Path, Path]:
    """``work/`` holding a link to ``archive/site`` (with a link back to ``work``)."""
    archive = tmp_path / "archive" / "site" / "seq"
    archive.mkdir(parents=True)
    work = tmp_path / "work"
    work.mkdir()
    os.symlink(tmp_path / "archive" / "site", work / "site")
    os.symlink(work, archive / "back")  # a cycle: must not loop
    return work, archive


def test_walk_enters_a_symlinked_folder_once_and_does_not_loop(tmp_path: Path) -> None:
    work, archive = _linked_archive(tmp_path)
    (archive / "a.txt").write_text("x")
    names = [p.relative_to(work).as_posix() for p in walk(work)]
    assert names == ["site", "site/seq", "site/seq/a.txt", "site/seq/back"]


def test_evaluations_and_reprocessing_find_what_a_link_leads_to(tmp_path: Path) -> None:
    work, archive = _linked_archive(tmp_path)
    (archive / META_NAME).write_text("{}")
    (archive / "frame0001.png").write_bytes(b"")
    (archive / "ogiflow-x.mcap").write_bytes(b"")
    assert find_emission_sequences(work) == [work / "site" / "seq"]
    assert list(find_sets(work)) == ["site/seq"]
    assert expand_inputs([str(work)]) == [(archive / "ogiflow-x.mcap").resolve()]
