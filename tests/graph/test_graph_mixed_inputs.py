"""RFID readings with a range and readings with RSS only in one drive (issue 14, item 4).

Both fields are optional in a reading. The drive's default range model of
such a drive reads ``range_m`` (it reports ranges); the RSS-only readings
go through the drive's default RSS model (:func:`graphpos.ranging.reading_models`),
each reading through the model of its own field, in the graphs and the
filters alike. A range model the user chose that no reading of the drive
can feed is refused, naming the estimator. Estimators see
``drive.without_truth()``; scores use the truth.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import pytest
from graph_drives import errors, mixed_readings, rms, run, synthetic_drive

from filters import ESTIMATORS as FILTERS
from graphpos.drive import Drive, Measurement
from graphpos.errors import ConfigError
from graphpos.graph import ESTIMATORS as GRAPHS
from graphpos.graph import ODOMETRY_ESTIMATORS
from graphpos.ranging import calibrated_model

GRAPH_KEYS = tuple(f"{name}/{p}" for name in sorted(ODOMETRY_ESTIMATORS) for p in ("planar", "inertial"))
#: Which readings carry RSS only ("rss-only", "range-only": the references).
MIXES = {
    "alternate": lambda n, rng: np.arange(n) % 2 == 0,
    "random-30%": lambda n, rng: rng.random(n) < 0.3,
    "all-but-one": lambda n, rng: np.arange(n) > 0,
    "rss-only": lambda n, rng: np.ones(n, dtype=bool),
    "range-only": lambda n, rng: np.zeros(n, dtype=bool),
}


@lru_cache(maxsize=None)
def mixed(mix: str) -> Drive:
    drive = synthetic_drive(25, seed=41, turn_radps=0.05)
    return mixed_readings(drive, MIXES[mix](len(drive.rfid), np.random.default_rng(2)))


@lru_cache(maxsize=None)
def reference_rms(key: str) -> float:
    """The worse of the drive with RSS only and with ranges only (each with its own default model)."""
    return max(rms(errors(mixed(m), run(key, mixed(m), model="drive"))) for m in ("rss-only", "range-only"))


@pytest.mark.parametrize("mix", ["alternate", "random-30%", "all-but-one"])
@pytest.mark.parametrize("key", GRAPH_KEYS)
def test_graphs_use_each_readings_own_field(key, mix):
    drive = mixed(mix)
    est = run(key, drive, model="drive")  # the drive's default: it reports ranges, so 'linear'
    assert np.all(np.isfinite(est.position)) and np.all(np.isfinite(est.cov_en_m2))
    assert est.diagnostics["ranges"] + est.diagnostics["ranges_unusable"] == len(drive.rfid)
    assert est.diagnostics["ranges_unusable"] <= 0.02 * len(drive.rfid)
    assert rms(errors(drive, est)) < reference_rms(key) + 0.05


@pytest.mark.parametrize("key", ["graph-isam2/inertial", "graph-batch/planar"])
def test_a_given_range_model_reads_its_field_the_default_the_other(key):
    drive = mixed("alternate")
    est = run(key, drive)  # LinearCalibration given: the RSS-only readings through the drive's RSS model
    assert est.diagnostics["ranges"] + est.diagnostics["ranges_unusable"] == len(drive.rfid)
    assert rms(errors(drive, est)) < 0.5


@pytest.mark.parametrize("mix", ["alternate", "random-30%", "all-but-one"])
def test_filters_use_each_readings_own_field(mix):
    drive = mixed(mix)
    for name in FILTERS:
        if name == "fkf":  # RSU/GNSS only
            continue
        est = run(name, drive, model="drive")
        assert len(est) > 0 and np.all(np.isfinite(est.position)), name
        assert est.diagnostics["ranges_unusable"] <= 0.02 * len(drive.rfid), (name, est.diagnostics["ranges_unusable"])


@pytest.mark.parametrize("name", ["graph-isam2", "graph-batch", "fusion-ekf", "rfid-ekf"])
def test_a_range_model_no_reading_can_feed_is_refused_naming_the_estimator(name):
    drive = synthetic_drive(10, seed=42)  # ranges only, no RSS
    with pytest.raises(ConfigError, match=rf"^{name}: range model 'lssvm' reads 'rss'"):
        run(name + ("/planar" if name.startswith("graph") else ""), drive, model=calibrated_model("tunnel"))


@pytest.mark.parametrize("key", ["graph-isam2/inertial", "graph-fixed-lag/planar", "fusion-ekf", "lms-federated"])
def test_a_reading_with_neither_field_is_counted(key):
    drive = mixed("alternate")
    blank = set(range(3, len(drive.rfid), 11))
    seen = [0]

    def spoil(_: int, m: Measurement) -> Measurement:
        if m.channel != "rfid":
            return m
        seen[0] += 1
        return m._replace(values={**m.values, "range_m": math.nan, "rss": math.nan}) if seen[0] - 1 in blank else m

    est = run(key, drive, model="drive", spoil=spoil)
    assert np.all(np.isfinite(est.position))
    assert est.diagnostics["non_finite"] == {"rfid.range_m/rss": len(blank)}
