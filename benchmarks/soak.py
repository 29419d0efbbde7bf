"""Soak test: run the whole appliance for N minutes and watch its memory and its counters.

Starts ``python -m appliance run`` (this checkout's code, default configuration unless
``--config``/``--set`` say otherwise: simulated cameras and anemometer, recording on, live view
served), samples the resident set size (RSS) of every process of the appliance - the daemon,
its worker processes, the Rerun viewer server - every ``--sample-s`` seconds, optionally
connects a headless browser to the live view for part of the run, and at the end reads the
last health snapshot of the recording. It reports per process the RSS slope after warm-up
(least-squares line, MB/h) and the frames lost, and writes ``soak.csv``, ``soak.json`` and
``soak.png`` into ``--out``.

    python benchmarks/soak.py --minutes 60 --browser-at 20 --browser-minutes 10
    python benchmarks/soak.py --minutes 62 --warmup-min 12 --browser-at 4 36 --browser-minutes 8

Several ``--browser-at`` minutes connect a fresh browser each time: a first connection during
warm-up pays the one-time costs (the viewer server loading the web viewer), a second one in
the measured window shows whether every connection leaves memory behind.

Needs psutil and matplotlib (``pip install 'ogiflow[bench]'``); the browser needs Debian's
``chromium`` and playwright (same extra).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))  # `python benchmarks/soak.py` from a checkout

PAGE = "http://127.0.0.1:{web}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc}%2Fproxy"
CHROMIUM_ARGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                 "--ignore-gpu-blocklist"]


def role_of(proc: Any, main_pid: int) -> str:
    """A stable name for one process of the appliance (main, worker-N, viewer-server, ...)."""
    if proc.pid == main_pid:
        return "main"
    try:
        cmd = " ".join(proc.cmdline())
        name = proc.name()
    except Exception:
        return "gone"
    if "--serve-web" in cmd or name == "rerun":
        return "viewer-server"
    if "resource_tracker" in cmd:
        return "resource-tracker"
    if "spawn_main" in cmd:
        return "worker"
    return name


def sample(main: Any) -> list[tuple[str, int, float]]:
    """(role, pid, RSS MB) of the daemon and all its descendants."""
    import psutil

    out = []
    try:
        procs = [main, *main.children(recursive=True)]
    except psutil.NoSuchProcess:
        return out
    for p in procs:
        try:
            out.append((role_of(p, main.pid), p.pid, p.memory_info().rss / 1e6))
        except psutil.NoSuchProcess:
            continue
    return out


def memory_kinds(proc: Any) -> tuple[dict[str, float], list[tuple[str, float, float]]]:
    """Where a process's resident memory lies: MB per kind of mapping and its large
    anonymous mappings (address, size MB, RSS MB).

    Kinds: ``heap`` (glibc's main arena, ``[heap]``), ``anon`` (anonymous mappings: glibc's
    thread arenas and large blocks, Python's object arenas, Rust allocators, thread stacks),
    ``file`` (code and mapped files), ``other``. A step in RSS that shows in one kind, and
    in one mapping there, names the allocator that holds it.
    """
    kinds = {"heap": 0.0, "anon": 0.0, "file": 0.0, "other": 0.0}
    big = []
    for m in proc.memory_maps(grouped=False):
        mb = m.rss / 1e6
        path = m.path
        if path == "[heap]":
            kinds["heap"] += mb
        elif not path or path.startswith("[anon"):
            kinds["anon"] += mb
            if mb >= 1.0:
                big.append((m.addr.split("-")[0], getattr(m, "size", 0) / 1e6, mb))
        elif path.startswith("/"):
            kinds["file"] += mb
        else:
            kinds["other"] += mb
    return kinds, big


def slope_mb_per_h(t_s: np.ndarray, rss_mb: np.ndarray) -> float | None:
    """Least-squares slope of RSS over time, MB/h (None with fewer than 3 samples)."""
    if len(t_s) < 3 or np.ptp(t_s) <= 0:
        return None
    return float(np.polyfit(t_s / 3600.0, rss_mb, 1)[0])


def browse(stop: threading.Event, starts_s: list[float], minutes: float, page_url: str,
           log: list[str]) -> None:
    """Open the live view in a fresh headless Chromium at each of ``starts_s`` (seconds
    from the start, ascending) for ``minutes`` each."""
    t_start = time.monotonic()
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        log.append("browser: playwright not installed; skipped")
        return
    for start_s in starts_s:
        if stop.wait(max(0.0, start_s - (time.monotonic() - t_start))):
            return
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=shutil.which("chromium") or
                                         "/usr/bin/chromium", args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": 1280, "height": 800})
            page.goto(page_url, timeout=120_000)
            log.append(f"browser: page loaded at {time.monotonic() - t_start:.0f} s")
            stop.wait(minutes * 60.0)
            browser.close()
            log.append(f"browser: closed at {time.monotonic() - t_start:.0f} s")


def last_health(rec_dir: Path) -> dict[str, Any] | None:
    """The last ``/health`` snapshot under ``rec_dir``: the newest closed recording that
    holds one, in any of the retention layout's folders (results, raw, events)."""
    from appliance.recording.reader import iter_json

    # File names start with their UTC start time, so the name orders them in time.
    files = sorted(rec_dir.rglob("ogiflow-*.mcap"), key=lambda f: f.name, reverse=True)
    for path in files:
        last = None
        _reader, messages = iter_json(path, ["/health"])
        for _topic, m in messages:
            last = m
        if last is not None:
            return last
    return None


def plot(rows: list[tuple[float, str, int, float]], path: Path, title: str,
         browser_windows: list[tuple[float, float]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 4.5))
    for key in sorted({(r, p) for _t, r, p, _m in rows}):
        pts = [(t, m) for t, r, p, m in rows if (r, p) == key]
        ax.plot([t / 60 for t, _ in pts], [m for _, m in pts], label=f"{key[0]} ({key[1]})")
    for i, window in enumerate(browser_windows):
        ax.axvspan(*window, color="0.9", label="browser connected" if i == 0 else None)
    ax.set_xlabel("minutes")
    ax.set_ylabel("RSS, MB")
    ax.set_title(title)
    ax.legend(fontsize=7, loc="upper left")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, required=True, help="length of the run")
    ap.add_argument("--warmup-min", type=float, default=10.0,
                    help="minutes left out of the RSS slope (numba compilation, caches)")
    ap.add_argument("--sample-s", type=float, default=10.0, help="RSS sampling interval")
    ap.add_argument("--browser-at", type=float, nargs="+", default=[], metavar="MIN",
                    help="connect a headless browser to the live view at these minutes")
    ap.add_argument("--browser-minutes", type=float, default=10.0)
    ap.add_argument("--out", type=Path, default=Path("soak-out"))
    ap.add_argument("--ports", type=int, nargs=2, default=(9876, 9090), metavar=("GRPC", "WEB"),
                    help="live view ports (another appliance on the box may hold the defaults)")
    ap.add_argument("--maps-every-s", type=float, default=60.0,
                    help="interval of the memory-map breakdown of the daemon and the viewer "
                         "server (soak_maps.csv, soak_maps.jsonl); 0 = off")
    ap.add_argument("--keep-recordings", action="store_true")
    ap.add_argument("--config", default=None)
    ap.add_argument("--set", action="append", default=[], dest="set_options")
    args = ap.parse_args(argv)
    import psutil

    args.out.mkdir(parents=True, exist_ok=True)
    rec_dir = args.out / "rec"
    cmd = [sys.executable, "-m", "appliance", "run", "--duration", str(args.minutes * 60),
           "--record-dir", str(rec_dir), "--set", "recording.quota_gb=20",
           "--set", f"live.grpc_port={args.ports[0]}", "--set", f"live.web_port={args.ports[1]}"]
    if args.config:
        cmd += ["--config", args.config]
    for s in args.set_options:
        cmd += ["--set", s]
    log_path = args.out / "daemon.log"
    t0 = time.monotonic()
    with open(log_path, "w") as log_file:
        proc = subprocess.Popen(cmd, cwd=ROOT, stdout=log_file, stderr=subprocess.STDOUT,
                                env={**os.environ, "PYTHONUNBUFFERED": "1"})
    main_proc = psutil.Process(proc.pid)
    stop = threading.Event()
    events: list[str] = []
    browser = None
    if args.browser_at:
        browser = threading.Thread(target=browse, daemon=True, args=(
            stop, sorted(m * 60 for m in args.browser_at), args.browser_minutes,
            PAGE.format(grpc=args.ports[0], web=args.ports[1]), events))
        browser.start()
    rows: list[tuple[float, str, int, float]] = []
    load: list[float] = []
    kind_rows: list[tuple[float, str, int, str, float]] = []
    maps_log = (args.out / "soak_maps.jsonl").open("w")
    last_maps = -1e9
    try:
        while proc.poll() is None:
            t = time.monotonic() - t0
            now = sample(main_proc)
            rows.extend((t, role, pid, mb) for role, pid, mb in now)
            load.append(os.getloadavg()[0])
            if args.maps_every_s > 0 and t - last_maps >= args.maps_every_s:
                last_maps = t
                for role, pid, _mb in now:
                    if role not in ("main", "viewer-server"):
                        continue
                    try:
                        p = psutil.Process(pid)
                        kinds, big = memory_kinds(p)
                        threads = p.num_threads()
                    except psutil.Error:
                        continue
                    kind_rows.extend((t, role, pid, k, v) for k, v in kinds.items())
                    maps_log.write(json.dumps({"t_s": round(t, 1), "role": role, "pid": pid,
                                               "threads": threads, "kinds": kinds,
                                               "anon_mappings": big}) + "\n")
                    maps_log.flush()
            time.sleep(args.sample_s)
    except KeyboardInterrupt:
        proc.send_signal(signal.SIGTERM)
        proc.wait(60)
    maps_log.close()
    stop.set()
    if browser is not None:
        browser.join(30)
    code = proc.returncode
    health = last_health(rec_dir)

    with open(args.out / "soak.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["t_s", "role", "pid", "rss_mb"])
        w.writerows(rows)
    with open(args.out / "soak_maps.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["t_s", "role", "pid", "kind", "rss_mb"])
        w.writerows(kind_rows)
    warm = args.warmup_min * 60
    kind_slopes: dict[str, float | None] = {}
    for key in sorted({(r, p, k) for _t, r, p, k, _m in kind_rows}):
        pts = np.array([(t, m) for t, r, p, k, m in kind_rows if (r, p, k) == key and t >= warm])
        kind_slopes[":".join(map(str, key))] = (slope_mb_per_h(pts[:, 0], pts[:, 1])
                                                if len(pts) else None)
    procs: dict[str, Any] = {}
    for key in sorted({(r, p) for _t, r, p, _m in rows}):
        pts = np.array([(t, m) for t, r, p, m in rows if (r, p) == key and t >= warm])
        allpts = [m for t, r, p, m in rows if (r, p) == key]
        half = pts[len(pts) // 2:] if len(pts) else pts
        procs[f"{key[0]}:{key[1]}"] = {
            "rss_start_mb": allpts[0], "rss_end_mb": allpts[-1], "rss_max_mb": max(allpts),
            "slope_after_warmup_mb_per_h": (slope_mb_per_h(pts[:, 0], pts[:, 1])
                                            if len(pts) else None),
            # A cache still filling shows as a slope that falls from half to half.
            "slope_last_half_mb_per_h": (slope_mb_per_h(half[:, 0], half[:, 1])
                                         if len(half) else None)}
    if health is None:
        print(f"warning: no /health snapshot found under {rec_dir}: frame counters unknown "
              "(see the daemon's last line in daemon.log)", file=sys.stderr)
    c = (health or {}).get("counters", {})
    frames = (c.get("frames_left", 0) + c.get("frames_right", 0)) if health else None
    lost = ((c.get("frames_lost_left", 0) + c.get("frames_lost_right", 0)
             + c.get("frame_queue_drops", 0)) if health else None)
    report = {
        "command": " ".join(cmd), "exit_code": code, "minutes": args.minutes,
        "warmup_min": args.warmup_min, "processes": procs,
        "frames": frames, "frames_lost": lost, "recorder_drops": c.get("recorder_drops"),
        "pairs": c.get("pairs"),
        "unpaired": [c.get("unpaired_left"), c.get("unpaired_right")],
        "paired_pct": 100.0 * 2 * c.get("pairs", 0) / frames if frames else None,
        "results": c.get("results"), "skipped_pairs": c.get("skipped_pairs"),
        "load_avg_1min": {"mean": float(np.mean(load)) if load else None,
                          "max": float(np.max(load)) if load else None},
        "counters": c, "events": events,
        "slope_after_warmup_by_kind_mb_per_h": kind_slopes,
    }
    (args.out / "soak.json").write_text(json.dumps(report, indent=2))
    windows = [(m, m + args.browser_minutes) for m in sorted(args.browser_at)]
    plot(rows, args.out / "soak.png", f"ogiflow run, {args.minutes:g} min: RSS per process",
         windows)
    if not args.keep_recordings:
        shutil.rmtree(rec_dir, ignore_errors=True)
    print(json.dumps({k: report[k] for k in ("exit_code", "frames", "frames_lost", "pairs",
                                             "paired_pct", "load_avg_1min")}, indent=2))
    for name, p in procs.items():
        s = p["slope_after_warmup_mb_per_h"]
        print(f"{name:28s} RSS {p['rss_start_mb']:7.1f} -> {p['rss_end_mb']:7.1f} MB, "
              f"slope after warm-up {'n/a' if s is None else f'{s:+.1f}'} MB/h")
    return 0 if code == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
