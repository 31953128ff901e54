"""`graphpos estimators` and `graphpos run`: outputs, and bad input -> one line, exit 2, no output."""

import csv
import json
import sys

import pytest
from song2016_drives import make_drive

from graphpos.cli import main
from graphpos.estimate import CSV_COLUMNS
from graphpos.io import read_drive, read_estimates, write_drive


@pytest.fixture(scope="module")
def drive_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("drive") / "d.mcap"
    write_drive(path, make_drive(duration_s=15.0, seed=2))
    return path


def test_estimators_lists_song2016(capsys):
    assert main(["estimators", "--json"]) == 0
    rows = {r["name"]: r for r in json.loads(capsys.readouterr().out)}
    for name in ("dr", "multilateration", "rfid-ekf", "fusion-ekf", "fukf", "two-level-ekf"):
        assert rows[name]["summary"]
    assert rows["fusion-ekf"]["required_channels"] == ["imu", "wheel", "rfid"]
    assert rows["fusion-ekf"]["config"]["accel_sigma_mps2"] == 0.1
    assert main(["estimators"]) == 0
    assert "fukf" in capsys.readouterr().out


def test_run_writes_every_output(drive_file, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["run", str(drive_file), "-e", "fusion-ekf", "-e", "rfid-ekf", "--layout", "optimized", "--out-dir", str(out)]) == 0
    assert {p.name for p in out.iterdir()} == {"run.json", "all_estimates.kml", "estimates.mcap", "estimates_ros2",
                                               *(f"{n}.{ext}" for n in ("fusion-ekf", "rfid-ekf", "truth")
                                                 for ext in ("csv", "tum", "kml", "geojson"))}
    for name in ("fusion-ekf", "rfid-ekf", "truth"):
        with open(out / f"{name}.csv") as fh:
            rows = list(csv.reader(fh))
        assert tuple(rows[0]) == CSV_COLUMNS and len(rows) > 10
        if name == "rfid-ekf":  # no velocity or yaw: empty cells, covariance present
            assert rows[1][3:6] == ["", "", ""] and rows[1][6] != ""
    summary = json.loads((out / "run.json").read_text())
    assert summary["layout"] == "optimized"
    fusion = summary["estimators"]["fusion-ekf"]
    assert fusion["wall_time_s"] > 0
    # as results.json's: wall time over the drive's duration (run.json once had its inverse under another name)
    assert fusion["real_time_factor"] == pytest.approx(fusion["wall_time_s"] / read_drive(drive_file).duration_s)
    assert "ranges_gated" in summary["estimators"]["fusion-ekf"]["diagnostics"]
    assert {e.name for e in read_estimates(out / "estimates.mcap")} == {"fusion-ekf", "rfid-ekf"}


def _bad(args, capsys, out):
    code = main(args)
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and "error" in err and "Traceback" not in err
    assert not out.exists() or not any(out.iterdir())
    return err


def test_bad_inputs(drive_file, tmp_path, capsys):
    out = tmp_path / "out"
    assert "no-such" in _bad(["run", str(tmp_path / "no-such.mcap"), "-e", "dr", "--out-dir", str(out)], capsys, out)
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file at all")
    _bad(["run", str(junk), "-e", "dr", "--out-dir", str(out)], capsys, out)
    assert "unknown estimator" in _bad(["run", str(drive_file), "-e", "nope", "--out-dir", str(out)], capsys, out)
    assert "layout" in _bad(["run", str(drive_file), "-e", "dr", "--layout", "sparse", "--out-dir", str(out)], capsys, out)
    bad_model = tmp_path / "model.json"
    bad_model.write_text("{]")
    _bad(["run", str(drive_file), "-e", "dr", "--range-model", str(bad_model), "--out-dir", str(out)], capsys, out)


def test_an_estimator_the_drive_lacks_channels_for_is_not_run(tmp_path, capsys):
    """The others run (as evaluate marks it n/a); run.json says why; with none left, nothing is written."""
    drive = make_drive(duration_s=5.0)
    path = tmp_path / "nowheel.mcap"
    write_drive(path, drive.replace(channels={k: v for k, v in drive.channels.items() if k != "wheel"}))
    out = tmp_path / "out"
    assert main(["run", str(path), "-e", "rfid-ekf,fusion-ekf", "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "warning: not run: " in err and "fusion-ekf needs" in err and "wheel" in err and "Traceback" not in err
    summary = json.loads((out / "run.json").read_text())
    assert summary["not_applicable"] == ["fusion-ekf"] and summary["failed"] == []
    assert summary["estimators"]["fusion-ekf"]["status"] == "not_applicable"
    assert summary["estimators"]["rfid-ekf"]["status"] == "ok"
    assert (out / "rfid-ekf.csv").exists() and not (out / "fusion-ekf.csv").exists()
    out2 = tmp_path / "out2"
    err = _bad(["run", str(path), "-e", "fusion-ekf", "--out-dir", str(out2)], capsys, out2)
    assert "wheel" in err


def test_progress_lines_on_a_terminal_only(drive_file, tmp_path, capsys, monkeypatch):
    """run said nothing for the 30-80 s its graph estimators take on a real drive; logs and pipes stay clean."""
    assert main(["run", str(drive_file), "-e", "dr,fusion-ekf", "-o", str(tmp_path / "quiet")]) == 0
    assert "(1 of 2)" not in capsys.readouterr().err
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)
    assert main(["run", str(drive_file), "-e", "dr,fusion-ekf", "-o", str(tmp_path / "tty")]) == 0
    err = capsys.readouterr().err
    assert "graphpos run: dr (1 of 2) on " in err and "graphpos run: fusion-ekf (2 of 2) on " in err
