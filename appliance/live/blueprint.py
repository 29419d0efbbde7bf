"""The live view's layout, declared in code as a Rerun blueprint."""

from __future__ import annotations

from typing import Any

__all__ = ["blueprint"]


def blueprint() -> Any:
    """The viewer layout: images and 3D velocity left, the Fig. 8 comparison and health right.

    Returns a ``rerun.blueprint.Blueprint`` (typed Any: rerun is imported only here, when a
    view starts).
    """
    import rerun.blueprint as rrb

    images = rrb.Grid(
        rrb.Spatial2DView(origin="cam/left/diff", name="left differential image"),
        rrb.Spatial2DView(origin="cam/right/diff", name="right differential image"),
        rrb.Spatial2DView(origin="flow", name="optical flow w_L"),
        rrb.Spatial2DView(origin="disparity", name="disparity d_L"),
        rrb.Spatial2DView(origin="gas/mask", name="gas mask"),
        rrb.Spatial3DView(origin="gas/velocity3d", name="3D gas velocity V"),
    )
    plots = rrb.Vertical(
        rrb.TimeSeriesView(origin="plots/speed", name="mean speed (m/s): gas vs wind"),
        rrb.TimeSeriesView(origin="plots/angle/x", name="angle to X (deg)"),
        rrb.TimeSeriesView(origin="plots/angle/y", name="angle to Y (deg)"),
        rrb.TimeSeriesView(origin="plots/angle/z", name="angle to Z (deg)"),
        rrb.TimeSeriesView(origin="health", name="health"),
    )
    # A live view follows the newest data on the pair-index timeline.
    time_panel = rrb.TimePanel(timeline="frame", play_state="following")
    return rrb.Blueprint(rrb.Horizontal(images, plots, column_shares=[3, 2]), time_panel,
                         collapse_panels=True)
