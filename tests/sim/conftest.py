"""Shared simulated drives for the simulator tests (built once per session)."""

from __future__ import annotations

import pytest

from graphpos.sim import simulate

#: A 10-minute drive: long enough for sensor statistics, about a second to build.
LONG_S = 600.0


@pytest.fixture(scope="session")
def long_straight():
    """paper-straight, 10 minutes out and back, seed 11."""
    return simulate("paper-straight", seed=11, duration_s=LONG_S)


@pytest.fixture(scope="session")
def long_urban():
    """urban-rsu-gnss, 10 minutes, seed 12."""
    return simulate("urban-rsu-gnss", seed=12, duration_s=LONG_S)
