"""Many browsers on the operator's page, and one that stops reading: nothing else slows.

``load``: N clients that behave like the page (read ``/events``, fetch each announced
picture) plus one that opens ``/events`` and then reads nothing for ``--stall-s`` seconds
(or until the others are done), run against a page at URL; prints one JSON line.

``compare`` (the benchmark): two runs of ``ogiflow run`` of ``--duration`` seconds, the
first without clients, the second with ``load`` running from ``--start-s`` in; it reports
lost frames, the processed fraction of both runs (from the final line) and the daemon's
resident memory (``/metrics``) before the clients came, while they were there and after
they left::

    python -m benchmarks.page_clients compare --duration 150 --clients 20 --stall-s 60

The clients are plain HTTP clients (``http.client``) in their own process, not browsers:
the page's load on the daemon is its event stream and picture requests, which these make
exactly as the page does; 20 headless browsers would measure the browsers.
"""

from __future__ import annotations

import argparse
import http.client
import json
import re
import socket
import subprocess
import sys
import threading
import time
import urllib.parse
import urllib.request
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]


def _events(host: str, port: int, timeout: float) -> tuple[http.client.HTTPConnection, Any]:
    conn = http.client.HTTPConnection(host, port, timeout=timeout)
    conn.request("GET", "/events", headers={"Accept": "text/event-stream"})
    resp = conn.getresponse()
    if resp.status != 200:
        raise RuntimeError(f"/events answered {resp.status}")
    return conn, resp


def page_client(url: str, frames: int, deadline: float, out: dict[str, Any]) -> None:
    """Read the event stream and fetch every announced picture, like the page, until
    ``frames`` pictures were fetched or ``deadline`` (monotonic s) passed."""
    u = urllib.parse.urlsplit(url)
    host, port = u.hostname or "127.0.0.1", u.port or 80
    conn, resp = _events(host, port, 10.0)
    pic = http.client.HTTPConnection(host, port, timeout=10.0)
    got = gone = statuses = 0
    kind = None
    try:
        while got < frames and time.monotonic() < deadline:
            line = resp.readline()
            if not line:
                break
            text = line.decode().rstrip("\n")
            if text.startswith("event: "):
                kind = text[7:]
            elif text.startswith("data: ") and kind == "frame":
                pic.request("GET", json.loads(text[6:])["url"])
                r = pic.getresponse()
                body = r.read()
                got += r.status == 200 and body[:2] == b"\xff\xd8"
                gone += r.status == 404
            elif text.startswith("data: ") and kind == "status":
                statuses += 1
    finally:
        conn.close()
        pic.close()
    out.update(frames=got, gone=gone, statuses=statuses)


def stalled_client(url: str, until: threading.Event, stall_s: float,
                   out: dict[str, Any]) -> None:
    """Open ``/events`` with a small receive buffer, read nothing for ``stall_s`` s (or
    until ``until`` is set), then read what is there and leave."""
    u = urllib.parse.urlsplit(url)
    s = socket.socket()
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    s.connect((u.hostname or "127.0.0.1", u.port or 80))
    s.sendall(b"GET /events HTTP/1.1\r\nHost: x\r\nAccept: text/event-stream\r\n\r\n")
    t0 = time.monotonic()
    until.wait(stall_s)
    out["stalled_s"] = time.monotonic() - t0
    s.settimeout(1.0)
    n = 0
    t_end = time.monotonic() + 2.0  # read what waits (the stream goes on), then leave
    try:
        while time.monotonic() < t_end:
            chunk = s.recv(65536)
            if not chunk:
                break
            n += len(chunk)
    except OSError:
        pass
    s.close()
    out["bytes_after_stall"] = n


def load(url: str, clients: int, frames: int, stall_s: float, timeout_s: float,
         stall_min_s: float = 0.0) -> dict[str, Any]:
    """Run the clients (module docstring); returns what each got."""
    deadline = time.monotonic() + timeout_s
    results: list[dict[str, Any]] = [{} for _ in range(clients)]
    stalled: dict[str, Any] = {}
    done = threading.Event()
    st = threading.Thread(target=stalled_client, args=(url, done, stall_s, stalled))
    st.start()
    threads = [threading.Thread(target=page_client, args=(url, frames, deadline, r))
               for r in results]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if stall_min_s:  # the stalled client stays stalled at least this long
        time.sleep(max(0.0, stall_min_s - (timeout_s - (deadline - time.monotonic()))))
    done.set()
    st.join()
    return {"clients": results, "stalled": stalled}


# --------------------------------------------------------------------------- benchmark


def metrics(url: str) -> dict[str, float]:
    """``/metrics`` as {name{labels}: value} (prometheus-client's parser)."""
    from prometheus_client.parser import text_string_to_metric_families

    text = urllib.request.urlopen(url + "metrics", timeout=10).read().decode()
    out = {}
    for fam in text_string_to_metric_families(text):
        for s in fam.samples:
            key = s.name + ("{" + ",".join(f"{k}={v}" for k, v in sorted(s.labels.items()))
                            + "}" if s.labels else "")
            out[key] = s.value
    return out


def _run(duration: float, with_clients: bool, args: argparse.Namespace) -> dict[str, Any]:
    cmd = [sys.executable, "-m", "appliance", "run", "--duration", str(duration),
           "--live", "off", "--set", "live.page.port=0", "--log-level", "WARNING",
           "--record-dir", args.record_dir]
    proc = subprocess.Popen(cmd, cwd=ROOT, stderr=subprocess.PIPE, text=True)
    assert proc.stderr is not None
    lines: list[str] = []
    url = None
    report: dict[str, Any] = {}
    for line in proc.stderr:
        lines.append(line)
        m = re.search(r"operator page: (http://\S+)", line)
        if m:
            url = m.group(1)
            if with_clients:
                threading.Thread(target=_with_clients, args=(url, args, report),
                                 daemon=True).start()
    proc.wait()
    final = next(x for x in lines if x.startswith("ogiflow: stopped."))
    processed = re.search(r"processed \d+ \([\d.]+/s, (\d+) %", final)
    lost = re.search(r"lost (\d+)/(\d+)", final)
    return {"final": final.strip(), "processed_pct": int(processed.group(1)),
            "lost": [int(lost.group(1)), int(lost.group(2))], **report, "url": url}


def _with_clients(url: str, args: argparse.Namespace, report: dict[str, Any]) -> None:
    rss = 'ogiflow_process_resident_memory_bytes{process=daemon}'
    time.sleep(args.start_s)
    # before: once processing runs (the scene's start-up memory is freed by then)
    while metrics(url).get("ogiflow_results_total", 0) < 100:
        time.sleep(1.0)
    report["rss_before_mb"] = metrics(url)[rss] / 2**20
    out = load(url, args.clients, args.frames, args.stall_s, args.stall_s + 30,
               stall_min_s=args.stall_s)
    report["rss_with_clients_mb"] = metrics(url)[rss] / 2**20
    time.sleep(10.0)
    m = metrics(url)
    report["rss_after_mb"] = m[rss] / 2**20
    report["page_drops"] = m.get("ogiflow_drops_total{queue=page}")
    report["frames_per_client"] = sorted(c.get("frames", 0) for c in out["clients"])
    report["stalled"] = out["stalled"]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    ld = sub.add_parser("load", help="clients against a running page")
    ld.add_argument("url")
    cp = sub.add_parser("compare", help="two daemon runs, without and with clients")
    cp.add_argument("--duration", type=float, default=150.0)
    cp.add_argument("--start-s", type=float, default=40.0,
                    help="clients come this long after the page is up (and once 100 "
                         "triples were processed)")
    cp.add_argument("--record-dir", default="/tmp/ogiflow-page-bench")
    for q in (ld, cp):
        q.add_argument("--clients", type=int, default=20)
        q.add_argument("--frames", type=int, default=100, help="pictures each client fetches")
        q.add_argument("--stall-s", type=float, default=60.0)
    ld.add_argument("--timeout-s", type=float, default=120.0)
    args = p.parse_args(argv)
    if args.cmd == "load":
        print(json.dumps(load(args.url, args.clients, args.frames, args.stall_s,
                              args.timeout_s)))
        return 0
    base = _run(args.duration, False, args)
    loaded = _run(args.duration, True, args)
    print(json.dumps({"without_clients": base, "with_clients": loaded,
                      "processed_points_difference": loaded["processed_pct"]
                      - base["processed_pct"]}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
