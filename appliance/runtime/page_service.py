"""Starting and stopping the operator's page for the daemon (``live.page``).

The hub (an encoder thread holding the newest picture and status) and the HTTP server are
started before any device opens, so a busy port is a configuration error (exit 2), and are
closed after the run's final summary.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from appliance.page.hub import PageHub
from appliance.page.server import PageServer


def start_page(page: Any, *, clock: Callable[[], int], metrics: Callable[[], bytes]
               ) -> tuple[PageHub | None, PageServer | None]:
    """The page's hub and server, started; (None, None) when ``page.enabled`` is false.

    Raises
    ------
    ConfigError
        ``page.port`` cannot be bound (the hub is closed again).
    """
    if not page.enabled:
        return None, None
    hub = PageHub(page.max_image_hz, page.jpeg_quality, clock=clock).start()
    try:
        server = PageServer(page, hub, metrics=metrics).start()
    except BaseException:
        hub.close()
        raise
    return hub, server


def stop_page(hub: PageHub | None, server: PageServer | None) -> None:
    """Close the server, then the hub (either may be None)."""
    if server is not None:
        server.close()
    if hub is not None:
        hub.close()
