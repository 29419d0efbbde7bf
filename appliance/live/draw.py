"""What the live view draws: Rerun archetypes for each item, logged through a callable.

Called only from the live thread (:mod:`appliance.live.view`): ``log(path, archetype)`` is
that thread's ``RecordingStream.log``. Entity paths are listed in the view's docstring and
laid out by :mod:`appliance.live.blueprint`.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from appliance.live import MAX_ARROWS
from appliance.live.colour import (
    GAS_COLOR,
    GAS_OPACITY,
    disparity_bgr,
    encode_jpeg,
    flow_bgr,
    ir_u8,
    operator_arrows,
    to_u8,
)
from appliance.live.items import LiveFrame, LiveScalars
from appliance.live.status import OperatorStatus, events_markdown, status_markdown

#: ``log(entity_path, archetype, static=False)``.
Log = Callable[..., None]

WIND_COLOR = (30, 110, 230)
#: Arrows on the operator's picture (a readable picture: fewer, longer arrows).
OPERATOR_ARROWS = MAX_ARROWS // 4
#: Arrows show the displacement over this many seconds (velocity in m/s times this).
ARROW_SCALE_S = 0.2


def log_styles(log: Log) -> None:
    """Static styles: series colours and names, the gas class of the operator's overlay."""
    # rerun is imported only when a live view starts (it costs ~1-2 s and memory).
    import rerun as rr

    for quantity in ("speed", "angle/x", "angle/y", "angle/z"):
        for src, color, label in (("gas", GAS_COLOR, "gas (scene flow)"),
                                  ("wind", WIND_COLOR, "wind (anemometer)")):
            log(f"plots/{quantity}/{src}",
                rr.SeriesLines(colors=[color], names=[label], widths=[2.0]), static=True)
    # The gas overlay of the operator's picture: class 1 = gas, in the gas colour.
    log("operator/ir", rr.AnnotationContext(
        [(0, "background", (0, 0, 0, 0)), (1, "gas", GAS_COLOR)]), static=True)
    for name, color, label in (("measured", GAS_COLOR, "emission rate (kg/h)"),
                               ("truth", (0, 0, 0), "simulated release (kg/h)")):
        log(f"operator/rate/{name}",
            rr.SeriesLines(colors=[color], names=[label], widths=[2.0]), static=True)
    log("operator/wind", rr.SeriesLines(colors=[WIND_COLOR], names=["wind (m/s)"],
                                        widths=[2.0]), static=True)


def log_image(log: Log, path: str, bgr_or_gray: np.ndarray, jpeg_quality: int) -> None:
    """An image as JPEG (raw uint16 would be 9.4 MB/s at 2 x 30 Hz)."""
    # rerun is imported only when a live view starts (it costs ~1-2 s and memory).
    import rerun as rr

    data = encode_jpeg(bgr_or_gray, jpeg_quality)
    log(path, rr.EncodedImage(contents=data, media_type="image/jpeg"))


def log_pictures(log: Log, f: LiveFrame, jpeg_quality: int) -> None:
    """The frame's pictures: operator's IR view, differential images, flow, disparity, gas
    mask and the 3D velocity arrows at the virtual gas surface."""
    # rerun is imported only when a live view starts (it costs ~1-2 s and memory).
    import rerun as rr

    log_operator(log, f, jpeg_quality)
    for path, image in (("cam/left/diff", None if f.diff_left is None else to_u8(f.diff_left)),
                        ("cam/right/diff",
                         None if f.diff_right is None else to_u8(f.diff_right)),
                        ("flow", None if f.flow is None else flow_bgr(f.flow)),
                        ("disparity", None if f.disparity is None
                         else disparity_bgr(f.disparity)),
                        ("gas/mask", None if f.gas_mask is None
                         else to_u8(np.asarray(f.gas_mask, bool)))):
        if image is not None:
            log_image(log, path, image, jpeg_quality)
    if f.points3d is not None and f.velocity3d is not None:
        pts = np.asarray(f.points3d, np.float32).reshape(-1, 3)
        vel = np.asarray(f.velocity3d, np.float32).reshape(-1, 3)
        ok = np.isfinite(pts).all(1) & np.isfinite(vel).all(1)
        pts, vel = pts[ok], vel[ok]
        if len(pts) > MAX_ARROWS:
            keep = np.linspace(0, len(pts) - 1, MAX_ARROWS).astype(int)
            pts, vel = pts[keep], vel[keep]
        log("gas/velocity3d", rr.Arrows3D(origins=pts, vectors=vel * ARROW_SCALE_S,
                                          colors=[GAS_COLOR]))


def log_plots(log: Log, f: LiveFrame) -> None:
    """Gas, wind and (simulated) true speed and directional angles (paper Fig. 8)."""
    # rerun is imported only when a live view starts (it costs ~1-2 s and memory).
    import rerun as rr

    for src, speed, angles in (("gas", f.gas_speed_m_s, f.gas_angles_deg),
                               ("wind", f.wind_speed_m_s, f.wind_angles_deg),
                               ("truth", f.truth_speed_m_s, f.truth_angles_deg)):
        if speed is not None and np.isfinite(speed):
            log(f"plots/speed/{src}", rr.Scalars(float(speed)))
        if angles is not None:
            for axis, a in zip("xyz", angles, strict=True):
                if a is not None and np.isfinite(a):
                    log(f"plots/angle/{axis}/{src}", rr.Scalars(float(a)))


def log_operator(log: Log, f: LiveFrame, jpeg_quality: int) -> None:
    """The operator's picture: raw IR, the gas region in colour, in-plane velocity."""
    # rerun is imported only when a live view starts (it costs ~1-2 s and memory).
    import rerun as rr

    if f.raw_left is None:
        return
    log_image(log, "operator/ir", ir_u8(f.raw_left), jpeg_quality)
    if f.gas_mask is not None:
        log("operator/ir/gas", rr.SegmentationImage(np.asarray(f.gas_mask, np.uint8),
                                                    opacity=GAS_OPACITY))
    arrows = operator_arrows(f.pixels, f.velocity3d, OPERATOR_ARROWS)
    if arrows is not None:
        log("operator/ir/velocity", rr.Arrows2D(origins=arrows[0], vectors=arrows[1],
                                                colors=[GAS_COLOR]))


def log_status(log: Log, s: OperatorStatus) -> None:
    """The operator's status and event list (Markdown), emission rate and wind plots."""
    # rerun is imported only when a live view starts (it costs ~1-2 s and memory).
    import rerun as rr

    log("operator/status", rr.TextDocument(status_markdown(s),
                                           media_type=rr.MediaType.MARKDOWN))
    log("operator/events", rr.TextDocument(events_markdown(s.events),
                                           media_type=rr.MediaType.MARKDOWN))
    for name, v in (("measured", s.rate_kg_h), ("truth", s.true_rate_kg_h)):
        if v is not None and np.isfinite(v):
            log(f"operator/rate/{name}", rr.Scalars(float(v)))
    if s.wind_m_s is not None and all(np.isfinite(s.wind_m_s)):
        log("operator/wind", rr.Scalars(float(np.linalg.norm(s.wind_m_s))))


def log_scalars(log: Log, s: LiveScalars) -> None:
    """Scalars under ``prefix/<name>`` (health), non-finite values left out."""
    # rerun is imported only when a live view starts (it costs ~1-2 s and memory).
    import rerun as rr

    for name, value in s.values.items():
        if value is not None and np.isfinite(value):
            log(f"{s.prefix}/{name}", rr.Scalars(float(value)))
