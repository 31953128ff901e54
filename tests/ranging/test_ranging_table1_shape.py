"""Issue 20: song2016 Table 1 in shape on the simulated calibration data.

Done when, over 20 fresh seeds: in every environment LSSVM's distance-error
STD is at most 0.65 x the propagation model's, and the ratio of the two STDs
matches the paper's (4.07/8.19, 3.13/8.28, 5.52/10.43) within +-25 %. The
RSS law's parameters were tuned on seeds 0-4; the seeds here are fresh.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from graphpos.ranging.calibration_data import simulate_collection
from graphpos.ranging.lssvm import LssvmRangeModel
from graphpos.ranging.table1 import PUBLISHED_TABLE1, fitting_errors, published_std_ratio

ENVIRONMENTS = ("laboratory", "outdoor", "tunnel")
MAX_RATIO = 0.65
TOLERANCE = 0.25


def _std_ratios(environment: str, seeds) -> np.ndarray:
    ratios = []
    for seed in seeds:
        row = fitting_errors(environment, seed)
        ratios.append(row["lssvm"]["std"] / row["propagation"]["std"])
    return np.array(ratios)


def _check(environment: str, seeds) -> None:
    ratios = _std_ratios(environment, seeds)
    paper = published_std_ratio(environment)
    assert ratios.max() <= MAX_RATIO, (environment, ratios.round(3))
    assert abs(ratios.mean() / paper - 1.0) <= TOLERANCE, (environment, ratios.mean(), paper)


def test_published_ratios():
    assert published_std_ratio("laboratory") == pytest.approx(4.07 / 8.19)
    assert set(PUBLISHED_TABLE1) == set(ENVIRONMENTS)


@pytest.mark.parametrize("environment", ENVIRONMENTS)
def test_table1_ratio_in_shape_few_seeds(environment):
    _check(environment, range(100, 103))


@pytest.mark.slow
@pytest.mark.parametrize("environment", ENVIRONMENTS)
def test_table1_ratio_in_shape_twenty_fresh_seeds(environment):
    _check(environment, range(100, 120))


@pytest.mark.parametrize("environment", ENVIRONMENTS)
def test_lssvm_calibration_fit_under_5_s(environment):
    train = simulate_collection(environment, [7, 0])
    start = time.perf_counter()
    LssvmRangeModel().fit(train.mean_rss, train.distance_m)
    assert time.perf_counter() - start < 5.0


def test_table1_text_prints_the_std_ratios_beside_the_papers(capsys):
    from graphpos.cli import main

    assert main(["ranging", "table1", "--seed", "100"]) == 0
    out = capsys.readouterr().out
    assert "STD ratio" in out and "ours (m)" in out and "ours (RSS)" in out
    rows = {line.split()[0]: line.split()[1:] for line in out.splitlines()[-3:]}
    assert set(rows) == set(ENVIRONMENTS)
    for environment, (ours_m, _ours_rss, paper) in rows.items():
        assert float(paper) == pytest.approx(published_std_ratio(environment), abs=0.005)
        assert float(ours_m) <= MAX_RATIO
