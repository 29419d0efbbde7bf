"""The running daemon (docs/design.md's data flow).

Acquisition threads and the daemon (``daemon``), clocks and pairing (``clock``, ``pairing``,
``stamping``), the shared-memory ring buffer (``ring``), worker processes (``workers``),
result publishing (``publishing``), health (``health``), systemd notification
(``sdnotify``) and the simulated site (``simsite``).
"""
