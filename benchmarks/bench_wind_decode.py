"""Decoding throughput of each anemometer protocol (messages per second).

Each protocol decodes a stream of 20,000 synthetic messages (plus the real captures in
tests/data/anemometer) fed in 4 KiB chunks, as a serial read would deliver them. Reported:
the median of REPEATS timed runs after one warm-up run. Target: >= 50,000 messages/s.

The machine is shared, so absolute rates move with its load; the last column is each rate
relative to a reference measured in the same run (splitting the CSAT3B stream into lines and
parsing four floats per line, with no framing or checks), which moves with the load too.

    python benchmarks/bench_wind_decode.py
"""

from __future__ import annotations

import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

from drivers.anemometer.campbell import format_csat3b
from drivers.anemometer.gill import format_gill_polar, format_gill_uvw
from drivers.anemometer.metek import format_metek
from drivers.anemometer.registry import make_decoder
from drivers.anemometer.young import format_young

N = 20_000
REPEATS = 7
CHUNK = 4096
TARGET = 50_000
DATA = Path(__file__).resolve().parents[1] / "tests" / "data" / "anemometer"


def synthetic() -> dict[str, bytes]:
    rng = np.random.default_rng(0)
    u, v, w = rng.normal(0, 5, (3, N))
    ts = rng.uniform(-10, 35, N)
    return {
        "gill_uvw": b"".join(format_gill_uvw(u[i], v[i], w[i], 340.0, ts[i]) for i in range(N)),
        "gill_polar": b"".join(
            format_gill_polar(i % 360, abs(u[i]), 340.0, ts[i], 0x60) for i in range(N)
        ),
        "campbell_csat3b": b"".join(
            format_csat3b(u[i], v[i], w[i], ts[i], 0, i % 256) for i in range(N)
        ),
        "young_81000": b"".join(
            format_young(abs(u[i]), i % 360, w[i], 340.0, ts[i]) for i in range(N)
        ),
        "metek_usonic3": b"".join(
            format_metek(int(100 * u[i]), int(100 * v[i]), int(100 * w[i]), int(100 * ts[i]))
            for i in range(N)
        ),
    }


def run_once(protocol: str, data: bytes) -> tuple[float, int]:
    decoder = make_decoder(protocol)
    feed = decoder.feed
    n = 0
    t = time.perf_counter()
    for k in range(0, len(data), CHUNK):
        n += len(feed(data[k : k + CHUNK], k))
    n += len(decoder.flush())
    return time.perf_counter() - t, n


def reference_rate(data: bytes) -> float:
    """Messages/s of the bare minimum: split lines, parse four floats (no checks)."""

    def once() -> tuple[float, int]:
        t = time.perf_counter()
        n = 0
        for line in data.splitlines():
            parts = line.split(b",")
            float(parts[0]), float(parts[1]), float(parts[2]), float(parts[3])
            n += 1
        return time.perf_counter() - t, n

    once()
    runs = [once() for _ in range(REPEATS)]
    return runs[0][1] / statistics.median(dt for dt, _ in runs)


def bench(
    name: str, protocol: str, data: bytes, ref: float, report: Callable[[str], None]
) -> float:
    run_once(protocol, data)  # warm-up
    times = []
    n = 0
    for _ in range(REPEATS):
        dt, n = run_once(protocol, data)
        times.append(dt)
    rate = n / statistics.median(times)
    flag = "ok" if rate >= TARGET else "BELOW TARGET"
    report(f"{name:<34} {n:>7} msgs  {rate:>10,.0f} msgs/s  {flag:<12} {rate / ref:5.2f} x ref")
    return rate


def main() -> int:
    print(
        f"decode throughput: median of {REPEATS} runs after warm-up, {CHUNK}-byte chunks, "
        f"target {TARGET:,} msgs/s"
    )
    streams = synthetic()
    ref = reference_rate(streams["campbell_csat3b"])
    print(f"{'reference: split + 4 floats':<34} {N:>7} msgs  {ref:>10,.0f} msgs/s")
    rates = {}
    for protocol, data in streams.items():
        decoder_name = "gill" if protocol.startswith("gill") else protocol
        rates[protocol] = bench(protocol, decoder_name, data, ref, print)
    captures = {
        "capture: CSAT3B raw (NCAR)": (
            "campbell_csat3b",
            DATA / "campbell_csat3b" / "csat3b_ascii_dsm5_id60_raw_stream.txt",
        ),
        "capture: CSAT3B timestamped": (
            "campbell_csat3b",
            DATA / "campbell_csat3b" / "csat3b_ascii_dsm5_id60_timestamped.tsv",
        ),
        "capture: Gill ship log": (
            "gill",
            DATA / "gill_windobserver" / "NBP1406_mwx1-2014-08-01.part1",
        ),
    }
    for name, (protocol, path) in captures.items():
        if path.is_file():
            rates[name] = bench(name, protocol, path.read_bytes(), ref, print)
    worst = min(rates, key=rates.__getitem__)
    print(
        f"slowest: {worst} at {rates[worst]:,.0f} msgs/s "
        f"({'meets' if rates[worst] >= TARGET else 'misses'} the {TARGET:,} target)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
