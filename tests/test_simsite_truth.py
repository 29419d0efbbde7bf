"""The simulated site's truth: computed from the scene's files two frames at a time.

A frame holds the scene's 3D fields; the whole loop at once takes 0.9 GB (320x240) or
3.3 GB (640x480) of the daemon's memory.
"""

from __future__ import annotations

import weakref
from dataclasses import replace
from pathlib import Path

import numpy as np

from appliance.runtime import simsite
from processing.synthetic import read_frame, write_sequence
from processing.synthetic.reference import triplet_reference
from processing.synthetic.sequences import generate_sequence, preset_field


def test_truth_holds_two_frames_and_is_the_per_triple_reference(tmp_path: Path,
                                                                monkeypatch) -> None:
    cfg = replace(preset_field(n_frames=6, voxel_m=0.12, release_rate_g_s=3.0),
                  spinup_steps=60)
    folder = tmp_path / "scene"
    write_sequence(folder, cfg.meta(), generate_sequence(cfg))
    alive: set[int] = set()
    most = 0

    def counting(directory: Path, index: int, meta: dict | None = None) -> object:
        nonlocal most
        frame = read_frame(directory, index, meta)
        alive.add(index)
        weakref.finalize(frame, alive.discard, index)
        most = max(most, len(alive))
        return frame

    monkeypatch.setattr(simsite, "read_frame", counting)
    truth = simsite.SceneTruth(folder)
    assert most <= 2

    frames = [read_frame(folder, i) for i in range(cfg.n_frames)]
    for k in range(cfg.n_frames - 2):
        v, mask = triplet_reference(frames[k], frames[k + 1])
        want = v[mask].astype(np.float64).mean(axis=0) if mask.any() else None
        got = truth.mean_velocity(k)
        if want is None:
            assert got is None
        else:
            np.testing.assert_array_equal(got, want)
    # the two triples that wrap around the loop have none
    assert truth.mean_velocity(cfg.n_frames - 2) is None
    assert truth.mean_velocity(cfg.n_frames - 1) is None
    assert truth.release_g_s == [f.release_rate_g_s for f in frames]
