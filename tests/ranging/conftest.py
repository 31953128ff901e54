"""Fixtures of the ranging tests: the Plaza1 drive when the shared data are present."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

PLAZA1 = Path(__file__).resolve().parents[2] / "../shared/data/plaza/Plaza1.mat"


def _plaza_from_mat(path: Path):
    """Plaza1 as a Drive (rfid ranges + truth) read with scipy, for when the io importer is absent.

    TD columns: time, ?, beacon id, range; TL: id, x, y; GT: time, x, y, heading.
    """
    import scipy.io

    from graphpos.drive import Channel, Drive, TagMap

    mat = scipy.io.loadmat(path)
    td, tl, gt = mat["TD"], mat["TL"], mat["GT"]
    td = td[np.argsort(td[:, 0], kind="stable")]  # a few rows are out of time order
    n = tl.shape[0]
    tags = TagMap(tl[:, 0], tl[:, 1], tl[:, 2], np.zeros(n), -np.ones(n))
    rfid = Channel("rfid", {"t_s": td[:, 0], "tag_id": td[:, 2], "range_m": td[:, 3]})
    zeros = np.zeros(gt.shape[0])
    truth = Channel("truth", {"t_s": gt[:, 0], "east_m": gt[:, 1], "north_m": gt[:, 2],
                              "v_east_mps": zeros, "v_north_mps": zeros, "yaw_rad": gt[:, 3]})
    return Drive("Plaza1", {"rfid": rfid, "truth": truth}, tags=tags)


@pytest.fixture(scope="session")
def plaza1_drive():
    if not PLAZA1.exists():
        pytest.skip(f"Plaza data not found at {PLAZA1}")
    try:
        from graphpos.io.plaza import import_plaza
    except ImportError:
        return _plaza_from_mat(PLAZA1)
    return import_plaza(PLAZA1)
