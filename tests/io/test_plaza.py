"""Plaza importer: conventions checked against the data, any file with the
layout, clear errors for files without it."""

from __future__ import annotations

import numpy as np
import pytest
from drive_samples import assert_drives_equal
from plaza_samples import synthetic_plaza

from graphpos.errors import DriveError, FileFormatError
from graphpos.io import read_drive, write_drive
from graphpos.io.plaza import import_plaza


def dead_reckon(drive):
    """Integrate wheel speed and yaw rate over the truth's intervals from the
    first truth pose (midpoint heading); returns east, north, yaw."""
    truth = drive.truth
    dt = np.diff(truth.t_s)
    rate = drive.imu.yaw_rate_radps
    yaw = truth.yaw_rad[0] + np.r_[0.0, np.cumsum(rate * dt)]
    mid = yaw[:-1] + rate * dt / 2
    step = drive.wheel.speed_mps * dt
    east = truth.east_m[0] + np.r_[0.0, np.cumsum(step * np.cos(mid))]
    north = truth.north_m[0] + np.r_[0.0, np.cumsum(step * np.sin(mid))]
    return east, north, yaw


def test_plaza1_counts_and_ranges_left_uncorrected(plaza1):
    drive = import_plaza(plaza1)
    assert len(drive.truth) == 9658 and len(drive.rfid) == 3529
    assert sorted(drive.tags.tag_id.tolist()) == [0, 1, 5, 6]
    assert drive.duration_s == pytest.approx(1933, abs=1)
    ratio = np.median(drive.rfid.range_m / drive.rfid.true_range_m)
    assert ratio == pytest.approx(1.069, abs=0.005)  # GTSAM_NOTES: ~1.069 x long
    assert np.all(np.isnan(drive.rfid.rss)) and np.all(np.isnan(drive.imu.accel_x_mps2))
    assert np.all(np.diff(drive.rfid.t_s) >= 0)


def test_plaza1_heading_is_yaw_from_east_ccw(plaza1):
    drive = import_plaza(plaza1)
    truth = drive.truth
    moving = np.hypot(truth.v_east_mps, truth.v_north_mps) > 0.5
    direction = np.arctan2(truth.v_north_mps, truth.v_east_mps)
    diff = np.angle(np.exp(1j * (direction - truth.yaw_rad)))[moving]
    assert abs(np.median(diff)) < 0.03
    assert np.percentile(np.abs(diff), 90) < 0.15


def test_plaza1_odometry_reproduces_ground_truth(plaza1):
    drive = import_plaza(plaza1)
    east, north, yaw = dead_reckon(drive)
    truth = drive.truth
    # the yaw increments are the ground truth heading's own differences
    assert np.abs(yaw - truth.yaw_rad).max() < 1e-5
    # 1.86 km of odometry drifts by under 0.5 % of the path
    assert np.hypot(east - truth.east_m, north - truth.north_m).max() < 9.3


def test_plaza1_round_trips(plaza1, tmp_path):
    drive = import_plaza(plaza1)
    write_drive(tmp_path / "p.mcap", drive)
    assert_drives_equal(drive, read_drive(tmp_path / "p.mcap"))


def test_any_plaza_layout_file(tmp_path):
    path = tmp_path / "circle.mat"
    arrays = synthetic_plaza(path)
    drive = import_plaza(path)
    assert drive.name == "circle"
    assert drive.tags.tag_id.tolist() == [3, 7, 8]
    assert np.all(drive.tags.wall_side == 0) and np.all(drive.tags.group == -1)
    assert list(drive.tags.layouts) == ["dense"]
    # speed and yaw rate of a 1 m/s, 20 m circle, stamped mid-interval
    assert np.allclose(drive.wheel.speed_mps, 1.0, rtol=1e-4)
    assert np.allclose(drive.imu.yaw_rate_radps, 1 / 20)
    assert np.allclose(drive.wheel.t_s, arrays["DR"][:, 0] - 0.1)
    # a heading change written unwrapped (+2pi) is the same turn
    dr = arrays["DR"].copy()
    dr[5, 2] += 2 * np.pi
    synthetic_plaza(path, DR=dr)
    assert np.allclose(import_plaza(path).imu.yaw_rate_radps, 1 / 20)
    speed = np.hypot(drive.truth.v_east_mps, drive.truth.v_north_mps)
    assert np.allclose(speed[1:-1], 1.0, rtol=1e-3)
    # ranges as recorded (1.05 x), sorted by time; true range from GT
    assert np.allclose(drive.rfid.range_m, 1.05 * drive.rfid.true_range_m, rtol=1e-3)
    assert drive.params["range_rows_reordered"] == 2
    east, north, _ = dead_reckon(drive)
    assert np.hypot(east - drive.truth.east_m, north - drive.truth.north_m).max() < 1e-3


@pytest.mark.parametrize("array", ["GT", "DR", "TD", "TL"])
def test_missing_array_is_named(tmp_path, array):
    path = tmp_path / "bad.mat"
    synthetic_plaza(path, drop=array)
    with pytest.raises(FileFormatError, match=rf"bad\.mat: no array '{array}'"):
        import_plaza(path)


@pytest.mark.parametrize(
    "array, value",
    [("GT", np.zeros((5, 3))), ("TL", np.zeros((4, 2))), ("TD", np.zeros((0, 4))), ("DR", np.array([["a", "b", "c"]]))],
)
def test_wrong_shape_is_named(tmp_path, array, value):
    path = tmp_path / "bad.mat"
    synthetic_plaza(path, **{array: value})
    with pytest.raises(FileFormatError, match=rf"bad\.mat: array '{array}' has shape"):
        import_plaza(path)


def test_unknown_beacon_and_bad_times(tmp_path):
    path = tmp_path / "bad.mat"
    arrays = synthetic_plaza(path)
    td = arrays["TD"].copy()
    td[6, 2] = 42
    synthetic_plaza(path, TD=td)
    with pytest.raises(FileFormatError, match="'TD' row 6: beacon 42 is not in 'TL'"):
        import_plaza(path)
    dr = arrays["DR"].copy()
    dr[10, 0] = dr[9, 0]
    synthetic_plaza(path, DR=dr)
    with pytest.raises(FileFormatError, match="'DR' row 10: time"):
        import_plaza(path)
    td = arrays["TD"].copy()
    td[5, 3] = -1.0
    synthetic_plaza(path, TD=td)
    with pytest.raises(DriveError, match=r"bad\.mat: channel 'rfid', row 5: range_m .* \(array 'TD' row 5\)"):
        import_plaza(path)


@pytest.mark.parametrize("content", [None, b"", b"MATLAB 5.0 MAT-file" + bytes(200), b"\x00\x01garbage" * 50])
def test_unreadable_files(tmp_path, content):
    path = tmp_path / "x.mat"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(FileFormatError, match=r"x\.mat: "):
        import_plaza(path)
