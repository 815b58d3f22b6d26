"""Shared fixtures: the reference data in ../shared (skipped with a clear message if absent)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parent.parent
SHARED = REPO.parent / "shared"
DATA = SHARED / "data"


def _require(path: Path) -> Path:
    if not path.exists():
        pytest.skip(f"reference data not found at {path} (expected ../shared/data beside the checkout)")
    return path


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data``; skips the test when it is absent."""
    return _require(DATA)


@pytest.fixture(scope="session")
def broad_dir() -> Path:
    return _require(DATA / "broad")


@pytest.fixture(scope="session")
def mavlink_logs_dir() -> Path:
    return _require(DATA / "mavlink_logs")


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)
