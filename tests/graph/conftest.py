"""Fixtures of the graph tests (their helpers are in graph_drives.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from graph_drives import PLAZA


@pytest.fixture
def plaza_path() -> Path:
    if not PLAZA.exists():
        pytest.skip(f"Plaza data not found at {PLAZA}")
    return PLAZA
