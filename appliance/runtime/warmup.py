"""``ogiflow run --prepare``: what a first start would otherwise do while acquiring.

Render the simulated scene (the configured one, cached) and run the chain once on its first
triple, which compiles numba's kernels into their on-disk cache. Opens no device.
"""

from __future__ import annotations

import time
from typing import Any

from processing.chain import ChainState, compute_scene_flow
from processing.synthetic import read_frame, read_sequence_meta


def warm_up(app: Any) -> str:
    """Prepare ``app`` (an :class:`appliance.runtime.daemon.Appliance`) with the full scene
    and compile the chain; returns what it did, for the user."""
    start = time.monotonic()
    app.prepare(full_scene=True)
    done = []
    site = app.site
    if site is not None and site.folder is not None and app.geometry is not None:
        done.append(f"simulated scene cached in {site.folder}")
        meta = read_sequence_meta(site.folder)
        f = [read_frame(site.folder, i, meta) for i in range(3)]
        compute_scene_flow([x.left for x in f], [x.right for x in f], [x.t_s for x in f],
                           app.geometry, app.params, ChainState())
        done.append("the chain's kernels compiled")
    else:
        done.append("no simulated scene to render; the chain compiles on its first triple")
    return f"{'; '.join(done)} ({time.monotonic() - start:.0f} s)"
