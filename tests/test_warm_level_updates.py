"""benchmarks/warm_level_updates.py: how far each pyramid level of a warm triple moves a field."""

from __future__ import annotations

import numpy as np

from appliance.evaluation import bench_input as bm
from benchmarks.warm_level_updates import measure
from processing.chain import ChainParameters, ChainState, SceneFlowResult, compute_scene_flow
from processing.chain.parameters import WARM_DISPARITY_OPTIONS, WARM_FLOW_OPTIONS
from processing.solvers import lagged

original = lagged.lagged_iterations


def _fields(results: list[SceneFlowResult]) -> list[np.ndarray]:
    return [a for r in results for a in (r.flow, r.disparity, r.disparity_change)]


def test_every_warm_level_of_both_solvers_is_measured_and_the_chain_is_not_changed() -> None:
    frames = bm.blob_frames(n_frames=6)
    geo = bm.geometry(frames.image_size)
    state = ChainState()
    triples = bm.iter_triples(frames)
    # The whole frame: the active region's box would change the levels' sizes per triple.
    params = ChainParameters(active_region=False)
    unwatched = [compute_scene_flow(*next(triples), geo, params, state) for _ in range(4)]
    watched: list[SceneFlowResult] = []
    updates = measure(frames, params, 4, watched)
    assert lagged.lagged_iterations is original  # put back
    assert all(np.array_equal(a, b, equal_nan=True)
               for a, b in zip(_fields(unwatched), _fields(watched), strict=True))
    for solver, options in (("Flow", WARM_FLOW_OPTIONS), ("Disparity", WARM_DISPARITY_OPTIONS)):
        widths = sorted(w for s, w in updates if s == solver)
        skipped = options.get("finest_level", 0)  # interpolated, not solved
        assert len(widths) == options["n_levels"] - skipped
        assert (widths[-1] == frames.image_size[0]) == (skipped == 0)
        for w in widths:
            rows = np.array(updates[(solver, w)])
            assert rows.shape == (3, 3)  # triples 2-4 are warm, the first cold
            assert np.all(np.isfinite(rows)) and np.all(rows >= 0)
    # The blob's texture moves between frames: the coarsest flow level of a warm start corrects.
    coarsest = min(w for s, w in updates if s == "Flow")
    assert np.median(np.array(updates[("Flow", coarsest)])[:, 0]) > 0.0
