"""Speed of the stereo emission rate of one triple at 320x240 (one core), as a worker runs it.

Run: ``PYTHONPATH=. .venv/bin/python benchmarks/bench_emission.py [--rates N] [--json OUT]``

Input: the bench's cached `field` frames (``ogiflow bench``'s input: a plume 5.5 m away, a
fifth of the frame, raw 16-bit counts of the simulator's counts model), run through the
chain once (warm, consecutive triples); then :func:`appliance.runtime.emission_setup.
emission_rate` on those results, cycled, as a worker calls it on every ``emission.every``-th
triple. The first ``background_frames`` rates only fill the background model's stack and
are not timed; after them the model refreshes its median once every ``background_frames``
rates, a slow call (tens of ms), so both the median and the mean per rate are reported (the
mean is what a worker pays on average). OpenCV Farneback on the same differential images is
the yardstick measured in the same run (the ratio divides by its median).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np

from appliance.evaluation.bench_input import SOURCES, geometry, iter_triples, load_frames
from appliance.runtime.emission_setup import EmissionSetup, emission_rate
from benchmarks.common import median_ms, single_thread
from processing.calibration.radiometric import CharacteristicCurve
from processing.chain import ChainParameters, ChainState, compute_scene_flow
from processing.emission.estimator import EmissionSettings
from processing.flow.opencv import farneback_flow
from processing.synthetic.imaging import CountsModel

#: The simulated scene's gas temperature, K (the rate's L_g).
GAS_TEMPERATURE_K = 285.0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--rates", type=int, default=120, help="timed rates after the stack fills")
    ap.add_argument("--triples", type=int, default=40, help="chain results to cycle through")
    ap.add_argument("--source", choices=SOURCES, default="field",
                    help="the bench input (`ogiflow bench --source`)")
    ap.add_argument("--cache-dir", type=Path, default=None, help="the bench input's cache")
    ap.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = ap.parse_args(argv)
    if args.rates < 1 or args.triples < 1:
        ap.error("--rates and --triples must be >= 1")
    single_thread()
    frames = load_frames(args.source, max(16, args.triples + 2), cache_dir=args.cache_dir)
    geo = geometry(frames.image_size)
    params, state = ChainParameters(), ChainState()
    triples = iter_triples(frames)
    results = []
    for _ in range(args.triples):
        left, right, times = next(triples)
        results.append((left[1], compute_scene_flow(left, right, times, geo, params, state)))
    counts = CountsModel()  # the simulator's, which the bench frames were rendered with
    settings = EmissionSettings()
    setup = EmissionSetup(settings, gas_temperature_k=GAS_TEMPERATURE_K,
                          curve_left=CharacteristicCurve(offset=counts.offset,
                                                         gain=counts.gain))
    estimator = setup.estimator(geo)
    assert estimator is not None  # the setup carries a curve
    for k in range(settings.background_frames):  # fill the background stack, untimed
        left1, res = results[k % len(results)]
        emission_rate(estimator, left1, res, GAS_TEMPERATURE_K)
    times_ms, defined = [], 0
    for k in range(args.rates):
        left1, res = results[k % len(results)]
        t0 = time.perf_counter()
        rate = emission_rate(estimator, left1, res, GAS_TEMPERATURE_K)
        times_ms.append((time.perf_counter() - t0) * 1e3)
        defined += rate.rate_g_s is not None
    d0, d1 = results[-1][1].diff_left
    farneback = median_ms(lambda: farneback_flow(d0, d1))
    figures = {
        "rate_median_ms": statistics.median(times_ms),
        "rate_mean_ms": float(np.mean(times_ms)),
        "rate_max_ms": float(np.max(times_ms)),
        "rates": args.rates, "rates_defined": defined,
        "farneback_ms": farneback,
        "ratio_to_farneback": statistics.median(times_ms) / farneback,
    }
    print(f"emission rate per triple, {args.rates} rates after the background stack filled "
          f"({defined} defined): median {figures['rate_median_ms']:.2f} ms, mean "
          f"{figures['rate_mean_ms']:.2f} ms (the background refresh included), max "
          f"{figures['rate_max_ms']:.1f} ms; Farneback {farneback:.2f} ms; median = "
          f"{figures['ratio_to_farneback']:.2f}x Farneback")
    if args.json is not None:
        args.json.write_text(json.dumps(figures, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
