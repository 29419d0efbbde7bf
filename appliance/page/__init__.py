"""The operator's web page: leak state, picture, rate, wind, events and health in any
browser (no GPU needed), ``/status.json`` and ``/metrics`` (docs/operator-page.md).

``hub`` takes what the daemon pushes and encodes it, ``server`` serves it over HTTP
(aiohttp, one thread), ``metrics`` writes the Prometheus text format."""
