"""Shared test fixtures.

Real data lives beside the project at ``../shared/data`` (override with
``LSR_SHARED_DATA``). Tests that need it take the ``shared_data`` fixture and skip
cleanly, with a reason, when it is absent.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]


def shared_data_dir() -> Path:
    return Path(os.environ.get("LSR_SHARED_DATA", REPO_ROOT.parent / "shared" / "data"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    root = shared_data_dir()
    if not (root / "README.md").is_file():
        pytest.skip(f"shared real data not found at {root} (set LSR_SHARED_DATA to point at it)")
    return root


@pytest.fixture
def rng() -> np.random.Generator:
    """Seeded numpy generator: random test data is reproducible."""
    return np.random.default_rng(0)
