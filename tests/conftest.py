"""Shared fixtures: the location of ../shared/data, skipping clearly where it is absent."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("MMDOPT_SHARED_DATA", REPO.parent / "shared" / "data"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared test data not found at {SHARED_DATA} (set MMDOPT_SHARED_DATA)")
    return SHARED_DATA


@pytest.fixture
def x64():
    """JAX's x64 mode for the duration of a test (the numerics of float64 code paths); the
    package itself never switches it on globally."""
    import jax

    with jax.enable_x64(True):
        yield
