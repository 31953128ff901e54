"""`graphpos import csv`: a simulated drive written as CSV logs (ms, deg/s,
km/h, compass degrees, latitude/longitude, a file shared by two channels)
comes back through the example mapping and every estimator recovers the
trajectory; RSUs with a constant sigma; every bad cell or mapping is one
line naming the file, line and column, status 2 and no output file; the
example mappings parse."""

from __future__ import annotations

import csv
import shutil

import numpy as np
import pytest
from recordings import (EXAMPLES, assert_bad_mapping_refused, assert_channels_close, copy_example, expected_import,
                        position_rms_m, simulated_drive, write_csv_logs)
from test_cli_drives import assert_one_line_error, run

from graphpos.drive import Drive
from graphpos.io import read_drive
from graphpos.io.csvlog import import_csv
from graphpos.io.mapping import load_mapping


@pytest.fixture(scope="module")
def sim() -> Drive:
    return simulated_drive()


@pytest.fixture(scope="module")
def logs(sim, tmp_path_factory):
    folder = tmp_path_factory.mktemp("logs")
    return write_csv_logs(sim, folder / "logs"), copy_example("mapping_csv.toml", folder, sim)


def test_csv_logs_come_back_and_every_estimator_recovers_the_trajectory(logs, sim, tmp_path, capsys):
    folder, mapping = logs
    out = tmp_path / "drive.mcap"
    status, stdout, err = run(capsys, "import", "csv", folder, "--mapping", mapping, "-o", out)
    assert status == 0 and err == "", err
    assert f"wrote {out}: logs, 30.0 s, 42 tags" in stdout
    drive = read_drive(out)
    assert_channels_close(drive, expected_import(sim, truth_yaw_rate=False))
    assert drive.params["files"]["compass"] == drive.params["files"]["wheel"] == "vehicle.csv"
    rms = position_rms_m(drive)
    assert max(rms.values()) < 3.0, rms
    assert rms["graph-batch"] < 1.0, rms


@pytest.mark.parametrize("name, source, channels", [
    ("mapping_rosbag.toml", "rosbag", ["imu", "wheel", "compass", "rfid", "gnss", "truth"]),
    ("mapping_csv.toml", "csv", ["imu", "wheel", "compass", "rfid", "gnss", "truth"]),
])
def test_example_mappings_parse(name, source, channels):
    mapping = load_mapping(EXAMPLES / name, source)
    assert list(mapping.channels) == channels
    assert len(mapping.tags) == 4 and mapping.tags.wall_side.tolist() == [1, -1, 1, -1]
    assert mapping.origin is not None and mapping.channels["compass"].convention == "north_cw"
    assert mapping.channels["compass"].factor("yaw") == pytest.approx(np.pi / 180)


def test_rsu_ranges_with_a_constant_sigma_and_a_yaml_map(tmp_path):
    (tmp_path / "rsus.yaml").write_text("- {rsu_id: 4, east_m: 100.0, north_m: 5.0}\n- {rsu_id: 5, east_m: 200.0, north_m: 5.0}\n")
    (tmp_path / "rsu.csv").write_text("t;unit;dist;got\n0.5;rsu-b;120.5;0.6\n0.0;rsu-a;100.25;0.1\n")
    (tmp_path / "m.toml").write_text('[drive]\nrsus = "rsus.yaml"\n[rsu]\nfile = "rsu.csv"\ndelimiter = ";"\ntime = "t"\n'
                                     'arrival = "got"\nids = { "rsu-a" = 4, "rsu-b" = 5 }\n'
                                     'fields = { rsu_id = "unit", range = "dist", sigma = 50 }\nunits = { sigma = "cm" }\n')
    drive = import_csv(tmp_path, tmp_path / "m.toml")
    rsu = drive.rsu
    assert rsu.rsu_id.tolist() == [4, 5] and rsu.range_m.tolist() == [100.25, 120.5]
    assert rsu.sigma_m.tolist() == [0.5, 0.5] and rsu.arrival_s.tolist() == [0.1, 0.6]
    assert np.isnan(rsu.east_m).all()
    assert drive.params["import_notes"] == [f"{tmp_path / 'rsu.csv'}: 2 rows were out of time order; sorted"]


def test_camera_ranges_keep_their_bearing_for_the_range_calibration(tmp_path):
    """A camera's ranges with the landmark's bearing (degrees in the log): the drive keeps it as ``bearing_rad``,
    which the sensor profile's bearing term reads, wrapped into (-180, 180] degrees (340 is -20); a reading without one
    (an empty cell) is NaN, not refused."""
    (tmp_path / "tags.csv").write_text("tag_id,east_m,north_m\n6,1.0,2.0\n7,3.0,-1.0\n")
    (tmp_path / "cam.csv").write_text("t,id,r,b\n0.0,6,2.5,340.0\n0.2,7,3.1,\n0.4,6,2.4,12.5\n")
    (tmp_path / "m.toml").write_text('[drive]\ntags = "tags.csv"\n[rfid]\nfile = "cam.csv"\ntime = "t"\n'
                                     'fields = { tag_id = "id", range = "r", bearing = "b" }\nunits = { bearing = "deg" }\n')
    rfid = import_csv(tmp_path, tmp_path / "m.toml").rfid
    assert rfid.range_m.tolist() == [2.5, 3.1, 2.4]
    np.testing.assert_allclose(rfid.bearing_rad, np.radians([-20.0, np.nan, 12.5]))


def _edit(path, line, column, value):
    """Set one cell of a CSV file (``line``: 1-based, the header is line 1)."""
    with path.open(newline="") as stream:
        rows = list(csv.reader(stream))
    rows[line - 1][rows[0].index(column)] = value
    with path.open("w", newline="") as stream:
        csv.writer(stream).writerows(rows)


#: file, line, column, new cell -> what the one error line says
BAD_CELLS = {
    "not a number": ("imu.csv", 5, "gyro_z", "abc", "imu.csv, line 5, column 'gyro_z' (yaw_rate): 'abc' is not a number"),
    "not finite": ("imu.csv", 7, "acc_x", "inf", "imu.csv, line 7, column 'acc_x' (accel_x): 'inf' is not a finite number"),
    "fraction of an id": ("ranges.csv", 3, "tag", "3.5", "ranges.csv, line 3, column 'tag' (tag_id): '3.5' is not a whole number"),
    "unknown tag": ("ranges.csv", 4, "tag", "999", "ranges.csv, line 4: tag id 999 is not in the tag map"),
    "implausible": ("vehicle.csv", 2, "speed", "1000", "vehicle.csv, line 2: speed_mps = 277.778 is outside the plausible range"),
    "arrival before time": ("ranges.csv", 2, "received_ms", "0", "ranges.csv, line 2: arrival_s is before t_s"),
    "bad time": ("reference.csv", 6, "time_ms", "12:00", "reference.csv, line 6, column 'time_ms' (time): '12:00' is not a number"),
}


@pytest.mark.parametrize("case", BAD_CELLS)
def test_bad_cell_is_one_line_naming_file_line_and_column(case, logs, tmp_path, capsys):
    folder, mapping = logs
    name, line, column, value, fragment = BAD_CELLS[case]
    copy = shutil.copytree(folder, tmp_path / "logs")
    _edit(copy / name, line, column, value)
    out = tmp_path / "out.mcap"
    assert_one_line_error(*run(capsys, "import", "csv", copy, "--mapping", mapping, "-o", out), fragment)
    assert not out.exists()


BAD_MAPPINGS = {
    "missing column": ('yaw_rate = "gyro_z"', 'yaw_rate = "gyro"', ["[imu]: column 'gyro' (yaw_rate) is not in", "imu.csv (its columns: time_ms, gyro_z"]),
    "missing file": ('file = "gnss.csv"', 'file = "nope.csv"', ["nope.csv: no such file"]),
    "bad unit": ('speed = "km/h"', 'speed = "furlong/s"', ["[wheel] units.speed: unknown speed unit 'furlong/s' (known: m/s, km/h, mph)"]),
    "no time column": ('file = "imu.csv"\ntime = "time_ms"', 'file = "imu.csv"', ["[imu]: missing key 'time'"]),
    "a quaternion": ('yaw = "heading"', 'orientation = "heading"', ["[compass] fields.orientation: a CSV column holds one number; give yaw"]),
    "half a pair": ('v_east = "v_east", ', "", ["[truth]: v_east and v_north go together; 'v_east' is not given"]),
    "two alternatives": ('sigma = "accuracy"', 'sigma = "accuracy", east = "lat", north = "lon"', ["[gnss]: give one of lat+lon or east+north, not several"]),
    "nothing read": ('fields = { speed = "speed" }', "", ["[wheel]: no field gives speed"]),
    "unit of no input": ('units = { time = "ms", yaw_rate = "deg/s" }', 'units = { time = "ms", yaw = "deg" }',
                         ["[imu] units: 'yaw' is not an input of [imu] (inputs with units: yaw_rate, accel_x, accel_y, time)"]),
    "unit of an input not read": (', accel_x = "acc_x", accel_y = "acc_y" }\nunits = { time = "ms", yaw_rate = "deg/s" }',
                                  ' }\nunits = { time = "ms", yaw_rate = "deg/s", accel_x = "g" }',
                                  ["[imu] units: 'accel_x' is not read (no field gives it)"]),
    "a unit for an id": ('units = { time = "ms", arrival = "ms" }', 'units = { time = "ms", tag_id = "m" }',
                         ["[rfid] units: 'tag_id' takes no unit"]),
    "no tag map": ('tags = "tags.csv"', "", ["[rfid]: readings need a map: set [drive] tags"]),
    "a rosbag key": ('file = "imu.csv"', 'topic = "/imu"', ["[imu]: unknown key 'topic'"]),
    "a non-finite constant": ('sigma = "accuracy"', "sigma = nan", ["[gnss] fields.sigma: expected a finite number, got nan"]),
}


@pytest.mark.parametrize("case", BAD_MAPPINGS)
def test_bad_mapping_is_one_line_and_writes_nothing(case, logs, sim, tmp_path, capsys):
    assert_bad_mapping_refused(capsys, "csv", logs[0], tmp_path, sim, *BAD_MAPPINGS[case])


def test_short_row_and_missing_folder(logs, tmp_path, capsys):
    folder, mapping = logs
    copy = shutil.copytree(folder, tmp_path / "logs")
    with (copy / "gnss.csv").open("a") as stream:
        stream.write("1700000001000.0,29.5\n")
    assert_one_line_error(*run(capsys, "import", "csv", copy, "--mapping", mapping, "-o", tmp_path / "o.mcap"),
                          "gnss.csv, line 28: 2 cells, the header has 4")
    assert_one_line_error(*run(capsys, "import", "csv", tmp_path / "nope", "--mapping", mapping, "-o", tmp_path / "o.mcap"),
                          "nope: no such folder")
    assert not (tmp_path / "o.mcap").exists()
