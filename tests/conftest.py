"""Shared fixtures: paths to the reference data shipped with the repository, and the small
simulated scene the whole-daemon tests share (rendered once per test session)."""

from __future__ import annotations

import fcntl
import os
from collections.abc import Iterator
from pathlib import Path

# Ray (the reprocess tests) resolves 127.0.0.1 to the host's network address and listens
# there unless this is set before ray is first imported: keep every test on loopback.
os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """The repository's ``data/`` folder (real reference data with provenance)."""
    return ROOT / "data"


@pytest.fixture(scope="session")
def test_data_dir() -> Path:
    """``tests/data/`` (small golden files)."""
    return ROOT / "tests" / "data"


@pytest.fixture(scope="module", autouse=True)
def module_lock(request: pytest.FixtureRequest,
                tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """With ``pytest -n`` (test modules in several processes): a module marked ``alone``
    runs while no other module does; the others run side by side.

    The browser modules read how soon chromium (software rendering) shows what the daemon
    did; beside another module's daemon that reads the load, not the page. A readers-
    writer lock on files every process of the run sees (flock): each module holds the
    main lock shared, an ``alone`` module exclusive; an ``alone`` module waiting holds the
    turnstile, so modules starting meanwhile wait behind it instead of starving it.
    """
    root = tmp_path_factory.getbasetemp().parent  # shared by the processes of one run
    alone = request.node.get_closest_marker("alone") is not None
    with open(root / "modules.turnstile", "a") as gate, open(root / "modules.lock", "a") as main:
        fcntl.flock(gate, fcntl.LOCK_EX if alone else fcntl.LOCK_SH)
        fcntl.flock(main, fcntl.LOCK_EX if alone else fcntl.LOCK_SH)
        if not alone:
            fcntl.flock(gate, fcntl.LOCK_UN)
        try:
            yield
        finally:
            fcntl.flock(main, fcntl.LOCK_UN)
            if alone:
                fcntl.flock(gate, fcntl.LOCK_UN)


@pytest.fixture(scope="session")
def scene_cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``simulation.cache_dir`` for whole-daemon tests: with :data:`SMALL_SCENE` the scene is
    rendered by the first test that runs the daemon and reused by the others."""
    return tmp_path_factory.mktemp("scene-cache")


#: Config overrides of a small, coarse simulated scene (fast to render, still a real plume).
# Whole-daemon tests read one set of files: the earlier single-folder recording layout (the
# split retention layout has its own tests in test_retention.py).
# The operator's page on any free port: daemons of tests running side by side (or a real
# appliance on this machine) never collide on the default 8080.
SMALL_SCENE = [("simulation.frames", 24), ("simulation.voxel_m", 0.12),
               ("recording.split", False), ("live.page.port", 0)]
