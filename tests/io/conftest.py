"""Shared fixtures for the io tests: paths to the real data bundled with the repository."""

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
DTU_PAIR = REPO / "tests" / "data" / "dtu_pair"
TEMPLE = REPO / "src" / "mvsformerpp" / "data" / "templeSparseRing"


@pytest.fixture
def dtu_pair() -> Path:
    return DTU_PAIR


@pytest.fixture
def temple() -> Path:
    return TEMPLE
