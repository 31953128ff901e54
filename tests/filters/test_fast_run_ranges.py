"""The fast offline loop (``FilterEstimator.run``) against the per-measurement
loop (``Estimator.run``) on a simulated paper drive with its default range
model: ranges that only ignition reads are converted per scan in both loops,
so the start (and every output) agrees exactly."""

import numpy as np
import pytest

from filters import ESTIMATORS
from graphpos.estimator import Estimator
from graphpos.sim import simulate


@pytest.fixture(scope="module")
def paper_drive():
    return simulate("paper-straight", seed=0, duration_s=25).without_truth()


@pytest.mark.parametrize("name", ["dr", "fusion-ekf"])
def test_fast_run_equals_process_loop_with_default_ranges(paper_drive, name):
    fast = ESTIMATORS[name]().run(paper_drive)
    slow = Estimator.run(ESTIMATORS[name](), paper_drive)
    assert len(fast) == len(slow) > 5
    assert fast.diagnostics["start"] == slow.diagnostics["start"]
    for col, a in fast.table().items():
        np.testing.assert_allclose(a, slow.table()[col], rtol=1e-12, atol=1e-12, err_msg=col)
