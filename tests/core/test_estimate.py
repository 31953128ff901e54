"""Estimate assembly and its CSV table."""

import numpy as np
import pytest

from graphpos.estimate import CSV_COLUMNS, Estimate, OutputRow


def test_from_rows_keeps_only_quantities_every_row_has():
    rows = [
        OutputRow(0.0, 1.0, 2.0, 0.5, 0.0, 0.1, np.eye(2)),
        OutputRow(0.1, 1.1, 2.0, None, 0.0, 0.1, np.eye(2) * 2),
    ]
    est = Estimate.from_rows("x", rows, rate_hz=10.0)
    assert est.v_east_mps is None and est.v_north_mps is not None
    assert est.cov_en_m2.shape == (2, 2, 2)
    table = est.table()
    assert list(table) == list(CSV_COLUMNS)
    assert np.isnan(table["v_east_mps"]).all()
    np.testing.assert_array_equal(table["var_east_m2"], [1.0, 2.0])


def test_shapes_are_checked():
    with pytest.raises(ValueError, match="east_m has 1 rows"):
        Estimate("x", t_s=[0.0, 1.0], east_m=[0.0], north_m=[0.0, 1.0])
    with pytest.raises(ValueError, match="cov_en_m2"):
        Estimate("x", t_s=[0.0], east_m=[0.0], north_m=[0.0], cov_en_m2=np.zeros((1, 3, 3)))
