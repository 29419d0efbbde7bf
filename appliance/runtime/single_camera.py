"""The single-camera chain: differential images, flow and gas segmentation of one camera.

The first stages of the scene-flow chain (paper Sec. 4.2-4.4) on three consecutive frames
of one camera: differential images (Eq. 2) with jitter removal and denoising
(:func:`processing.preprocess.differential.preprocess_camera`), the flow between them
(Eq. 5) and the level-set segmentation (Eq. 9). No stereo: no disparity, no 3D velocity;
an emission rate only with a typed-in distance (:func:`single_camera_rate`).
``ogiflow eval detection`` and ``ogiflow eval footage`` run it on folders of frames, the
daemon's workers (:class:`SingleCameraWorker`) on a camera whose partner is lost and on
single-camera sites: one path for both.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from appliance.runtime.ring import LEFT, RIGHT
from drivers.camera.base import CameraError
from drivers.camera.registry import create_camera
from processing.chain.driver import frame_interval
from processing.emission.rate import FrameRate, single_camera_velocity
from processing.flow.brox import brox_optical_flow
from processing.preprocess.differential import preprocess_camera
from processing.segmentation.segment import segment_gas

#: Normalisation scale of a camera whose configuration sets none: this quantile of the
#: first triple's absolute frame difference (as the stereo chain's first scale).
SCALE_QUANTILE = 0.999


@dataclass
class MonoTriple:
    """One consecutive triple (N, N+1, N+2) of one camera through the chain's first
    stages: raw frame N, I_diff(N) in [0, 1], flow (Eq. 5), gas mask (Eq. 9)."""

    frame: int
    raw: np.ndarray
    diff: np.ndarray
    flow: np.ndarray
    mask: np.ndarray
    activity_ratio: float
    shifts: tuple[tuple[float, float], tuple[float, float]]
    timings_ms: dict[str, float]
    diff1: np.ndarray | None = None  # I_diff(N + 1), for the emission rate's curtains
    rejected_shifts: int = 0
    offset_step1: float = 0.0  # the camera's offset step levelled out of I_diff(N + 1)


def mono_triple(frame: int, imgs: Sequence[np.ndarray], *, scale: float, register: bool,
                denoise_lambda: float, shift01: tuple[float, float] | None = None,
                max_shift_px: float = 1.0, flow_options: Mapping[str, Any] | None = None,
                segmentation_options: Mapping[str, Any] | None = None) -> MonoTriple:
    """Pre-processing, flow and segmentation of three consecutive frames of one camera.

    Parameters
    ----------
    frame : int
        Number of the first frame (reports).
    imgs : sequence of 3 ndarrays, shape (H, W)
        Raw frames (counts; identity characteristic curve).
    scale : float
        Intensity difference in counts mapped to 1.0 in the differential images.
    register, denoise_lambda, max_shift_px
        As :func:`processing.preprocess.differential.preprocess_camera`.
    shift01 : (float, float) or None
        Known jitter of frame N+1 against N (from the previous triple), px.
    flow_options, segmentation_options : mapping, optional
        Keyword arguments of the flow solver and the segmentation.

    Raises
    ------
    ValueError
        Frames of different sizes.
    """

    if imgs[0].shape != imgs[1].shape or imgs[0].shape != imgs[2].shape:
        raise ValueError(f"frames {frame}..{frame + 2} differ in size")
    t0 = time.perf_counter()
    pre = preprocess_camera(imgs, scale=scale, register=register,
                            denoise_lambda=denoise_lambda, shift01=shift01,
                            max_shift_px=max_shift_px)
    t1 = time.perf_counter()
    flow = brox_optical_flow(pre.diff0, pre.diff1, **dict(flow_options or {}))
    t2 = time.perf_counter()
    seg = segment_gas(pre.diff0, flow, **dict(segmentation_options or {}))
    t3 = time.perf_counter()
    return MonoTriple(frame, imgs[0], pre.diff0, flow, seg.mask, float(seg.activity_ratio),
                      (tuple(pre.shifts[0]), tuple(pre.shifts[1])),  # type: ignore[arg-type]
                      {"preprocess": (t1 - t0) * 1e3, "flow": (t2 - t1) * 1e3,
                       "segmentation": (t3 - t2) * 1e3},
                      diff1=pre.diff1, rejected_shifts=int(pre.rejected_shifts),
                      offset_step1=float(pre.offset_step1))


def first_scale(imgs: Sequence[np.ndarray]) -> float:
    """A normalisation scale from a first triple (counts): the :data:`SCALE_QUANTILE` of
    |frame 1 - frame 0|, at least 1 count (a static scene has no difference at all)."""
    d = np.abs(np.asarray(imgs[1], np.float32) - np.asarray(imgs[0], np.float32))
    return max(float(np.quantile(d[::2, ::2], SCALE_QUANTILE)), 1.0)


def single_camera_rate(estimator: Any, counts_t1: np.ndarray, tr: MonoTriple, dt_s: float,
                       distance_m: float, gas_temperature_k: float) -> FrameRate:
    """The single-camera emission rate of one triple: the gas's image flow scaled to the
    typed-in ``distance_m`` (no depth from one camera) through the stereo rate's curtains.
    A failure is a rate with its reason, never a lost result.

    ``estimator`` is the worker's :class:`processing.emission.estimator.EmissionEstimator`.
    """
    try:
        sigma = estimator.column_kg_m2(counts_t1, tr.mask, gas_temperature_k)
        v = single_camera_velocity(tr.flow, distance_m, estimator.camera_constant, dt_s)
        ok = np.isfinite(tr.flow[..., 0]) & np.isfinite(tr.flow[..., 1])
        r = estimator.rates(sigma, flow=tr.flow, velocity=v,
                            depth=np.full(tr.mask.shape, distance_m), valid=ok,
                            gas_mask=tr.mask, dt_s=dt_s).stereo()
    except (ValueError, FloatingPointError) as exc:
        return FrameRate(None, (), f"single-camera rate failed: {exc}")
    # one camera sees no motion out of the image plane: that angle stays unknown
    return FrameRate(r.rate_g_s, r.curtain_rates_g_s, r.reason, None)


def window_camera(meta: list[dict[str, int]]) -> str | None:
    """The camera whose frames a window holds alone ("left"/"right"), None for three
    stereo pairs: a window across a loss or a return holds the survivor's frames in every
    slot and runs the single-camera chain on them.

    Raises
    ------
    ValueError
        Slots of one camera alone and slots of the other alone (no camera in all three).
    """

    bits = LEFT | RIGHT
    for m in meta:
        bits &= int(m.get("cameras", LEFT | RIGHT))
    if bits == LEFT | RIGHT:
        return None
    if bits:
        return "left" if bits & LEFT else "right"
    raise ValueError("a window of frames of the left camera alone and the right alone")


class SingleCameraWorker:
    """One worker's single-camera chain (:mod:`appliance.runtime.single_camera`): a
    normalisation scale per camera (``diff_scale``, else from its first triple) and the
    jitter of the previous triple when it shares frames with this one (one worker)."""

    def __init__(self, params: Any) -> None:
        self.params = params  # processing.chain.driver.ChainParameters
        self._scale: dict[str, float] = {}
        self._prev: tuple[str, int, tuple[float, float]] | None = None

    def __call__(self, camera: str, frames: np.ndarray, t_mono_ns: tuple[int, ...],
                 base: Any) -> MonoTriple:

        p = self.params
        base.dt_s = frame_interval([t / 1e9 for t in t_mono_ns])
        scale = p.diff_scale or self._scale.get(camera)
        if scale is None:
            scale = self._scale[camera] = first_scale(frames)
        first = base.pair_indices[0]
        prev = self._prev
        shift01 = prev[2] if prev is not None and prev[:2] == (camera, first - 1) else None
        tr = mono_triple(first, list(frames), scale=scale, register=p.register,
                         denoise_lambda=p.denoise_lambda, shift01=shift01,
                         max_shift_px=p.max_jitter_px,
                         flow_options={"alpha": p.alpha, "beta": p.beta, **p.flow_options},
                         segmentation_options={"nu": p.nu, **p.segmentation_options})
        self._prev = (camera, first, tr.shifts[1])
        base.diff_scale = scale
        return tr

    def rate(self, estimator: Any, emission: Any, counts_t1: np.ndarray, tr: MonoTriple,
             dt_s: float | None, sonic_k: Any, due: bool) -> FrameRate | None:
        """The single-camera rate of a triple (None: not this triple, emission.every), or
        the reason there is none."""
        distance = emission.settings.typed_distance_m
        if distance is None:
            return NO_DISTANCE
        if estimator is None:
            return FrameRate(None, (), "single camera: the rate needs the left camera's "
                                       "radiometric calibration (right camera, or none)")
        if not due or dt_s is None:
            return None
        return single_camera_rate(estimator, counts_t1, tr, dt_s, distance,
                                  emission.temperature_k(sonic_k))


#: The rate of a single-camera triple without a typed-in distance.
NO_DISTANCE = FrameRate(None, (), "single camera: no depth (set "
                                  "emission.single_camera_distance_m)")


def probe_image_size(cfg: Any, site: Any) -> tuple[int, int]:
    """(W, H) of the single camera of a site without a calibration: its first frame (the
    shared-memory ring's slots are sized before acquisition starts).

    Raises
    ------
    RuntimeError
        The camera delivers no frame within 10 s (a runtime fault: exit code 1).
    """

    cam_cfg = cfg.cameras.left
    assert cam_cfg is not None
    camera = create_camera(cam_cfg.backend, **site.camera_options("left", cam_cfg))
    try:
        camera.open()
        camera.start()
        deadline = time.monotonic() + 10.0
        while True:
            try:
                frame = camera.grab(timeout=0.5)
                break
            except CameraError as exc:
                if time.monotonic() > deadline or not isinstance(exc, TimeoutError):
                    raise
    except CameraError as exc:
        raise RuntimeError(f"cameras.left: no first frame to size the images: {exc}") from exc
    finally:
        with contextlib.suppress(CameraError, OSError):
            camera.close()
    h, w = frame.image.shape[:2]
    return int(w), int(h)
