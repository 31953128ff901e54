"""What a user audit found reading user drives (CSV logs through a mapping), one test each.

- A compass or a bearing in degrees with the mapping's unit left out (so
  taken as radians) is refused in one line naming the file, line and
  column and the unit to set, not wrapped.
- Times in milliseconds taken as seconds leave the IMU and wheel at 0.1
  rows/s: the drive check ``odometry-rate`` says so (``info``, ``run``);
  no simulated or real drive (Plaza1, MRCLAM Dataset 6) trips it.
- Rows of one sensor at one time with other values are an import note and
  the drive check ``conflicting-rows``; exact repeats are dropped, noted.
- An empty or NaN gyro cell is a gap in that sensor (README: non-finite
  samples are gaps), its row dropped and counted; ``inf`` is still refused.
- ``info``'s channel table keeps its columns apart with Unix-epoch times.
- A wheel speed that never changes (a vehicle standing still) gets no
  ``held-readings`` warning, and no rate near 0 is ever advised.
"""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path
from typing import Callable

import numpy as np
import pytest
from drive_samples import every_channel_drive
from recordings import copy_example, simulated_drive, write_csv_logs
from test_cli_drives import assert_one_line_error, run

from graphpos.drive import Drive
from graphpos.errors import FileFormatError
from graphpos.io import read_drive, write_drive
from graphpos.io.checks import drive_checks, repeated_rows
from graphpos.io.csvlog import import_csv
from graphpos.sim import simulate

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"
PLAZA1 = DATA / "plaza" / "Plaza1.mat"
DATASET6 = DATA / "mrclam" / "MRCLAM_Dataset6"


@pytest.fixture(scope="module")
def sim() -> Drive:
    return simulated_drive()


@pytest.fixture(scope="module")
def logs(sim, tmp_path_factory) -> Path:
    """The simulated drive as CSV logs with ``mapping_csv.toml`` beside them."""
    folder = write_csv_logs(sim, tmp_path_factory.mktemp("audit") / "logs")
    copy_example("mapping_csv.toml", folder, sim)
    return folder


def _copy(logs: Path, tmp_path: Path) -> Path:
    return shutil.copytree(logs, tmp_path / "logs")


def _rows(path: Path) -> list[list[str]]:
    with path.open(newline="") as stream:
        return list(csv.reader(stream))


def _write_rows(path: Path, rows: list[list[str]]) -> None:
    with path.open("w", newline="") as stream:
        csv.writer(stream).writerows(rows)


def _edit_mapping(folder: Path, old: str, new: str) -> Path:
    mapping = folder / "mapping_csv.toml"
    text = mapping.read_text()
    assert old in text
    mapping.write_text(text.replace(old, new, 1))
    return mapping


def _retimed(drive: Drive, new_t_s: Callable[[np.ndarray], np.ndarray]) -> Drive:
    """The drive with every ``t_s`` and ``arrival_s`` mapped through ``new_t_s``, without its windows."""
    return drive.replace(channels={k: ch.replace(**{c: new_t_s(ch.columns[c]) for c in ("t_s", "arrival_s") if c in ch.columns})
                                   for k, ch in drive.channels.items()}, windows=())


def _verdicts(drive: Drive) -> dict[str, str | None]:
    return {c["name"]: c["message"] for c in drive_checks(drive)}


# -- 1. angles in degrees read as radians -------------------------------------------------------------------------
def test_a_compass_in_degrees_without_its_unit_is_refused_naming_the_column_and_the_unit(logs, tmp_path, capsys):
    folder = _copy(logs, tmp_path)
    mapping = _edit_mapping(folder, 'units = { time = "ms", yaw = "deg" }', 'units = { time = "ms" }')
    out = tmp_path / "out.mcap"
    status, stdout, err = run(capsys, "import", "csv", folder, "--mapping", mapping, "-o", out)
    assert_one_line_error(status, stdout, err, "vehicle.csv, line ", "column 'heading' (yaw)", "beyond ±12.57 rad",
                          'set units = { yaw = "deg" } in', "[compass]")
    assert not out.exists()


def test_a_bearing_in_degrees_without_its_unit_is_refused(tmp_path):
    """A yaw rate in deg/s read as rad/s needs no such check: beyond 10 rad/s the drive refuses it anyway."""
    (tmp_path / "tags.csv").write_text("tag_id,east_m,north_m\n6,1.0,2.0\n")
    (tmp_path / "cam.csv").write_text("t,id,r,b\n0.0,6,2.5,340.0\n")
    (tmp_path / "cam.toml").write_text('[drive]\ntags = "tags.csv"\n[rfid]\nfile = "cam.csv"\ntime = "t"\n'
                                       'fields = { tag_id = "id", range = "r", bearing = "b" }\n')
    with pytest.raises(FileFormatError, match=r"cam\.csv, line 2, column 'b' \(bearing\): 340 is beyond .*"
                                              r'set units = \{ bearing = "deg" \}'):
        import_csv(tmp_path, tmp_path / "cam.toml")


def test_a_compass_in_radians_up_to_a_turn_still_reads(tmp_path):
    (tmp_path / "c.csv").write_text("t,h\n0.0,0.1\n0.1,3.2\n0.2,6.25\n")
    (tmp_path / "c.toml").write_text('[compass]\nfile = "c.csv"\ntime = "t"\nfields = { yaw = "h" }\nconvention = "north_cw"\n')
    yaw = import_csv(tmp_path, tmp_path / "c.toml").compass.yaw_rad
    np.testing.assert_allclose(np.exp(1j * yaw), np.exp(1j * (np.pi / 2 - np.array([0.1, 3.2, 6.25]))))


# -- 2. times in the wrong unit -------------------------------------------------------------------------------------
def _odometry_in_ms(folder: Path, seconds: float = 30.0) -> Path:
    """IMU and wheel at 100 Hz, times in milliseconds, and a mapping that leaves the time unit out."""
    folder.mkdir()
    t_ms = np.arange(0.0, seconds * 1000 + 1, 10.0)
    _write_rows(folder / "imu.csv", [["time_ms", "gyro_z"], *([repr(t), "0.01"] for t in t_ms.tolist())])
    _write_rows(folder / "wheel.csv", [["time_ms", "speed"], *([repr(t), "2.0"] for t in t_ms.tolist())])
    mapping = folder / "m.toml"
    mapping.write_text('[imu]\nfile = "imu.csv"\ntime = "time_ms"\nfields = { yaw_rate = "gyro_z" }\n'
                       '[wheel]\nfile = "wheel.csv"\ntime = "time_ms"\nfields = { speed = "speed" }\n')
    return mapping


def test_times_in_ms_read_as_seconds_are_warned_of_by_info_and_run(tmp_path, capsys):
    mapping = _odometry_in_ms(tmp_path / "logs")
    drive_path = tmp_path / "drive.mcap"
    status, _, _ = run(capsys, "import", "csv", tmp_path / "logs", "--mapping", mapping, "-o", drive_path)
    assert status == 0
    message = _verdicts(read_drive(drive_path))["odometry-rate"]
    assert message is not None and "imu at 0.1 rows/s" in message and "wheel at 0.1 rows/s" in message
    assert "units.time" in message
    status, out, err = run(capsys, "info", drive_path)
    assert status == 0 and "(drive check 'odometry-rate')" in err
    assert any(line.split()[:3] == ["odometry-rate", "warning", "warning"] for line in out.splitlines())
    status, _, err = run(capsys, "run", drive_path, "-e", "dr", "--out-dir", tmp_path / "run")
    assert status == 0 and "(drive check 'odometry-rate')" in err
    warnings = json.loads((tmp_path / "run" / "run.json").read_text())["drive_warnings"]
    assert any("'odometry-rate'" in w for w in warnings)


def test_odometry_rate_bounds(sim):
    assert _verdicts(sim)["odometry-rate"] is None
    assert "imu at 0.1 rows/s" in _verdicts(_retimed(sim, lambda t: t * 1000.0))["odometry-rate"]  # ms read as s
    assert "imu at 1e+05 rows/s" in _verdicts(_retimed(sim, lambda t: t / 1000.0))["odometry-rate"]  # s read as ms


# -- the new checks on drives real and simulated ----------------------------------------------------------------------
NEW_CHECKS = ("odometry-rate", "conflicting-rows", "odometry-span")


@pytest.mark.parametrize("scenario", ["paper-straight", "paper-comprehensive", "paper-imm", "urban-rsu-gnss", "long-tunnel"])
def test_simulated_drives_trip_no_new_check(scenario):
    for drive in (simulate(scenario, seed=1, duration_s=40.0), simulate(scenario, seed=2, duration_s=40.0, profile="realistic")):
        verdicts = _verdicts(drive)
        assert all(verdicts[name] is None for name in NEW_CHECKS), verdicts


def test_plaza1_and_mrclam_trip_no_new_check():
    from graphpos.io.mrclam import import_mrclam
    from graphpos.io.plaza import import_plaza

    if not PLAZA1.exists() or not DATASET6.is_dir():
        pytest.skip("Plaza1 or MRCLAM Dataset 6 not found under ../shared/data")
    drives = [import_plaza(PLAZA1)] + [import_mrclam(DATASET6, robot) for robot in range(1, 6)]
    for drive in drives:
        verdicts = _verdicts(drive)
        assert all(verdicts[name] is None for name in NEW_CHECKS), (drive.name, verdicts)


# -- 3. rows at one time ------------------------------------------------------------------------------------------------
def test_wheel_rows_repeated_with_other_speeds_are_noted_and_warned_of(logs, tmp_path):
    folder = _copy(logs, tmp_path)
    rows = _rows(folder / "vehicle.csv")
    doubled = [rows[0]]
    for row in rows[1:]:
        doubled.append(row)
        if row[1]:
            doubled.append([row[0], repr(2 * float(row[1])), ""])
    _write_rows(folder / "vehicle.csv", doubled)
    drive = import_csv(folder, folder / "mapping_csv.toml")
    wheels = sum(1 for row in rows[1:] if row[1])
    assert len(drive.wheel) == 2 * wheels
    notes = [n for n in drive.params["import_notes"] if "at the time of the row before with other values" in n]
    assert len(notes) == 1 and f"{wheels} of {2 * wheels} rows" in notes[0] and "both kept" in notes[0]
    message = _verdicts(drive)["conflicting-rows"]
    assert message is not None and f"wheel: {wheels} of {2 * wheels} rows" in message


def test_rows_repeated_exactly_are_dropped_with_a_note(logs, tmp_path, sim):
    folder = _copy(logs, tmp_path)
    rows = _rows(folder / "imu.csv")
    _write_rows(folder / "imu.csv", rows[:1] + [row for row in rows[1:] for _ in (0, 1)])
    drive = import_csv(folder, folder / "mapping_csv.toml")
    assert len(drive.imu) == len(sim.imu)
    assert f"{len(sim.imu)} of {2 * len(sim.imu)} rows repeat an earlier row exactly (first: line 3); dropped" in \
        " ".join(drive.params["import_notes"])
    assert _verdicts(drive)["conflicting-rows"] is None


def test_repeated_rows_tell_exact_repeats_and_conflicts_apart():
    drive = every_channel_drive()
    for channel in drive.channels.values():  # rfid: two tags per instant, no conflict
        exact, conflicting = repeated_rows(channel)
        assert not exact.any() and not conflicting.any(), channel.kind
    wheel = drive.wheel.select(np.repeat(np.arange(len(drive.wheel)), 2))
    exact, conflicting = repeated_rows(wheel)
    assert exact.tolist() == [False, True] * len(drive.wheel) and not conflicting.any()
    changed = wheel.replace(speed_mps=wheel.speed_mps * np.tile([1.0, 2.0], len(drive.wheel)))
    exact, conflicting = repeated_rows(changed)
    assert not exact.any() and conflicting.tolist() == [False, True] * len(drive.wheel)


# -- 4. gaps ---------------------------------------------------------------------------------------------------------
def test_empty_and_nan_gyro_cells_are_gaps_dropped_and_counted(logs, tmp_path, sim):
    folder = _copy(logs, tmp_path)
    rows = _rows(folder / "imu.csv")
    rows[8][1], rows[19][1] = "", "NaN"  # lines 9 and 20
    _write_rows(folder / "imu.csv", rows)
    drive = import_csv(folder, folder / "mapping_csv.toml")
    assert len(drive.imu) == len(sim.imu) - 2
    assert not np.isin(drive.imu.t_s, sim.imu.t_s[[7, 18]] + drive.imu.t_s[0] - sim.imu.t_s[0]).any()
    note = next(n for n in drive.params["import_notes"] if "imu.csv" in n)
    assert (f"2 of {len(sim.imu)} rows have no value (NaN or empty) where one is needed (column 'gyro_z' (yaw_rate): "
            "2, first line 9): gaps in that sensor; dropped") in note


@pytest.mark.parametrize("column, value, fragment", [
    ("gyro_z", "inf", "imu.csv, line 9, column 'gyro_z' (yaw_rate): 'inf' is not a finite number"),
    ("time_ms", "", "imu.csv, line 9, column 'time_ms' (time): is empty"),
])
def test_infinite_values_and_missing_times_are_still_refused(logs, tmp_path, capsys, column, value, fragment):
    folder = _copy(logs, tmp_path)
    rows = _rows(folder / "imu.csv")
    rows[8][rows[0].index(column)] = value
    _write_rows(folder / "imu.csv", rows)
    out = tmp_path / "out.mcap"
    assert_one_line_error(*run(capsys, "import", "csv", folder, "--mapping", folder / "mapping_csv.toml", "-o", out),
                          fragment)


# -- 5. info with Unix-epoch times ----------------------------------------------------------------------------------
def test_info_columns_stay_apart_with_unix_epoch_times(tmp_path, capsys):
    drive = _retimed(every_channel_drive(), lambda t: t + 1_700_000_000.0)
    path = tmp_path / "epoch.mcap"
    write_drive(path, drive)
    status, out, _ = run(capsys, "info", path)
    assert status == 0
    lines = {line.split()[0]: line.split() for line in out.splitlines() if line.split()}
    imu = drive.imu
    assert lines["imu"] == ["imu", str(len(imu)), "100.00", f"{imu.t_s[0]:.3f}", f"{imu.t_s[-1]:.3f}"]
    assert lines["channel"] == ["channel", "rows", "rate_hz", "start_s", "end_s"]


# -- 6. a vehicle that never moves ----------------------------------------------------------------------------------
def test_a_wheel_standing_still_gets_no_held_readings_advice(sim):
    still = sim.replace(channels={**sim.channels, "wheel": sim.wheel.replace(speed_mps=np.zeros(len(sim.wheel)))})
    assert _verdicts(still)["held-readings"] is None
    blips = np.zeros(len(sim.wheel))
    blips[[500, 1500, 2500]] = 0.01  # three readings of a creeping vehicle: new readings at 0.1/s
    rarely = sim.replace(channels={**sim.channels, "wheel": sim.wheel.replace(speed_mps=blips)})
    assert _verdicts(rarely)["held-readings"] is None


def test_an_odometry_log_cut_short_is_warned_of(sim):
    """An IMU log that ended at 7 s of a 30 s drive ended every track at 9 s, with exit 0 and no word."""
    t0, t1 = sim.imu.t_s[0], sim.truth.t_s[-1]
    cut = sim.replace(channels={**sim.channels, "imu": sim.imu.between(t0, t0 + 7.0)})
    said = _verdicts(cut)["odometry-span"]
    assert said is not None and "'imu' ends at" in said and "before the last sensor row" in said
    late = sim.replace(channels={**sim.channels, "wheel": sim.wheel.between(t0 + 8.0, t1)})
    assert "'wheel' starts at" in _verdicts(late)["odometry-span"]
    assert _verdicts(sim)["odometry-span"] is None
