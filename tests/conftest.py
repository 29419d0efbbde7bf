"""Shared fixtures: paths to the reference data shipped with the repository."""

from __future__ import annotations

from pathlib import Path

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
