"""Publishing scene-flow results: shared by ``ogiflow run`` and ``ogiflow replay``.

:class:`ResultPublisher` turns a :class:`~appliance.runtime.worker_result.WorkerResult` into
what the user gets: the per-frame summary (with validity and flags) and, every N-th result, the
full fields in the MCAP file, the wind in the camera frame at the pair's time, and the
live-view item. Run and replay share it, so a replayed recording is published exactly as
it was live.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import cv2
import numpy as np

from appliance.live.view import LiveFrame
from appliance.recording import schemas
from appliance.runtime.worker_result import WorkerResult
from processing.chain.summary import directional_angles
from processing.emission.rate import RateEstimate, RateWindow


class ResultPublisher:
    """Records and shows results and pairs.

    Parameters
    ----------
    recorder : appliance.recording.recorder.Recorder or None
    live : appliance.live.view.LiveView or None
    wall_ns : callable
        Host monotonic ns -> UNIX ns.
    fields_every : int
        Record the full fields of every N-th result.
    wind_at : callable, optional
        Host monotonic ns -> ``WindAt`` (the anemometer's wind in the camera frame).
    truth_for : callable, optional
        Pair index of t0 -> simulator ground-truth mean velocity (simulated runs).
    monitor : LeakMonitor, optional
        Gets every result for the leak events, the rate window and the operator's status.
    keep_summaries : bool
        Keep every published summary in :attr:`summaries` (bounded runs only).
    rate_window_s : float
        Window of the emission-rate average that the summaries carry, s.
    true_rate_for : callable, optional
        Pair index of t1 -> the simulator's true release rate, g/s (simulated runs).
    """

    def __init__(self, recorder: Any, live: Any, wall_ns: Callable[[int], int],
                 fields_every: int, *, wind_at: Callable[[int], Any] | None = None,
                 truth_for: Callable[[int], np.ndarray | None] | None = None,
                 monitor: Any = None, keep_summaries: bool = False,
                 rate_window_s: float = 30.0,
                 true_rate_for: Callable[[int], float | None] | None = None) -> None:
        self.recorder = recorder
        self.live = live
        self.wall_ns = wall_ns
        self.fields_every = fields_every
        self.wind_at = wind_at
        self.truth_for = truth_for
        self.monitor = monitor
        self.rate_window = RateWindow(rate_window_s)
        self.true_rate_for = true_rate_for
        self._rate_sums = [0.0, 0.0, 0]  # measured window rate, true rate, results with both
        self.published = 0
        self.errors = 0
        #: Results published since the last one whose fields were recorded.
        self._since_fields = 0
        #: Shared flag the workers read (``runtime.pool``): set when the next result should
        #: carry its full fields; None (replay, tests) = every result carries them.
        self.fields_wanted: Any = None
        # Running sums for truth_comparison(): a list of every result would grow the
        # daemon without bound (about 65 MB/h at the default configuration).
        self._truth_n = 0
        self._truth_sum = np.zeros(3)
        self._measured_sum = np.zeros(3)
        #: Every published summary, when asked for (a reprocessing segment collects its
        #: rows; the daemon never keeps them: unbounded growth).
        self.summaries: list[dict[str, Any]] | None = [] if keep_summaries else None
        self._lock = threading.Lock()

    # ------------------------------------------------------------------ recording

    def record_json(self, topic: str, schema: schemas.MessageSchema, obj: dict[str, Any],
                    mono_ns: int) -> None:
        if self.recorder is None:
            return
        payload = schemas.encode_json(schema, obj, validate=False)
        self.recorder.record(topic, schema, payload, self.wall_ns(mono_ns), mono_ns)

    def record_pair(self, index: int, p: Any) -> None:
        """The ``/pairs`` message of stereo pair ``index``."""
        left, right = p.left, p.right
        t = p.time_ns
        self.record_json("/pairs", schemas.STEREO_PAIR, {
            "pair_index": index, "left_seq": left.seq, "right_seq": right.seq,
            "t_left_mono_ns": p.left_ns, "t_right_mono_ns": p.right_ns, "t_mono_ns": t,
            "t_wall_ns": self.wall_ns(t), "dt_ns": p.residual_ns,
            "t_left_device_ns": left.device_ts_ns, "t_right_device_ns": right.device_ts_ns,
        }, t)

    # ------------------------------------------------------------------ results

    def publish(self, res: WorkerResult, *, fields: bool | None = None) -> dict[str, Any] | None:
        """Record (and show) one result; returns its summary, or None for a failed one.

        ``fields`` says whether to record the full fields; None: every ``fields_every``-th
        published result (live; with :attr:`fields_wanted` the first result that carries
        them once that many were published, usually one or two later), a bool: the caller
        decides (replay chooses by triple index, so that segmenting does not change which
        triples carry fields).
        """
        if res.error is not None:
            self.errors += 1
            return None
        t1 = res.t_mono_ns[1]
        s = res.summary
        flags = list(s.get("flags", []))
        if res.rejected_shifts and "registration_rejected" not in flags:
            flags.append("registration_rejected")
        summary = {
            "t_mono_ns": t1, "t_wall_ns": self.wall_ns(t1), "pair_index": res.pair_indices[1],
            "gas_pixels": int(s.get("gas_pixel_count") or 0),
            "mean_velocity_m_s": s.get("mean_velocity"), "speed_m_s": s.get("speed"),
            "angles_deg": s.get("angles_deg"), "c_usf": s.get("c_usf"),
            "latency_ms": (res.done_mono_ns - res.t_mono_ns[2]) / 1e6 if res.done_mono_ns
            else None,
            "skipped_pairs": int(res.skipped), "valid": bool(s.get("valid")), "flags": flags,
        }
        window = None
        if res.rate is not None:
            window = self.rate_window.push(self.wall_ns(t1) / 1e9, res.rate)
            summary.update(self._emission(res, window))
        self.record_json("/sceneflow/summary", schemas.SCENEFLOW_SUMMARY, summary, t1)
        wind = self._wind(t1, res.pair_indices[1])
        truth = None if self.truth_for is None else self.truth_for(res.pair_indices[0])
        with self._lock:
            self.published += 1
            self._since_fields += 1
            self._add_truth(truth, summary)
            if self.summaries is not None:
                self.summaries.append(summary)
            due = self._since_fields >= self.fields_every if fields is None else fields
            record_fields = due and res.has_fields
            if record_fields:
                self._since_fields = 0
        if self.recorder is not None and record_fields:
            self._record_fields(res, t1)
        if self.live is not None:
            self._push_live(res, summary, wind, truth, t1)
        if self.monitor is not None and res.gas_mask is not None and res.gas_flow is not None:
            self.monitor.on_result(summary["t_wall_ns"], res.pair_indices[1], res.gas_mask,
                                   res.gas_flow, summary, wind=wind, rate=res.rate,
                                   window=window)
        if self.fields_wanted is not None and (
                self._since_fields + 1 >= self.fields_every
                or (self.live is not None and self.live.wants_pictures())):
            self.fields_wanted.value = 1
        return summary

    def _emission(self, res: WorkerResult, est: RateEstimate) -> dict[str, Any]:
        """The summary's emission keys: the frame's rate and the window's (g/s, kg/h)."""
        rate = res.rate
        assert rate is not None
        true = None if self.true_rate_for is None else self.true_rate_for(res.pair_indices[1])
        out = {
            "emission_rate_g_s": rate.rate_g_s,
            "emission_rate_kg_h": None if rate.rate_g_s is None else rate.rate_g_s * 3.6,
            "emission_reason": rate.reason,
            "emission_window_rate_g_s": est.rate_g_s,
            "emission_window_rate_kg_h": est.rate_kg_h,
            "emission_window_uncertainty_g_s": est.uncertainty_g_s,
            "emission_window_s": est.window_s,
            "emission_window_frames": est.frames,
            "emission_window_out_of_plane_deg": est.out_of_plane_deg,
            "emission_window_flags": list(est.flags),
        }
        if true is not None:
            out["emission_true_rate_g_s"] = true
            if est.rate_g_s is not None:
                with self._lock:
                    self._rate_sums[0] += est.rate_g_s
                    self._rate_sums[1] += true
                    self._rate_sums[2] += 1
        return out

    def rate_comparison(self) -> tuple[float, float, float | None] | None:
        """(last window rate, mean true release, its relative error) of a simulated run;
        None without a rate or a truth. The window of the last result is what the
        appliance reports at the end."""
        est = self.rate_window.estimate()
        with self._lock:
            n = self._rate_sums[2]
            true = self._rate_sums[1] / n if n else None
        if est.rate_g_s is None or true is None:
            return None
        return est.rate_g_s, true, (est.rate_g_s / true - 1.0) if true else None

    def record_event(self, kind: str, event: dict[str, Any]) -> None:
        """The ``/events`` message of a leak-event change (start, update, end)."""
        t_wall = int(event["t_wall_ns"])
        if kind == "update" and event.get("frames", 0) % 30:
            return  # updates about once a second; start and end always
        self.record_json("/events", schemas.LEAK_EVENT, {"kind": kind, **event},
                         t_wall - (self.wall_ns(0)))

    def _wind(self, t_mono: int, pair_index: int) -> np.ndarray | None:
        if self.wind_at is None:
            return None
        at = self.wind_at(t_mono)
        if not at.ok:
            return None
        v = np.asarray(at.vector, dtype=np.float64)
        if not np.all(np.isfinite(v)):
            return None  # a failed axis is no wind measurement, not a calm
        self.record_json("/wind/camera", schemas.WIND_CAMERA, {
            "t_mono_ns": t_mono, "t_wall_ns": self.wall_ns(t_mono), "pair_index": pair_index,
            "velocity_m_s": [float(x) for x in v], "speed_m_s": float(np.linalg.norm(v)),
            "angles_deg": directional_angles(v), "interpolated": at.span_ns > 0,
        }, t_mono)
        return v

    def _push_live(self, res: WorkerResult, summary: dict[str, Any], wind: np.ndarray | None,
                   truth: np.ndarray | None, t1: int) -> None:
        ok = summary["valid"]
        self.live.push(LiveFrame(
            frame=res.pair_indices[1], t_capture_ns=self.wall_ns(t1),
            diff_left=res.diff_left, diff_right=res.diff_right, flow=res.flow,
            disparity=None if res.disparity is None or res.valid is None
            else np.where(res.valid, res.disparity, np.nan).astype(np.float32),
            gas_mask=res.gas_mask, points3d=res.points3d, velocity3d=res.velocity3d,
            pixels=res.pixels, raw_left=res.raw_left,
            raw_capture_ns=self.wall_ns(res.t_mono_ns[0]), camera=res.single_camera or "left",
            gas_speed_m_s=summary["speed_m_s"] if ok else None,
            gas_angles_deg=tuple(summary["angles_deg"]) if ok and summary["angles_deg"]
            else None,
            wind_speed_m_s=None if wind is None else float(np.linalg.norm(wind)),
            wind_angles_deg=None if wind is None else directional_angles(wind),
            truth_speed_m_s=None if truth is None else float(np.linalg.norm(truth)),
            truth_angles_deg=None if truth is None else directional_angles(truth),
        ))

    def _record_fields(self, res: WorkerResult, t1: int) -> None:
        wall = self.wall_ns(t1)
        # a single-camera result has its camera's I_diff (as diff_left) and no stereo fields
        own = res.single_camera or "left"
        for side, img in ((own, res.diff_left), ("right", res.diff_right)):
            if img is None:
                continue
            ok, jpg = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 90])
            if ok:
                payload = schemas.compressed_image(jpg.tobytes(), wall, f"camera_{side}")
                self.recorder.record(f"/cam/{side}/diff", schemas.COMPRESSED_IMAGE, payload,
                                     wall, t1)
        frame_id = f"camera_{own}"
        grids = [("/sceneflow/flow", res.flow, ("u", "v"))]
        if res.disparity is not None and res.velocity is not None:
            grids += [("/sceneflow/disparity",
                       np.stack([res.disparity, res.disparity_change], -1), ("d", "d_change")),
                      ("/sceneflow/velocity", res.velocity, ("vx", "vy", "vz"))]
        for topic, arr, names in grids:
            self.recorder.record(topic, schemas.GRID,
                                 schemas.grid(arr, wall, frame_id, names), wall, t1)
        ok, png = cv2.imencode(".png", res.gas_mask.astype(np.uint8) * 255)
        if ok:
            payload = schemas.compressed_image(png.tobytes(), wall, frame_id, "png")
            self.recorder.record("/sceneflow/mask", schemas.COMPRESSED_IMAGE, payload, wall, t1)

    def restart_rate_window(self) -> None:
        """Forget the emission-rate window (a reprocessing segment's cold start: the window
        of a segment then holds only its own frames, the same in a replay and in a Ray task
        that runs the segment alone)."""
        self.rate_window = RateWindow(self.rate_window.window_s)

    # ------------------------------------------------------------------ ground truth

    def _add_truth(self, truth: np.ndarray | None, summary: dict[str, Any]) -> None:
        """Count one result towards :meth:`truth_comparison` (call with the lock held)."""
        measured = summary["mean_velocity_m_s"]
        if truth is None or not summary["valid"] or measured is None:
            return
        m = np.asarray(measured, dtype=np.float64)
        t = np.asarray(truth, dtype=np.float64)
        if m.shape != (3,) or t.shape != (3,) or not (np.isfinite(m).all()
                                                       and np.isfinite(t).all()):
            return
        self._truth_n += 1
        self._truth_sum += t
        self._measured_sum += m

    def truth_comparison(self) -> dict[str, Any] | None:
        """Mean measured vs mean true gas velocity over the valid frames of a simulated run.

        Only frames with a valid summary and a ground truth (not wrapping the scene loop)
        count; None when there is none.
        """
        with self._lock:
            n = self._truth_n
            if n == 0:
                return None
            measured = self._measured_sum / n
            truth = self._truth_sum / n
        nt, nm = float(np.linalg.norm(truth)), float(np.linalg.norm(measured))
        cos = float(np.clip(measured @ truth / (nm * nt), -1, 1)) if nm > 0 and nt > 0 else 1.0
        return {"frames": n, "truth_m_s": truth.tolist(),
                "measured_m_s": measured.tolist(),
                "magnitude_error_pct": 100.0 * abs(nm - nt) / nt if nt > 0 else float("nan"),
                "direction_error_deg": float(np.degrees(np.arccos(cos)))}
