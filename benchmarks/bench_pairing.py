"""Stereo pairing accuracy and cost over simulated time.

Two simulated cameras (not triggered together, different latency, jitter, clock offset and
drift, dropped frames) are driven on a virtual clock - no sleeping - through the real code
path: ``SimulatedCamera.grab`` -> ``ClockModel.update`` -> ``StereoPairer.push``, merged in
order of host arrival as the daemon would see them. The ground truth is the same pairing rule
applied to the true capture times the timing model knows.

Run:  /work/devenv/bin/python benchmarks/bench_pairing.py [--minutes 10] [--no-device-clock]
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass, field

import numpy as np

from appliance.runtime.clock import ClockModel
from appliance.runtime.pairing import StereoPairer
from drivers.camera.simulated import SimulatedCamera
from drivers.camera.sources import TexturePatternSource

PERIOD_NS = round(1e9 / 30.0)

#: Acceptance scenario: realistic but unkind (relative drift 65 ppm slips the phase of the
#: two cameras by ~39 ms in 10 min, so it crosses the half-period boundary).
LEFT = dict(
    latency_s=0.008,
    jitter_s=0.002,
    clock_offset_s=1234.5,
    drift_ppm=40.0,
    drop_rate=0.002,
    phase_s=0.0,
    seed=1,
)
RIGHT = dict(
    latency_s=0.012,
    jitter_s=0.003,
    clock_offset_s=-77.0,
    drift_ppm=-25.0,
    drop_rate=0.002,
    phase_s=0.011,
    seed=2,
)


@dataclass
class Result:
    """Outcome of one simulated run (times in ns)."""

    frames: dict[str, int] = field(default_factory=dict)
    pairs: int = 0
    truth_pairs: int = 0
    frames_correct: int = 0
    frames_total: int = 0
    beyond_tolerance: int = 0
    max_true_residual_ns: int = 0
    max_est_residual_ns: int = 0
    clock_err_ns: dict[str, dict[str, float]] = field(default_factory=dict)
    cpu_s: float = 0.0

    @property
    def fraction_correct(self) -> float:
        return self.frames_correct / max(self.frames_total, 1)


def _match(times: dict[str, list[tuple[int, int]]], tol: int) -> dict[tuple[str, int], int | None]:
    """Ground truth: the pairing rule on true times (offline, everything known)."""
    pairer: StereoPairer[int] = StereoPairer(PERIOD_NS, tolerance_ns=tol, max_queue=10**9)
    events = sorted((t, s, k) for s in times for k, t in times[s])
    outcome: dict[tuple[str, int], int | None] = {}
    pairs = []
    for t, s, k in events:
        pairs += pairer.push(s, t, k)
    pairs += pairer.flush()
    for p in pairs:
        outcome[("left", p.left)] = p.right
        outcome[("right", p.right)] = p.left
    for s, _, k in pairer.take_unpaired():
        outcome[(s, k)] = None
    return outcome


def simulate_pairing(
    duration_s: float = 600.0,
    left: dict | None = None,
    right: dict | None = None,
    *,
    device_clock: bool = True,
    image_jitter_px: float = 0.2,
    warmup_s: float = 5.0,
) -> Result:
    """Run both simulated cameras for ``duration_s`` of simulated time; see module doc."""
    source = TexturePatternSource(n_frames=8)
    params = {
        "left": dict(LEFT if left is None else left),
        "right": dict(RIGHT if right is None else right),
    }
    cams = {
        s: SimulatedCamera(
            s,
            source,
            realtime=False,
            epoch_ns=0,
            device_clock=device_clock,
            image_jitter_px=image_jitter_px,
            **params[s],
        )
        for s in params
    }
    clocks = {
        s: ClockModel(latency_ns=round(params[s]["latency_s"] * 1e9), nominal_period_ns=PERIOD_NS)
        for s in params
    }
    pairer: StereoPairer[int] = StereoPairer(PERIOD_NS)
    tol = pairer.tolerance_ns
    end_ns = int(duration_s * 1e9)
    res = Result()
    true_times: dict[str, list[tuple[int, int]]] = {"left": [], "right": []}
    errors: dict[str, list[float]] = {"left": [], "right": []}
    est_pairs = []
    cpu0 = time.process_time()
    for c in cams.values():
        c.open()
        c.start()
    heads = {s: cams[s].grab() for s in cams}
    while heads:
        side = min(heads, key=lambda s: heads[s].host_ns)
        f = heads[side]
        if f.host_ns > end_ns:
            del heads[side]
            continue
        heads[side] = cams[side].grab()
        k = f.device_frame_id
        assert k is not None
        # Without a device clock, give the model no frame ids either (like V4L2): it counts
        # frame periods from the arrival gaps.
        fid = f.device_frame_id if device_clock else None
        t_hat = clocks[side].update(f.host_ns, f.device_ts_ns, fid)
        t_true = int(cams[side].timing.capture_time_ns(k))
        true_times[side].append((k, t_true))
        if f.host_ns > warmup_s * 1e9:
            errors[side].append(t_hat - t_true)
        est_pairs += pairer.push(side, t_hat, k, now_ns=f.host_ns)
    est_pairs += pairer.flush()
    res.cpu_s = time.process_time() - cpu0
    truth = _match(true_times, tol)
    est: dict[tuple[str, int], int | None] = {}
    tt = {s: dict(true_times[s]) for s in true_times}
    for p in est_pairs:
        est[("left", p.left)] = p.right
        est[("right", p.right)] = p.left
        dt = abs(tt["right"][p.right] - tt["left"][p.left])
        res.max_true_residual_ns = max(res.max_true_residual_ns, dt)
        res.max_est_residual_ns = max(res.max_est_residual_ns, abs(p.residual_ns))
        res.beyond_tolerance += dt > tol
    for s, _, k in pairer.take_unpaired():
        est[(s, k)] = None
    res.frames = {s: len(true_times[s]) for s in true_times}
    res.frames_total = len(truth)
    res.frames_correct = sum(est.get(key, "missing") == v for key, v in truth.items())
    res.pairs = len(est_pairs)
    res.truth_pairs = sum(v is not None for (s, _), v in truth.items() if s == "left")
    for s, e in errors.items():
        a = np.asarray(e, dtype=np.float64)
        res.clock_err_ns[s] = {
            "mean": float(a.mean()),
            "std": float(a.std()),
            "max_abs": float(np.abs(a).max()),
        }
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument(
        "--no-device-clock",
        action="store_true",
        help="cameras without clock or frame ids, like V4L2 (arrival smoothing only)",
    )
    args = ap.parse_args()
    r = simulate_pairing(args.minutes * 60.0, device_clock=not args.no_device_clock)
    n = r.frames["left"] + r.frames["right"]
    print(
        json.dumps(
            {
                "simulated_minutes": args.minutes,
                "device_clock": not args.no_device_clock,
                "frames": r.frames,
                "pairs": r.pairs,
                "truth_pairs": r.truth_pairs,
                "fraction_frames_paired_correctly": round(r.fraction_correct, 6),
                "frames_wrong": r.frames_total - r.frames_correct,
                "pairs_beyond_tolerance_in_true_time": r.beyond_tolerance,
                "max_true_residual_ms": r.max_true_residual_ns / 1e6,
                "max_estimated_residual_ms": r.max_est_residual_ns / 1e6,
                "tolerance_ms": PERIOD_NS / 2e6,
                "capture_time_error_us": {
                    s: {k: round(v / 1e3, 2) for k, v in e.items()}
                    for s, e in r.clock_err_ns.items()
                },
                "cpu_s_total": round(r.cpu_s, 2),
                "cpu_us_per_frame": round(r.cpu_s / n * 1e6, 1),
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
