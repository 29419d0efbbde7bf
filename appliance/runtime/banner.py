"""What ``ogiflow run`` tells the user on stderr when it starts and when it stops."""

from __future__ import annotations

import sys
import time
from typing import Any

from processing.emission import RateEstimate


def announce_start(app: Any) -> None:
    """Where the operator's page, the live view and the recording are, and how to stop."""
    where = app.live_url or "off"
    page = app.page_server.url if app.page_server is not None else "off"
    rec = str(app.cfg.recording.dir) if app.cfg.recording.enabled else "off"
    sys.stderr.write(f"ogiflow: running. operator page: {page}  live view: {where}  "
                     f"recording: {rec}  (Ctrl-C or SIGTERM stops)\n")


def announce_end(app: Any) -> None:
    """Final counts (processed and skipped triples per second, peak memory of every
    process), and the simulated ground truth against the measurement."""
    c = app.counters
    elapsed = max(time.monotonic() - app.t_start, 1e-9)
    share = c.results / max(c.results + c.skipped_pairs, 1)
    sys.stderr.write(
        f"ogiflow: stopped. frames {c.frames['left']}/{c.frames['right']} (left/right), "
        f"lost {c.frames_lost['left']}/{c.frames_lost['right']}, pairs {c.pairs}, "
        f"processed {c.results} ({c.results / elapsed:.1f}/s, {100 * share:.0f} %, "
        f"{100 * c.cold_results / max(c.results, 1):.0f} % of them started cold), "
        f"skipped {c.skipped_pairs} ({c.skipped_pairs / elapsed:.1f}/s), "
        f"failed {c.result_errors}, wind samples {c.wind_samples}"
        f"{levelled_steps_words(c.offset_steps)}{camera_words(app)}\n")
    where = app.stage_times.describe()
    if where is not None:
        sys.stderr.write(f"ogiflow: {where}\n")
    if app.peak_rss_mb:
        names = ["daemon", *(f"worker {i}" for i in range(len(app.peak_rss_mb) - 1))]
        sys.stderr.write("ogiflow: peak RSS (MB): " + ", ".join(
            f"{n} {'n/a' if mb is None else f'{mb:.0f}'}"
            for n, mb in zip(names, app.peak_rss_mb, strict=True)) + "\n")
    comparison = app.publisher.truth_comparison()
    if comparison is not None:
        sys.stderr.write(
            "ogiflow: simulated ground truth vs measured mean gas velocity over "
            f"{comparison['frames']} valid frames: truth "
            f"{_fmt(comparison['truth_m_s'])} m/s, measured "
            f"{_fmt(comparison['measured_m_s'])} m/s, magnitude error "
            f"{comparison['magnitude_error_pct']:.1f} %, direction error "
            f"{comparison['direction_error_deg']:.1f} deg\n")
    rates = app.publisher.rate_comparison()
    est = app.publisher.rate_window.estimate()
    if est.rate_g_s is not None:
        unc = "" if est.uncertainty_g_s is None else f" +- {est.uncertainty_g_s:.2f}"
        sys.stderr.write(
            f"ogiflow: emission rate (last {est.window_s:.0f} s, {est.frames} of "
            f"{est.frames_total} frames with a rate): {est.rate_g_s:.2f}{unc} g/s = "
            f"{est.rate_kg_h:.3f} kg/h{line_of_sight_words(est)}\n")
    elif app.publisher.published:
        sys.stderr.write("ogiflow: emission rate: undefined (no frame with a rate in the "
                         "last window)\n")
    if rates is not None:
        measured, true, err = rates
        sys.stderr.write(
            f"ogiflow: simulated release rate {true:.2f} g/s ({true * 3.6:.3f} kg/h), "
            f"measured {measured:.2f} g/s ({measured * 3.6:.3f} kg/h), error "
            f"{'n/a' if err is None else f'{100 * err:+.1f} %'}\n")


def camera_words(app: Any) -> str:
    """``, degraded 40 s (right camera lost 1x; 1200 frames of one camera)`` when a
    camera of the pair was lost, ``, single camera`` at a single-camera site."""
    acq = app.acquisition
    if acq is None:
        return ""
    watch = acq.watch
    c = app.counters
    if watch.mode == "single_camera":
        return f", single camera ({c.single_frames} frames, {c.single_results} processed)"
    lost = [f"{s} camera lost {watch.losses(s)}x" for s in ("left", "right")
            if watch.losses(s)]
    return (f", degraded {watch.degraded_s(time.monotonic_ns()):.0f} s"
            f" ({'; '.join(lost) or 'no camera lost'}; {c.single_frames} frames of one "
            f"camera, {c.single_results} of them processed)")


def levelled_steps_words(steps: dict[str, int]) -> str:
    """``, offset steps levelled 4/0 (left/right)`` when a camera's picture stepped (a
    flat-field shutter, a drift) in the processed triples; empty when none did."""
    if not any(steps.values()):
        return ""
    return f", offset steps levelled {steps['left']}/{steps['right']} (left/right)"


def line_of_sight_words(est: RateEstimate) -> str:
    """``"; FLAGGED line_of_sight: ..."`` when the window's rate carries that flag."""
    if "line_of_sight" not in est.flags or est.out_of_plane_deg is None:
        return ""
    return (f"; FLAGGED line_of_sight: the gas moves {est.out_of_plane_deg:.0f} deg out of the "
            "image plane, where image-based rates read high (docs/method.md, emission rate)")


def _fmt(v: Any) -> str:
    return "(" + ", ".join(f"{x:.2f}" for x in v) + ")"
