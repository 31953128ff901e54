"""Filters started from ranges read long take the ranges' scale ignition found (filters/base.py)."""

from __future__ import annotations

import pytest

from tests.graph.graph_drives import position_errors, rms, run, synthetic_drive

#: Far beacons (20-90 m away): a few per cent of range scale is metres of error.
BEACONS = [(-20.0, 30.0, 0), (60.0, -25.0, 0), (130.0, 35.0, 0), (200.0, -30.0, 0), (40.0, 40.0, 0), (170.0, 45.0, 0)]


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("name", ["fusion-ekf", "fukf"])
def test_ranges_read_long_are_scaled_from_the_start(name, seed):
    """Ranges 7 % long: the start finds the scale and the filter tracks as it does on exact ranges
    (taken as exact, the same ranges put fusion-ekf and fukf about 2 m off, against 0.1-0.2 m)."""
    exact = synthetic_drive(duration_s=60, seed=seed, beacons=BEACONS, max_range_m=90, compass=False)
    long = synthetic_drive(duration_s=60, seed=seed, beacons=BEACONS, max_range_m=90, compass=False, range_scale=1.07)
    on_exact, on_long = run(name, exact, model="drive"), run(name, long, model="drive")
    assert on_exact.diagnostics["start"]["range_scale"] == 1.0
    assert on_long.diagnostics["start"]["range_scale"] == pytest.approx(1.07, abs=0.01)
    assert rms(position_errors(long, on_long)) < 1.5 * rms(position_errors(exact, on_exact)) + 0.05
