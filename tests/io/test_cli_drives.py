"""`graphpos info` and `graphpos import plaza`: output, and every bad input
giving one line on stderr, exit status 2 and no output file."""

from __future__ import annotations

import json

import numpy as np
import pytest
from plaza_samples import synthetic_plaza

from graphpos.cli import main
from graphpos.io import write_drive


def run(capsys, *argv):
    status = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return status, out, err


def assert_one_line_error(status, out, err, *fragments):
    assert status == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])


def test_info_json(tmp_path, capsys, drive, estimate):
    path = tmp_path / "d.mcap"
    write_drive(path, drive, estimates=[estimate])
    status, out, _ = run(capsys, "info", path, "--json")
    assert status == 0
    info = json.loads(out)
    assert info["duration_s"] == pytest.approx(drive.duration_s)
    imu = info["channels"]["imu"]
    assert imu["count"] == len(drive.imu)
    assert imu["rate_hz"] == pytest.approx(100.0)
    assert imu["start_s"] == drive.imu.t_s[0] and imu["end_s"] == drive.imu.t_s[-1]
    # rfid has two readings per timestamp at 10 Hz: rate counts distinct timestamps
    assert info["channels"]["rfid"]["count"] == 2 * len(drive.compass)
    assert info["channels"]["rfid"]["rate_hz"] == pytest.approx(10.0)
    assert info["tags"] == {"count": 4, "layouts": {"optimized": 2, "sparse": 1, "dense": 4}}
    assert info["windows"] == [{"label": "in_tunnel", "start_s": 1.0, "end_s": 3.0}, {"label": "zone:open", "start_s": 0.0, "end_s": 1.0}]
    assert info["estimates"] == {"fusion-ekf": {"count": len(estimate), "rate_hz": 100.0}}


def test_info_table(tmp_path, capsys, drive):
    path = tmp_path / "d.mcap"
    write_drive(path, drive)
    status, out, _ = run(capsys, "info", path)
    assert status == 0
    lines = {line.split()[0]: line for line in out.splitlines()}
    assert lines["imu"].split()[1:3] == [str(len(drive.imu)), "100.00"]
    assert "dense 4" in lines["tags"] and "in_tunnel" in lines["windows"]


def test_import_plaza_then_info(tmp_path, capsys):
    mat = tmp_path / "circle.mat"
    synthetic_plaza(mat)
    out_path = tmp_path / "circle.mcap"
    status, out, _ = run(capsys, "import", "plaza", mat, "-o", out_path)
    assert status == 0 and "wrote" in out
    status, out, _ = run(capsys, "info", out_path, "--json")
    info = json.loads(out)
    assert set(info["channels"]) == {"imu", "wheel", "rfid", "truth"}
    assert info["channels"]["wheel"]["rate_hz"] == pytest.approx(5.0)
    assert info["tags"] == {"count": 3, "layouts": {"dense": 3}}
    assert info["origin"]["lat_deg"] == pytest.approx(40.4435)
    status, _, _ = run(capsys, "import", "plaza", mat, "-o", out_path, "--origin", "51.5,-0.12,10")
    assert status == 0
    assert json.loads(run(capsys, "info", out_path, "--json")[1])["origin"] == {"lat_deg": 51.5, "lon_deg": -0.12, "alt_m": 10.0}


@pytest.mark.parametrize("case", ["missing", "empty", "random", "truncated", "foreign", "invalid", "folder"])
def test_info_bad_input(tmp_path, capsys, drive, case):
    path = tmp_path / f"{case}.mcap"
    if case == "empty":
        path.write_bytes(b"")
    elif case == "random":
        path.write_bytes(np.random.default_rng(0).bytes(1000))
    elif case == "truncated":
        write_drive(path, drive)
        path.write_bytes(path.read_bytes()[:-100])
    elif case == "foreign":
        from test_foreign_and_bad_files import write_foreign

        write_foreign(path, {"/camera": ("sensor_msgs/Image", "ros1", [b"\x00"])})
    elif case == "invalid":
        from test_foreign_and_bad_files import write_foreign

        write_foreign(path, {"/wheel": ("graphpos.wheel", "json", [b'{"t_s": 1, "speed_mps": 1}', b'{"t_s": 0, "speed_mps": 1}'])})
    elif case == "folder":
        path.mkdir()
    status, out, err = run(capsys, "info", path)
    assert_one_line_error(status, out, err, "graphpos info: error:", str(path))
    if case == "invalid":
        assert "channel 'wheel', row 1" in err


@pytest.mark.parametrize("case", ["missing", "not-mat", "missing-array", "wrong-shape", "no-folder", "output-is-folder"])
def test_import_plaza_bad_input(tmp_path, capsys, case):
    mat = tmp_path / "in.mat"
    output = tmp_path / "out.mcap"
    expect = str(mat)
    if case == "not-mat":
        mat.write_bytes(b"hello")
    elif case == "missing-array":
        synthetic_plaza(mat, drop="TD")
        expect = "no array 'TD'"
    elif case == "wrong-shape":
        synthetic_plaza(mat, GT=np.zeros((3, 2)))
        expect = "array 'GT' has shape (3, 2)"
    elif case == "no-folder":
        synthetic_plaza(mat)
        output = tmp_path / "nowhere" / "out.mcap"
        expect = "does not exist"
    elif case == "output-is-folder":
        synthetic_plaza(mat)
        output.mkdir()
        expect = "it is a folder"
    before = sorted(p.name for p in tmp_path.iterdir())
    status, out, err = run(capsys, "import", "plaza", mat, "-o", output)
    assert_one_line_error(status, out, err, "graphpos import plaza: error:", expect)
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_bad_options(capsys):
    for argv in (["info"], ["import"], ["import", "plaza", "x.mat"], ["import", "csv", "x"],
                 ["import", "plaza", "x.mat", "-o", "y.mcap", "--origin", "north"],
                 ["import", "plaza", "x.mat", "-o", "y.mcap", "--origin", "95,0"]):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == 2
        assert len(capsys.readouterr().err.strip().splitlines()) == 1
