"""The live view's layout, declared in code as a Rerun blueprint.

Two tabs. ``operator`` answers an operator's questions at a glance: the left camera's IR
picture with the gas region in colour and the in-plane gas velocity as arrows (as OGI
cameras show gas), the status in words (LEAK / no leak, rate, duration, wind, health), the
emission rate and wind over time, and the list of leak events. ``engineering`` holds the
fields of the method (differential images, flow, disparity, mask, 3D velocity) and the
paper's Fig. 8 comparison of gas velocity and wind, plus health.
"""

from __future__ import annotations

from typing import Any

__all__ = ["blueprint"]


def blueprint() -> Any:
    """The viewer layout (a ``rerun.blueprint.Blueprint``; rerun is imported only here)."""
    # rerun is imported only when a live view starts (it costs ~1-2 s and memory).
    import rerun.blueprint as rrb

    operator = rrb.Horizontal(
        rrb.Spatial2DView(origin="operator/ir", name="gas camera (left IR) with gas"),
        rrb.Vertical(
            rrb.TextDocumentView(origin="operator/status", name="status"),
            rrb.TimeSeriesView(origin="operator", contents=["+ operator/rate/**",
                                                            "+ operator/wind"],
                               name="emission rate (kg/h) and wind (m/s)"),
            rrb.TextDocumentView(origin="operator/events", name="leak events"),
            row_shares=[3, 2, 2],  # the status first: its last line is health
        ),
        column_shares=[3, 2], name="operator",
    )
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
    engineering = rrb.Horizontal(images, plots, column_shares=[3, 2], name="engineering")
    # A live view follows the newest data on the pair-index timeline.
    time_panel = rrb.TimePanel(timeline="frame", play_state="following")
    return rrb.Blueprint(rrb.Tabs(operator, engineering, active_tab=0), time_panel,
                         collapse_panels=True)
