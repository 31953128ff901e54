"""The song2016 estimators on simulated drives of the papers' specification.

Consistency (NEES) over seeded runs, and the papers' orderings: fusion-ekf
(dense tags) and fukf (optimised layout) beat rfid-ekf and dr; fukf is within
25 % of fusion-ekf; rfid-ekf beats multilateration inside the tunnel. The
full sets are slow; a small fast version of each runs by default.
"""

import numpy as np
import pytest
from scipy.stats import chi2
from song2016_drives import position_errors, rms

from filters.song2016 import ESTIMATORS
from graphpos.sim import simulate

LAYOUT = {"fukf": "optimized"}


def _anees(name, seeds, scenario="paper-straight", pattern="constant"):
    """Mean over epochs of the NEES averaged over runs, and its 95 % band."""
    per_run = []
    for seed in seeds:
        drive = simulate(scenario, pattern=pattern, seed=seed)
        est = ESTIMATORS[name](layout=LAYOUT.get(name)).run(drive)
        tr = drive.truth
        d = np.column_stack([est.east_m - np.interp(est.t_s, tr.t_s, tr.east_m), est.north_m - np.interp(est.t_s, tr.t_s, tr.north_m)])
        per_run.append(np.einsum("ni,nij,nj->n", d, np.linalg.inv(est.cov_en_m2), d))
    n = len(seeds)
    anees = np.mean(per_run, axis=0)  # per epoch, over runs
    return float(anees.mean()), (chi2.ppf(0.025, 2 * n) / n, chi2.ppf(0.975, 2 * n) / n)


@pytest.mark.parametrize("name", ["fusion-ekf", "fukf"])
def test_nees_in_band_fast(name):
    value, (lo, hi) = _anees(name, range(5))
    assert lo <= value <= hi, (value, lo, hi)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["fusion-ekf", "fukf"])
@pytest.mark.parametrize("scenario,pattern", [("paper-straight", "accel"), ("paper-comprehensive", "lane-change-curve")])
def test_nees_in_band_20_runs(name, scenario, pattern):
    value, (lo, hi) = _anees(name, range(20), scenario, pattern)
    assert lo <= value <= hi, (value, lo, hi)


def _table(drives):
    """Mean over drives of the RMS error, whole drive and inside the tunnel."""
    whole, tunnel = {}, {}
    for drive in drives:
        for name in ESTIMATORS:
            est = ESTIMATORS[name](layout=LAYOUT.get(name)).run(drive)
            whole.setdefault(name, []).append(rms(position_errors(drive, est)))
            tunnel.setdefault(name, []).append(rms(position_errors(drive, est, "in_tunnel")))
    return {k: np.mean(v) for k, v in whole.items()}, {k: np.mean(v) for k, v in tunnel.items()}


def _check_orderings(drives):
    whole, tunnel = _table(drives)
    for best in ("fusion-ekf", "fukf"):
        for worse in ("rfid-ekf", "dr"):
            assert whole[best] < whole[worse], (best, worse, whole)
    assert whole["fukf"] <= 1.25 * whole["fusion-ekf"], whole
    assert tunnel["rfid-ekf"] < tunnel["multilateration"], tunnel


def test_paper_orderings_fast():
    _check_orderings([simulate("paper-straight", pattern="accel", seed=11), simulate("paper-comprehensive", pattern="lane-change-curve", seed=12)])


@pytest.mark.slow
def test_paper_orderings_all_patterns():
    from graphpos.sim.scenarios import CURVE_PATTERNS, STRAIGHT_PATTERNS

    drives = [simulate("paper-straight", pattern=p, seed=s) for p in STRAIGHT_PATTERNS for s in (1, 2)]
    drives += [simulate("paper-comprehensive", pattern=p, seed=s) for p in CURVE_PATTERNS for s in (1, 2)]
    _check_orderings(drives)
