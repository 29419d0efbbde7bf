"""What a worker sends the daemon for one window: :class:`WorkerResult` and how it is packed.

Only what crosses the process boundary travels: the chain result's summary, gas mask and
flow at the gas pixels always, the full fields only when the daemon asks for them
(:func:`pack_result`, :func:`pack_single`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from appliance.live import MAX_ARROWS
from processing.chain.binning import block_of, grow, upsampled_result, upsampled_summary
from processing.chain.driver import SceneFlowResult
from processing.emission.rate import FrameRate


@dataclass
class WorkerResult:
    """One processed window, as sent from a worker to the daemon (picklable).

    Times are host monotonic ns of the three pairs (mean of both cameras' capture times);
    fields are those of the left view at t0, (H, W) unless stated.
    """

    worker: int
    pair_indices: tuple[int, int, int]
    t_mono_ns: tuple[int, int, int]
    t_wall_ns: int
    skipped: int
    done_mono_ns: int
    error: str | None = None
    summary: dict[str, Any] = field(default_factory=dict)
    timings_ms: dict[str, float] = field(default_factory=dict)
    dt_s: float | None = None
    diff_scale: float | None = None
    rejected_shifts: int = 0
    diff_left: np.ndarray | None = None  # uint8, 0.5 = no change
    diff_right: np.ndarray | None = None
    flow: np.ndarray | None = None  # (H, W, 2) float32 px (with the fields only)
    gas_flow: np.ndarray | None = None  # (N, 2) float32 px at the gas pixels, row-major
    disparity: np.ndarray | None = None  # float32 px
    disparity_change: np.ndarray | None = None
    velocity: np.ndarray | None = None  # (H, W, 3) float32 m/s
    valid: np.ndarray | None = None  # bool
    gas_mask: np.ndarray | None = None  # bool
    points3d: np.ndarray | None = None  # (N, 3) m, gas pixels only
    velocity3d: np.ndarray | None = None  # (N, 3) m/s
    pixels: np.ndarray | None = None  # (N, 2) int32 (x, y) of those gas pixels
    raw_left: np.ndarray | None = None  # uint16 raw left frame at t0 (the operator's view)
    rate: FrameRate | None = None  # emission rate of the triple (None: not computed)
    warm: bool = False  # the solvers started from the worker's previous triple
    #: Whether the left and the right camera's offset stepped between the triple's last
    #: two frames (a shutter, a drift), levelled out of D(t1): each frame pair once.
    offset_levelled: tuple[bool, bool] = (False, False)
    #: The camera of a single-camera result ("left"/"right"; its diff and raw frame travel
    #: as ``diff_left``/``raw_left``, the image the zones and the operator see); None: stereo.
    single_camera: str | None = None

    @property
    def has_fields(self) -> bool:
        """Whether the full fields came along (see :func:`pack_result`)."""
        return self.flow is not None if self.single_camera else self.velocity is not None


def _to_u8(image: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(image * 255.0), 0, 255).astype(np.uint8)


def pack_result(res: SceneFlowResult, base: WorkerResult,
                raw_left: np.ndarray | None = None, *, fields: bool = True,
                binning: int = 1) -> WorkerResult:
    """Fill ``base`` with what the daemon needs from a chain result (and the raw left frame
    at t0, which the operator's view shows under the gas overlay).

    Without ``fields`` only what every result needs travels - summary, gas mask and the
    flow at the gas pixels (the leak events), the gas arrows - about 0.1-0.3 MB instead of
    2.6 MB at 320x240: the daemon records the full fields of every N-th result and shows
    pictures a few times a second, and pickling, piping and unpickling the rest cost both
    processes ~2-3 ms each.

    With ``binning`` k > 1, ``res`` is the chain's result on k x k blocks
    (``compute_scene_flow(..., at_camera_size=False)``) and what travels is at the cameras'
    size, as :func:`processing.chain.binning.upsampled_result` would give it; only what
    travels is grown (the full fields of every triple cost a 640x480 worker 5 % of its time).
    """
    if binning > 1 and fields:
        res, binning = upsampled_result(res, binning), 1
    k = binning
    base.summary = upsampled_summary(res.summary, k).to_dict()
    base.timings_ms = dict(res.timings_ms)
    base.dt_s = res.dt_s
    base.diff_scale = res.diff_scale
    base.rejected_shifts = res.rejected_shifts
    base.warm = bool(res.warm)
    base.offset_levelled = (bool(res.offset_steps[0]), bool(res.offset_steps[1]))
    base.gas_mask = grow(res.gas_mask, k) if k > 1 else res.gas_mask
    w = base.gas_mask.shape[1]
    gas = np.flatnonzero(base.gas_mask)
    flow = res.flow.reshape(-1, 2)
    base.gas_flow = flow[gas] if k == 1 else flow[block_of(gas, w, k)] * np.float32(k)
    if fields:
        base.flow = res.flow
        base.diff_left = _to_u8(res.diff_left[0])
        base.diff_right = _to_u8(res.diff_right[0])
        base.disparity = res.disparity
        base.disparity_change = res.disparity_change
        base.velocity = res.velocity
        base.valid = res.valid
    valid = grow(res.valid, k) if k > 1 else res.valid
    sel = np.flatnonzero((base.gas_mask & valid).ravel())
    if sel.size > MAX_ARROWS:
        sel = sel[:: int(np.ceil(sel.size / MAX_ARROWS))]
    at = sel if k == 1 else block_of(sel, w, k)
    base.points3d = res.position.reshape(-1, 3)[at].copy()
    base.velocity3d = res.velocity.reshape(-1, 3)[at].copy()
    base.pixels = np.column_stack([sel % w, sel // w]).astype(np.int32)
    if raw_left is not None and fields:
        base.raw_left = np.array(raw_left, copy=True)
    return base


def pack_single(tr: Any, base: WorkerResult, camera: str, *, fields: bool = True) -> None:
    """Fill ``base`` with a single-camera triple (:class:`~appliance.runtime.single_camera.
    MonoTriple`): gas mask and the flow at its pixels always, the flow, I_diff and the raw
    frame with the fields; no disparity, no 3D velocity."""
    n = int(tr.mask.sum())
    flags = ["single_camera"] + ([] if camera == "left" else ["right_camera"])
    base.single_camera = camera
    base.summary = {"gas_pixel_count": n, "valid": False, "mean_velocity": None,
                    "speed": None, "angles_deg": None, "c_usf": None, "flags": flags}
    base.timings_ms = {**tr.timings_ms, "total": sum(tr.timings_ms.values())}
    base.rejected_shifts = tr.rejected_shifts
    levelled = bool(tr.offset_step1)
    base.offset_levelled = (levelled, False) if camera == "left" else (False, levelled)
    base.gas_mask = tr.mask
    base.gas_flow = tr.flow.reshape(-1, 2)[np.flatnonzero(tr.mask)]
    if fields:
        base.flow = tr.flow
        base.diff_left = _to_u8(tr.diff)
        base.raw_left = np.array(tr.raw, copy=True)
