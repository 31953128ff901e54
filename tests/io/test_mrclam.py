"""MRCLAM importer: the columns of small synthetic MRCLAM-format folders,
clear one-line errors for bad ones, and the conventions checked against the
real Dataset 6 (skipped when ../shared/data/mrclam is absent)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from drive_samples import assert_drives_equal

from graphpos.cli import main
from graphpos.errors import DriveError, FileFormatError
from graphpos.io import read_drive, write_drive
from graphpos.io.mrclam import MRCLAM_ORIGIN, import_mrclam

MRCLAM = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "mrclam"
DATASET6 = MRCLAM / "MRCLAM_Dataset6"

HEADER = "# UTIAS Multi-Robot Cooperative Localization and Mapping Dataset\n# synthetic\n# {what}\n# {columns}\n"
T0 = 1248444175.0  # Unix seconds, as in the real files
ROBOT_BARCODES = {1: 5, 2: 14, 3: 41, 4: 32, 5: 23}
LANDMARK_BARCODES = {6: 63, 7: 81, 8: 7}
LANDMARKS = {6: (2.0, 0.0), 7: (0.0, 3.0), 8: (-2.5, -1.0)}


def _write(path: Path, what: str, columns: str, rows: list[list[float]] | np.ndarray, fmt: str = "{:.6f}") -> None:
    body = "".join(" \t".join(fmt.format(v) for v in row) + "\n" for row in rows)
    path.write_text(HEADER.format(what=what, columns=columns) + body)


def synthetic_mrclam(folder: Path, robot: int = 1) -> dict[str, np.ndarray]:
    """Write an MRCLAM-format folder: robot ``robot`` on a 1 m circle at
    0.1 m/s for 60 s (counter-clockwise from (1, 0), heading wrapped to
    [-pi, pi]); odometry at 50 Hz with three repeated stamps (the last of
    each pair is the true one); exact ranges at 2 Hz to three landmarks,
    plus two sightings of robot 2 and one of an unknown barcode; truth at
    60 Hz ending 5 s before the last sighting. Returns the rows written."""
    folder.mkdir(parents=True, exist_ok=True)
    speed, radius = 0.1, 1.0
    omega = speed / radius
    barcodes = [[s, b] for s, b in {**ROBOT_BARCODES, **LANDMARK_BARCODES}.items()]
    _write(folder / "Barcodes.dat", "Barcode Data Format:", "Subject #    Barcode #", barcodes, "{:.0f}")
    landmarks = [[s, x, y, 1e-4, 2e-4] for s, (x, y) in LANDMARKS.items()]
    _write(folder / "Landmark_Groundtruth.dat", "Landmark Groundtruth", "Subject # x [m] y [m] x std-dev [m] y std-dev [m]", landmarks)

    t_gt = T0 + np.arange(0, 55.0, 1 / 60)
    phi = omega * (t_gt - T0)
    theta = np.angle(np.exp(1j * (phi + np.pi / 2)))
    gt = np.column_stack([t_gt, radius * np.cos(phi), radius * np.sin(phi), theta])
    _write(folder / f"Robot{robot}_Groundtruth.dat", "Robot Groundtruth", "Time [s] x [m] y [m] orientation [rad]", gt)

    t_odo = T0 + 0.5 + np.arange(0, 59.0, 0.02)
    odo = np.column_stack([t_odo, np.full(t_odo.size, speed), np.full(t_odo.size, omega)])
    rows = odo.tolist()
    for i in (100, 200, 300):  # a stale row at the same stamp before the true one
        rows.insert(i + (i // 100 - 1), [t_odo[i], 0.0, 0.0])
    _write(folder / f"Robot{robot}_Odometry.dat", "Odometry", "Time [s] forward velocity [m/s] angular velocity [rad/s]", rows)

    meas = []
    for k, t in enumerate(T0 + 1.0 + np.arange(0, 59.0, 0.5)):
        subject = (6, 7, 8)[k % 3]
        p = omega * (t - T0)
        x, y = radius * np.cos(p), radius * np.sin(p)
        lx, ly = LANDMARKS[subject]
        meas.append([t, LANDMARK_BARCODES[subject], np.hypot(lx - x, ly - y), 0.1])
    meas.insert(10, [meas[9][0], ROBOT_BARCODES[2], 1.5, 0.2])
    meas.insert(20, [meas[19][0], ROBOT_BARCODES[2], 1.6, 0.2])
    meas.insert(30, [meas[29][0], 99, 2.0, 0.0])
    _write(folder / f"Robot{robot}_Measurement.dat", "Measurement", "Time [s] Subject # range [m] bearing [rad]", meas)
    return {"gt": gt, "odo": np.array(rows), "meas": np.array(meas)}


def replace_line(path: Path, line: int, text: str) -> None:
    """Replace line ``line`` (1-based) of a text file."""
    lines = path.read_text().splitlines()
    lines[line - 1] = text
    path.write_text("\n".join(lines) + "\n")


def run(capsys, *argv):
    status = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return status, out, err


# ---------------------------------------------------------------------------
# Synthetic folders
# ---------------------------------------------------------------------------


def test_synthetic_columns(tmp_path):
    rows = synthetic_mrclam(tmp_path / "MRCLAM_Test")
    drive = import_mrclam(tmp_path / "MRCLAM_Test", 1)
    assert drive.name == "MRCLAM_Test-robot1"
    assert set(drive.channels) == {"imu", "wheel", "rfid", "truth"}
    assert drive.origin == MRCLAM_ORIGIN
    tags = drive.tags
    assert tags.tag_id.tolist() == [6, 7, 8]
    assert np.allclose(tags.positions(np.array([6, 7, 8])), list(LANDMARKS.values()))
    assert np.all(tags.wall_side == 0) and np.all(tags.group == -1) and list(tags.layouts) == ["dense"]
    # odometry: one row per distinct stamp, the file's own (Unix) clock
    assert np.array_equal(drive.wheel.t_s, np.unique(rows["odo"][:, 0]))
    assert drive.wheel.t_s[0] > 1e9
    assert np.all(drive.wheel.speed_mps == 0.1) and np.all(drive.imu.yaw_rate_radps == 0.1)
    assert np.array_equal(drive.imu.t_s, drive.wheel.t_s)
    assert np.all(np.isnan(drive.imu.accel_x_mps2)) and np.all(np.isnan(drive.imu.accel_y_mps2))
    # truth: unwrapped yaw, velocity of a 0.1 m/s circle
    truth = drive.truth
    assert np.all(np.abs(np.diff(truth.yaw_rad)) < 0.01)
    assert truth.yaw_rad[-1] - truth.yaw_rad[0] == pytest.approx(0.1 * (truth.t_s[-1] - truth.t_s[0]), abs=1e-4)
    assert np.allclose(np.hypot(truth.v_east_mps, truth.v_north_mps), 0.1, rtol=1e-3)
    assert np.all(np.isnan(truth.yaw_rate_radps)) and np.all(np.isnan(truth.accel_x_mps2))
    # rfid: landmark sightings only, ranges as recorded, true ranges from the truth
    rfid = drive.rfid
    assert len(rfid) == 118 and set(rfid.tag_id.tolist()) == {6, 7, 8}
    assert np.all(np.isnan(rfid.rss))
    assert np.all(rfid.bearing_rad == 0.1)  # the camera's bearing, kept for the profile's bearing-dependent range term
    inside = rfid.t_s <= truth.t_s[-1]
    assert np.allclose(rfid.range_m[inside], rfid.true_range_m[inside], atol=1e-5)
    assert np.all(np.isnan(rfid.true_range_m[~inside])) and (~inside).sum() == 10


def test_sightings_of_robots_and_unknown_barcodes_are_dropped_and_counted(tmp_path):
    synthetic_mrclam(tmp_path)
    params = import_mrclam(tmp_path, 1).params
    assert params["source"] == "mrclam" and params["dataset"] == tmp_path.name and params["robot"] == 1
    assert params["sightings_of_robots_dropped"] == 2
    assert params["sightings_of_unknown_barcodes_dropped"] == 1
    assert params["sightings_of_unsurveyed_subjects_dropped"] == 0
    json.dumps(params)  # provenance is JSON
    # a subject with a barcode but no surveyed position is no landmark either
    with (tmp_path / "Barcodes.dat").open("a") as f:
        f.write(" 9 \t 70\n")
    replace_line(tmp_path / "Robot1_Measurement.dat", 8, f"{T0 + 2.5:.3f} 70 2.0 0.1")
    drive = import_mrclam(tmp_path, 1)
    assert drive.params["sightings_of_unsurveyed_subjects_dropped"] == 1
    assert len(drive.rfid) == 117 and len(drive.tags) == 3


def test_repeated_stamps_keep_the_last_row(tmp_path):
    rows = synthetic_mrclam(tmp_path)
    drive = import_mrclam(tmp_path, 1)
    assert drive.params["odometry_repeated_stamps_dropped"] == 3
    assert len(drive.wheel) == rows["odo"].shape[0] - 3
    # the stale zero rows came first at their stamps: none survives
    assert np.all(drive.wheel.speed_mps > 0)
    # the other way round, the last (zero) row of each stamp is kept
    path = tmp_path / "Robot1_Odometry.dat"
    lines = path.read_text().splitlines()
    stale = 5 + 100  # file line of the stale row at stamp 100; its true twin follows
    lines[stale - 1], lines[stale] = lines[stale], lines[stale - 1]
    path.write_text("\n".join(lines) + "\n")
    drive = import_mrclam(tmp_path, 1)
    assert np.count_nonzero(drive.wheel.speed_mps == 0) == 1
    # a repeated truth stamp: the last row of the stamp is kept too
    gt = tmp_path / "Robot1_Groundtruth.dat"
    lines = gt.read_text().splitlines()
    cells = lines[10].split()
    lines.insert(11, " ".join([cells[0], "1.05", cells[2], cells[3]]))
    gt.write_text("\n".join(lines) + "\n")
    drive = import_mrclam(tmp_path, 1)
    assert drive.params["truth_repeated_stamps_dropped"] == 1
    assert drive.truth.east_m[6] == 1.05


def test_rows_out_of_time_order_are_sorted(tmp_path):
    synthetic_mrclam(tmp_path)
    path = tmp_path / "Robot1_Measurement.dat"
    lines = path.read_text().splitlines()
    lines[20], lines[24] = lines[24], lines[20]
    path.write_text("\n".join(lines) + "\n")
    drive = import_mrclam(tmp_path, 1)
    assert np.all(np.diff(drive.rfid.t_s) >= 0)
    assert drive.params["rows_reordered"]["measurement"] > 0
    assert drive.params["rows_reordered"]["odometry"] == 0


def test_unix_times_round_trip_through_mcap(tmp_path):
    synthetic_mrclam(tmp_path / "d")
    drive = import_mrclam(tmp_path / "d", 1)
    write_drive(tmp_path / "d.mcap", drive)
    assert_drives_equal(drive, read_drive(tmp_path / "d.mcap"))


def test_other_robot_numbers(tmp_path):
    synthetic_mrclam(tmp_path, robot=4)
    assert import_mrclam(tmp_path, 4).name.endswith("-robot4")
    with pytest.raises(FileFormatError, match=r"Robot1_Odometry\.dat: no such file"):
        import_mrclam(tmp_path, 1)
    for robot in (0, 6, -1, 2.5, "3"):
        with pytest.raises(FileFormatError, match=rf"no robot {robot!r}; MRCLAM robots are 1-5 \(this folder has files of robot\(s\) 4\)"):
            import_mrclam(tmp_path, robot)


@pytest.mark.parametrize(
    "file, line, text, expect",
    [
        ("Robot1_Odometry.dat", 7, "1248444176.0 0.1", r"Robot1_Odometry\.dat: line 7: 2 columns, expected 3 \(t_s v_mps omega_radps\)"),
        ("Robot1_Measurement.dat", 5, "1248444176.0 63 2.0 0.1 9", r"Robot1_Measurement\.dat: line 5: 5 columns, expected 4"),
        ("Robot1_Groundtruth.dat", 9, "1248444176.0 0.5 abc 0.1", r"Robot1_Groundtruth\.dat: line 9, column 3 \(y_m\): 'abc' is not a number"),
        ("Robot1_Odometry.dat", 8, "1248444176.0 nan 0.1", r"Robot1_Odometry\.dat: line 8, column 2 \(v_mps\): nan is not a finite number"),
        ("Robot1_Measurement.dat", 6, "1248444176.0 63 inf 0.1", r"Robot1_Measurement\.dat: line 6, column 3 \(range_m\): inf is not a finite number"),
        ("Robot1_Measurement.dat", 6, "1248444176.0 63.5 2.0 0.1", r"Robot1_Measurement\.dat: line 6, column 2 \(barcode\): 63.5 is not a whole number"),
        ("Barcodes.dat", 7, "3 14", r"Barcodes\.dat: line 7: barcode 14 is listed twice"),
        ("Landmark_Groundtruth.dat", 5, "3 0.0 0.0 0.0 0.0", r"Landmark_Groundtruth\.dat: line 5: subject 3 is a robot"),
        ("Landmark_Groundtruth.dat", 6, "6 0.0 0.0 0.0 0.0", r"Landmark_Groundtruth\.dat: line 6: landmark 6 is listed twice"),
    ],
)
def test_bad_cells_name_file_line_and_column(tmp_path, file, line, text, expect):
    synthetic_mrclam(tmp_path)
    replace_line(tmp_path / file, line, text)
    with pytest.raises(FileFormatError, match=expect):
        import_mrclam(tmp_path, 1)


def test_values_the_drive_rejects_name_the_file_line(tmp_path):
    synthetic_mrclam(tmp_path)
    replace_line(tmp_path / "Robot1_Measurement.dat", 7, f"{T0 + 2.0:.3f} 63 -1.0 0.1")
    with pytest.raises(DriveError, match=r"Robot1_Measurement\.dat: channel 'rfid', row 2: range_m = -1 .* \(line 7\)"):
        import_mrclam(tmp_path, 1)
    synthetic_mrclam(tmp_path)
    replace_line(tmp_path / "Robot1_Odometry.dat", 10, f"{T0 + 0.6:.3f} 0.1 25.0")
    with pytest.raises(DriveError, match=r"Robot1_Odometry\.dat: channel 'imu', row 5: yaw_rate_radps = 25 .* \(line 10\)"):
        import_mrclam(tmp_path, 1)


@pytest.mark.parametrize("content", [b"", b"\xff\xfe\x00garbage" * 20, b"# only a header\n", b"PK\x03\x04" + bytes(100)])
def test_unreadable_files(tmp_path, content):
    synthetic_mrclam(tmp_path)
    (tmp_path / "Robot1_Groundtruth.dat").write_bytes(content)
    with pytest.raises(FileFormatError, match=r"Robot1_Groundtruth\.dat: "):
        import_mrclam(tmp_path, 1)


def test_import_mrclam_then_info(tmp_path, capsys):
    synthetic_mrclam(tmp_path / "MRCLAM_Test", robot=2)
    out_path = tmp_path / "r2.mcap"
    status, out, _ = run(capsys, "import", "mrclam", tmp_path / "MRCLAM_Test", "--robot", 2, "-o", out_path)
    assert status == 0
    assert len(out.strip().splitlines()) == 1
    assert out.startswith(f"wrote {out_path}: MRCLAM_Test-robot2, ") and "3 landmarks" in out
    assert "dropped 2 robot sightings, 1 unknown, 3 repeated odometry stamps" in out
    info = json.loads(run(capsys, "info", out_path, "--json")[1])
    assert set(info["channels"]) == {"imu", "wheel", "rfid", "truth"}
    assert info["channels"]["rfid"]["count"] == 118
    assert info["tags"] == {"count": 3, "layouts": {"dense": 3}}
    assert info["params"]["robot"] == 2 and info["params"]["sightings_of_robots_dropped"] == 2
    assert info["origin"]["lat_deg"] == pytest.approx(43.7823)
    status, _, _ = run(capsys, "import", "mrclam", tmp_path / "MRCLAM_Test", "--robot", 2, "-o", out_path, "--origin", "51.5,-0.12")
    assert status == 0
    assert json.loads(run(capsys, "info", out_path, "--json")[1])["origin"]["lat_deg"] == 51.5


@pytest.mark.parametrize(
    "case", ["no-folder", "not-a-folder", "missing-file", "columns", "not-a-number", "not-finite", "robot-7", "robot-0",
             "negative-range", "no-output-folder"],
)
def test_import_mrclam_bad_input(tmp_path, capsys, case):
    data = tmp_path / "MRCLAM_Test"
    synthetic_mrclam(data)
    output = tmp_path / "out.mcap"
    robot = 1
    if case == "no-folder":
        data = tmp_path / "nowhere"
        expect = f"{data}: no such folder"
    elif case == "not-a-folder":
        data = data / "Barcodes.dat"
        expect = "is a file, not an MRCLAM dataset folder"
    elif case == "missing-file":
        (data / "Robot1_Measurement.dat").unlink()
        expect = "Robot1_Measurement.dat: no such file"
    elif case == "columns":
        replace_line(data / "Landmark_Groundtruth.dat", 5, "6 2.0 0.0")
        expect = "Landmark_Groundtruth.dat: line 5: 3 columns, expected 5"
    elif case == "not-a-number":
        replace_line(data / "Robot1_Odometry.dat", 12, "1248444175.72 0.1 0.1x")
        expect = "Robot1_Odometry.dat: line 12, column 3 (omega_radps): '0.1x' is not a number"
    elif case == "not-finite":
        replace_line(data / "Robot1_Groundtruth.dat", 30, "1248444175.5 inf 0.0 0.0")
        expect = "Robot1_Groundtruth.dat: line 30, column 2 (x_m): inf is not a finite number"
    elif case in ("robot-7", "robot-0"):
        robot = int(case[-1])
        expect = f"no robot {robot}; MRCLAM robots are 1-5"
    elif case == "negative-range":
        replace_line(data / "Robot1_Measurement.dat", 5, f"{T0 + 1.0:.3f} 63 -0.5 0.1")
        expect = "Robot1_Measurement.dat: channel 'rfid', row 0: range_m = -0.5"
    elif case == "no-output-folder":
        output = tmp_path / "nowhere" / "out.mcap"
        expect = "does not exist"
    before = sorted(p.name for p in tmp_path.iterdir())
    status, out, err = run(capsys, "import", "mrclam", data, "--robot", robot, "-o", output)
    assert status == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith("graphpos import mrclam: error:") and expect in lines[0], (expect, lines[0])
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_import_mrclam_bad_options(capsys):
    for argv in (["import", "mrclam", "d", "-o", "x.mcap"], ["import", "mrclam", "d", "--robot", "one", "-o", "x.mcap"],
                 ["import", "mrclam", "d", "--robot", "1"], ["import", "mrclam", "d", "--robot", "1", "-o", "x.mcap", "--origin", "95,0"]):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == 2
        assert len(capsys.readouterr().err.strip().splitlines()) == 1


# ---------------------------------------------------------------------------
# The real Dataset 6
# ---------------------------------------------------------------------------

#: Rows per channel of Dataset 6 (odometry rows less repeated stamps) and the sightings dropped.
DATASET6_ROWS = {
    1: {"wheel": 61785, "rfid": 1534, "truth": 49241, "robots": 407, "unknown": 1, "repeats": 0},
    2: {"wheel": 65004, "rfid": 3239, "truth": 59705, "robots": 792, "unknown": 0, "repeats": 1},
    3: {"wheel": 61150, "rfid": 4348, "truth": 56977, "robots": 1277, "unknown": 2, "repeats": 8},
    4: {"wheel": 52906, "rfid": 2023, "truth": 61714, "robots": 373, "unknown": 3, "repeats": 10},
    5: {"wheel": 60563, "rfid": 4239, "truth": 57467, "robots": 1139, "unknown": 0, "repeats": 4},
}


@pytest.fixture
def dataset6() -> Path:
    if not DATASET6.is_dir():
        pytest.skip(f"MRCLAM Dataset 6 not found at {DATASET6}")
    return DATASET6


def wheel_and_truth_distance_m(drive) -> tuple[float, float]:
    """Odometry speed integrated (each row held until the next) and the truth
    path length (resampled at 2 Hz: at 60 Hz, sub-millimetre wiggles add 4-10 %),
    over the span both cover."""
    truth, wheel = drive.truth, drive.wheel
    t0, t1 = max(truth.t_s[0], wheel.t_s[0]), min(truth.t_s[-1], wheel.t_s[-1])
    edges = np.clip(np.r_[wheel.t_s, t1], t0, t1)
    wheel_m = float(np.sum(np.abs(wheel.speed_mps) * np.diff(edges)))
    t = np.arange(t0, t1, 0.5)
    east, north = np.interp(t, truth.t_s, truth.east_m), np.interp(t, truth.t_s, truth.north_m)
    return wheel_m, float(np.sum(np.hypot(np.diff(east), np.diff(north))))


@pytest.mark.parametrize("robot", [1, 2, 3, 4, 5])
def test_dataset6_rows_ranges_and_odometry(dataset6, robot):
    drive = import_mrclam(dataset6, robot)
    expect = DATASET6_ROWS[robot]
    assert drive.name == f"MRCLAM_Dataset6-robot{robot}"
    assert drive.duration_s == pytest.approx(900, abs=1)
    assert len(drive.tags) == 15 and drive.tags.tag_id.tolist() == list(range(6, 21))
    assert len(drive.wheel) == len(drive.imu) == expect["wheel"]
    assert len(drive.rfid) == expect["rfid"] and len(drive.truth) == expect["truth"]
    params = drive.params
    assert params["sightings_of_robots_dropped"] == expect["robots"]
    assert params["sightings_of_unknown_barcodes_dropped"] == expect["unknown"]
    assert params["odometry_repeated_stamps_dropped"] == expect["repeats"]
    assert drive.start_s == pytest.approx(1248444175.1, abs=0.1)  # Unix seconds, kept
    # ranges agree with the truth: a few cm of bias, 0.08-0.18 m robust sigma
    error = drive.rfid.range_m - drive.rfid.true_range_m
    assert np.isfinite(error).all()
    assert abs(np.median(error)) < 0.1
    assert np.median(np.abs(error)) < 0.15
    assert 1.4826 * np.median(np.abs(error - np.median(error))) < 0.25
    # commanded speed integrated: 4-10 % longer than the truth path
    wheel_m, truth_m = wheel_and_truth_distance_m(drive)
    assert 35 < truth_m < 60
    assert wheel_m / truth_m == pytest.approx(1.0, abs=0.15)


@pytest.mark.parametrize("robot", [1, 2, 3, 4, 5])
def test_dataset6_theta_is_yaw_from_east_ccw(dataset6, robot):
    truth = import_mrclam(dataset6, robot).truth
    # direction of motion over 0.5 s steps (60 Hz differences are mostly wiggle)
    t = np.arange(truth.t_s[0], truth.t_s[-1], 0.5)
    east, north = np.interp(t, truth.t_s, truth.east_m), np.interp(t, truth.t_s, truth.north_m)
    moving = np.hypot(np.diff(east), np.diff(north)) > 0.02
    direction = np.arctan2(np.diff(north), np.diff(east))
    yaw = np.interp(t[:-1] + 0.25, truth.t_s, truth.yaw_rad)
    diff = np.angle(np.exp(1j * (direction - yaw)))[moving]
    assert moving.sum() > 1000
    assert abs(np.median(diff)) < 0.05
    assert np.percentile(np.abs(diff), 90) < 0.15
    assert np.all(np.abs(np.diff(truth.yaw_rad)) < np.pi)  # unwrapped


def test_dataset6_turn_rate_scale(dataset6):
    """Heading change over 5 s windows: truth = s x odometry + c with s within 10 % of 1."""
    drive = import_mrclam(dataset6, 3)
    truth, imu = drive.truth, drive.imu
    turned = np.r_[0.0, np.cumsum(imu.yaw_rate_radps[:-1] * np.diff(imu.t_s))]
    edges = np.arange(max(truth.t_s[0], imu.t_s[0]), min(truth.t_s[-1], imu.t_s[-1]), 5.0)
    scale, _ = np.polyfit(np.diff(np.interp(edges, imu.t_s, turned)), np.diff(np.interp(edges, truth.t_s, truth.yaw_rad)), 1)
    assert scale == pytest.approx(1.0, abs=0.1)


@pytest.mark.parametrize("robot", [1, 4])
def test_dataset6_held_speeds_are_warned_of(dataset6, robot):
    """MRCLAM logs each commanded speed over several 100 Hz rows: the drive check says so, with the rate to give."""
    from graphpos.io.checks import drive_checks, new_reading_rate_hz

    drive = import_mrclam(dataset6, robot)
    rows_hz, new_hz = new_reading_rate_hz(drive.wheel.t_s, drive.wheel.speed_mps)
    assert rows_hz == pytest.approx(100.0) and 5.0 < new_hz < 25.0
    message = {c["name"]: c["message"] for c in drive_checks(drive)}["held-readings"]
    assert message is not None and f"wheel_rate_hz={new_hz:.3g}" in message and "imu" not in message
