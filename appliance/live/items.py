"""What producers hand to the live view: plain dataclasses, built in any thread.

Only the live view's own thread calls Rerun (:mod:`appliance.live.view`); everything else
builds one of these items and pushes it, which never blocks.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["LiveFrame", "LiveScalars", "LiveStats", "health_scalars"]


@dataclass
class LiveFrame:
    """What the live view shows for one processed stereo pair; every image field is optional.

    The arrays must belong to this item (not views into the ring buffer): the live thread
    reads them later.

    Attributes
    ----------
    frame
        Pair index (the ``frame`` timeline).
    t_capture_ns
        Capture time of the pair, UNIX ns (the ``capture_time`` timeline).
    diff_left, diff_right
        (H, W) differential images (paper Eq. 2), float in [0, 1], uint8 or uint16.
    flow
        (H, W, 2) optical flow w_L = (u, v) in px/frame (Eq. 5), shown colour-coded.
    disparity
        (H, W) disparity d_L in px (Eq. 6); NaN where undefined.
    gas_mask
        (H, W) bool gas segmentation (Eq. 9).
    points3d, velocity3d
        (N, 3) points of the virtual gas surface (m) and their 3D velocity V (m/s, Eq. 4),
        left camera frame.
    gas_speed_m_s, gas_angles_deg
        Mean gas velocity magnitude and directional angles to X, Y, Z (paper footnote 1).
    wind_speed_m_s, wind_angles_deg
        The anemometer's wind in the camera frame at this pair's time.
    truth_speed_m_s, truth_angles_deg
        Simulated runs only: the simulator's true mean gas velocity for this triple.
    pixels
        (N, 2) image positions (x, y) of ``points3d`` in the left image, px.
    raw_left
        (H, W) raw left frame (counts), the operator's IR picture.
    raw_capture_ns
        Capture time of ``raw_left``, UNIX ns (the triple's first frame; ``t_capture_ns`` is
        its middle one).
    camera
        The camera of ``raw_left`` and of the image coordinates: "left", or the surviving
        camera of a single-camera result.
    """

    frame: int
    t_capture_ns: int
    diff_left: np.ndarray | None = None
    diff_right: np.ndarray | None = None
    flow: np.ndarray | None = None
    disparity: np.ndarray | None = None
    gas_mask: np.ndarray | None = None
    points3d: np.ndarray | None = None
    velocity3d: np.ndarray | None = None
    gas_speed_m_s: float | None = None
    gas_angles_deg: tuple[float, float, float] | None = None
    wind_speed_m_s: float | None = None
    wind_angles_deg: tuple[float, float, float] | None = None
    truth_speed_m_s: float | None = None
    truth_angles_deg: tuple[float, float, float] | None = None
    pixels: np.ndarray | None = None
    raw_left: np.ndarray | None = None
    raw_capture_ns: int | None = None
    camera: str = "left"

    @property
    def has_pictures(self) -> bool:
        """Whether it carries the pictures (differential images, disparity, IR): results
        without them (``worker_result.pack_result``) feed the plots only."""
        return any(a is not None for a in (self.diff_left, self.diff_right, self.disparity,
                                           self.raw_left))


@dataclass
class LiveScalars:
    """Scalars logged under ``prefix/<name>`` (e.g. health: ``health/cam_left_rate_hz``)."""

    t_capture_ns: int
    values: Mapping[str, float | None]
    prefix: str = "health"
    frame: int | None = None


@dataclass
class LiveStats:
    """Counters of the live view."""

    pushed: int = 0
    dropped: int = 0
    logged: int = 0
    errors: int = 0
    #: Frames after which Rerun had not sent everything within ``DRAIN_TIMEOUT_S``.
    slow_sends: int = 0
    last_error: str = ""
    url: str = ""


def health_scalars(snapshot: Any) -> LiveScalars:
    """A :class:`LiveScalars` of the numbers worth plotting from a health snapshot."""
    values: dict[str, float | None] = {}
    for name, s in snapshot.streams.items():
        key = name.replace("/", "_")
        values[f"{key}_rate_hz"] = s.rate_hz
        values[f"{key}_drops"] = float(s.drops)
    for name, lat in snapshot.latencies.items():
        values[f"{name.replace('/', '_')}_latency_ms"] = lat["mean_ms"]
    for name, v in snapshot.counters.items():
        values[name] = float(v)
    values.update(snapshot.gauges)
    return LiveScalars(t_capture_ns=snapshot.t_wall_ns, values=values)

