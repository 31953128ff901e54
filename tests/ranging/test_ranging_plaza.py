"""Linear calibration of the Plaza1 ranges (real data; skipped when the shared data are absent)."""

from __future__ import annotations

import numpy as np

from graphpos.ranging import LinearCalibration, fit_from_drive, true_ranges_m


def test_plaza1_ranges_read_seven_percent_long(plaza1_drive):
    model = fit_from_drive(plaza1_drive)
    assert isinstance(model, LinearCalibration)
    assert abs(model.scale - 1.07) < 0.01
    true_m = true_ranges_m(plaza1_drive)
    reported = plaza1_drive.rfid.range_m
    ok = np.isfinite(true_m) & np.isfinite(reported)
    before = np.mean(reported[ok] - true_m[ok])
    after = model.predict_distance_m(reported[ok]) - true_m[ok]
    assert before > 2.0  # uncalibrated, the ranges read metres long
    assert abs(np.mean(after)) < 0.2
    # the learned sigma describes the calibrated residuals
    z = after / model.predict_sigma_m(model.predict_distance_m(reported[ok]))
    assert 0.7 < np.sqrt(np.mean(z**2)) < 1.5
