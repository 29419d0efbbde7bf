"""``/metrics``: the running appliance in the Prometheus text format (prometheus-client).

Read at each scrape from the same counters as the health report and the final line of
``ogiflow run`` (:func:`appliance.runtime.counters.health_counters`), so a scrape at the
end of a run gives that line's numbers. Names (``_total`` = counter):

- ``ogiflow_frames_total{camera}``, ``ogiflow_frames_lost_total{camera}``,
  ``ogiflow_unpaired_frames_total{camera}``, ``ogiflow_pairs_total``,
  ``ogiflow_results_total``, ``ogiflow_result_errors_total``,
  ``ogiflow_skipped_pairs_total``, ``ogiflow_wind_samples_total``;
- ``ogiflow_drops_total{queue}`` (frame_queue, recorder, live, ring, alarm, page);
- ``ogiflow_processed_fraction`` (results / (results + skipped triples));
- ``ogiflow_queue_depth{queue}`` (recorder, ring, alarm, page);
- ``ogiflow_disk_free_bytes``, ``ogiflow_leak`` (1 while an event is open),
  ``ogiflow_leak_events_total``, ``ogiflow_emission_rate_kg_h`` and
  ``ogiflow_emission_rate_uncertainty_kg_h`` (NaN when unknown);
- ``ogiflow_process_resident_memory_bytes{process}`` (daemon, worker0, worker1, ...);
- ``ogiflow_page_clients``; ``ogiflow_health_counter{name}``: every counter of the health
  report under its own name (one that the health monitor adds later appears by itself).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

from prometheus_client import CONTENT_TYPE_LATEST, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector, CollectorRegistry

from appliance.runtime.counters import health_counters
from appliance.runtime.health import disk_free_source
from appliance.runtime.keepup import rss_mb

__all__ = ["ApplianceCollector", "metrics_text"]

SIDES = ("left", "right")


def _nan(v: float | None) -> float:
    return math.nan if v is None else float(v)


class ApplianceCollector(Collector):
    """Reads a running :class:`~appliance.runtime.daemon.Appliance` at each scrape."""

    def __init__(self, app: Any) -> None:
        self.app = app

    def collect(self) -> Iterator[Metric]:

        app = self.app
        c = health_counters(app)
        yield from self._streams(c)
        yield from self._queues(c)
        results, skipped = c["results"], c["skipped_pairs"]
        yield GaugeMetricFamily("ogiflow_processed_fraction",
                                "processed triples / (processed + skipped)",
                                value=results / (results + skipped) if results + skipped
                                else math.nan)
        yield from self._monitor()
        yield from self._memory()
        g = GaugeMetricFamily("ogiflow_health_counter", "every counter of the health report",
                              labels=["name"])
        for name, v in sorted(c.items()):
            g.add_metric([name], float(v))
        yield g

    def _streams(self, c: dict[str, int]) -> Iterator[Metric]:
        for name, doc, key in (("frames", "frames captured", "frames_{}"),
                               ("frames_lost", "frames the camera lost", "frames_lost_{}"),
                               ("unpaired_frames", "frames left without a partner",
                                "unpaired_{}")):
            m = CounterMetricFamily(f"ogiflow_{name}", doc, labels=["camera"])
            for side in SIDES:
                m.add_metric([side], c[key.format(side)])
            yield m
        for name, doc, key in (("pairs", "stereo pairs", "pairs"),
                               ("results", "processed triples published", "results"),
                               ("result_errors", "triples whose processing failed",
                                "result_errors"),
                               ("skipped_pairs", "triples skipped to keep up", "skipped_pairs"),
                               ("wind_samples", "anemometer samples", "wind_samples"),
                               ("worker_restarts", "worker processes restarted",
                                "worker_restarts")):
            yield CounterMetricFamily(f"ogiflow_{name}", doc, value=c[key])

    def _queues(self, c: dict[str, int]) -> Iterator[Metric]:
        app = self.app
        page = getattr(app, "page_server", None)
        ps = page.stats() if page is not None else None
        drops = CounterMetricFamily("ogiflow_drops", "items dropped by a bounded queue",
                                    labels=["queue"])
        for queue, key in (("frame_queue", "frame_queue_drops"), ("recorder", "recorder_drops"),
                           ("live", "live_drops"), ("ring", "ring_overwrites"),
                           ("alarm", "alarm_dropped")):
            if key in c:
                drops.add_metric([queue], c[key])
        if ps is not None:
            drops.add_metric(["page"], ps.client_drops)
        yield drops
        depth = GaugeMetricFamily("ogiflow_queue_depth", "items waiting in a queue",
                                  labels=["queue"])
        if app.recorder is not None:
            depth.add_metric(["recorder"], app.recorder.stats().queue_depth)
        if app.ring is not None:
            depth.add_metric(["ring"], app.ring.stats().occupancy)
        if "alarm_queued" in c:
            depth.add_metric(["alarm"], c["alarm_queued"])
        if ps is not None:
            depth.add_metric(["page"], ps.queue_depth)
        yield depth
        if ps is not None:
            yield GaugeMetricFamily("ogiflow_page_clients", "browsers on the operator's page",
                                    value=ps.clients)
        free = None
        if app.cfg.recording.enabled:

            free = disk_free_source(app.cfg.recording.dir)()["disk_free_gb"]
        yield GaugeMetricFamily("ogiflow_disk_free_bytes", "free space for recordings",
                                value=math.nan if free is None else free * 1e9)

    def _monitor(self) -> Iterator[Metric]:
        mon = self.app.monitor
        s = None if mon is None else mon.status()
        n_events = 0 if mon is None else (len(mon.detector.finished)
                                          + (mon.detector.current is not None))
        yield GaugeMetricFamily("ogiflow_leak", "1 while a leak event is open",
                                value=float(s is not None and s.leak is not None))
        yield CounterMetricFamily("ogiflow_leak_events", "leak events opened", value=n_events)
        yield GaugeMetricFamily("ogiflow_emission_rate_kg_h", "windowed emission rate",
                                value=_nan(None if s is None else s.rate_kg_h))
        yield GaugeMetricFamily("ogiflow_emission_rate_uncertainty_kg_h",
                                "uncertainty of the windowed emission rate",
                                value=_nan(None if s is None else s.rate_uncertainty_kg_h))

    def _memory(self) -> Iterator[Metric]:

        m = GaugeMetricFamily("ogiflow_process_resident_memory_bytes",
                              "resident memory of each process", labels=["process"])
        procs: list[tuple[str, int | None]] = [("daemon", None)]
        pool = self.app.pool
        if pool is not None:
            procs += [(f"worker{i}", p.pid) for i, p in enumerate(pool.workers)]
        for name, pid in procs:
            mb = rss_mb(pid)
            if mb is not None:
                m.add_metric([name], mb * 1024 * 1024)
        yield m


def metrics_text(app: Any) -> tuple[bytes, str]:
    """The ``/metrics`` body of ``app`` and its content type."""
    registry = CollectorRegistry(auto_describe=False)
    registry.register(ApplianceCollector(app))
    return generate_latest(registry), CONTENT_TYPE_LATEST
