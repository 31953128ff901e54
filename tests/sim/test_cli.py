"""The `scenarios` and `simulate` commands, bad input included."""

from __future__ import annotations

import json
import os

import pytest

from graphpos.cli import main
from graphpos.sim import SCENARIOS, simulate


def test_scenarios_lists_every_scenario(capsys):
    assert main(["scenarios"]) == 0
    out = capsys.readouterr().out
    for name in SCENARIOS:
        assert name in out
    assert main(["scenarios", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["name"] for r in rows] == list(SCENARIOS)
    assert rows[0]["default_duration_s"] == pytest.approx(76.0, abs=1)
    assert all(set(r) == {"name", "summary", "patterns", "default_pattern", "default_duration_s"} for r in rows)


def test_simulate_writes_a_drive_that_reads_back(tmp_path, capsys):
    io = pytest.importorskip("graphpos.io")
    out = tmp_path / "d.mcap"
    cfg = tmp_path / "c.toml"
    cfg.write_text("[imu]\ngyro_sigma_dps = 0.25\n")
    rc = main(["simulate", "paper-comprehensive", "--pattern", "lane-change-curve", "--seed", "4", "--duration", "100",
               "--config", str(cfg), "--rfid-latency", "0.5:2", "-o", str(out)])
    assert rc == 0, capsys.readouterr().err
    assert "wrote" in capsys.readouterr().out
    back = io.read_drive(out)
    ref = simulate("paper-comprehensive", "lane-change-curve", seed=4, duration_s=100, overrides={"imu": {"gyro_sigma_dps": 0.25}},
                   rfid_latency_s=(0.5, 2.0))
    for name, ch in ref.channels.items():
        assert back.channels[name] == ch, name
    assert back.tags == ref.tags and back.params["imu"]["gyro_sigma_dps"] == 0.25
    delay = back.rfid.arrival_s - back.rfid.t_s
    assert delay.min() >= 0.5 and delay.max() <= 2.0
    assert {w.label for w in back.windows} >= {"in_tunnel", "straight", "curve", "zone:tunnel"}


def test_simulate_with_faults(tmp_path, capsys):
    io = pytest.importorskip("graphpos.io")
    out = tmp_path / "f.mcap"
    cfg = tmp_path / "c.toml"
    cfg.write_text("[[faults.rfid_blackout]]\nstart_s = 10\nduration_s = 5\n")
    rc = main(["simulate", "paper-straight", "--config", str(cfg), "--fault", "rfid_blackout:start_s=40:duration_s=10",
               "--fault", "dropped_samples:channels=imu+wheel:fraction=0.1", "-o", str(out)])
    assert rc == 0, capsys.readouterr().err
    back = io.read_drive(out)
    assert [(w.start_s, w.end_s) for w in back.window("fault:rfid_blackout")] == [(10.0, 15.0), (40.0, 50.0)]
    assert len(back.window("fault:dropped_samples")) == 1
    assert len(back.imu) < len(back.truth)


#: Bad command lines ({name} is a path made by the test).
BAD_COMMANDS = """
simulate nope
simulate paper-straight --pattern lane-change-curve
simulate paper-straight --seed -1
simulate paper-straight --seed x
simulate paper-straight --duration -5
simulate paper-straight --duration 0
simulate paper-straight --duration abc
simulate paper-straight --rfid-latency a:b
simulate paper-straight --rfid-latency 2:1
simulate paper-straight --rfid-latency 1:2:3
simulate paper-straight --config {missing}
simulate paper-straight --config {bad_toml}
simulate paper-straight --config {unknown_key}
simulate paper-straight --config {bad_value}
simulate paper-straight --output-folder-missing
simulate paper-straight --fault bogus
simulate paper-straight --fault wheel_slip:slip
simulate paper-straight --fault wheel_slip:grip=1
simulate paper-straight --fault dead_tags:fraction=7
simulate paper-straight --config {bad_faults}
simulate paper-straight --profile nope
simulate paper-straight -o {no_folder}
simulate paper-straight -o {a_folder}
simulate paper-straight -o {read_only}
simulate
scenarios --bogus
scenarios --params nope
scenarios --params paper-straight --profile nope
scenarios --profile realistic
""".strip().splitlines()


@pytest.mark.parametrize("argv", [line.split() for line in BAD_COMMANDS], ids=BAD_COMMANDS)
def test_bad_input_exits_2_with_one_line(argv, tmp_path, capsys):
    if "{read_only}" in argv and os.geteuid() == 0:
        pytest.skip("root may write into a read-only folder")
    (tmp_path / "bad.toml").write_text("[imu\n")
    (tmp_path / "unknown.toml").write_text("[imu]\ngyro = 1\n")
    (tmp_path / "value.toml").write_text("[wheel]\nrate_hz = -3\n")
    (tmp_path / "faults.toml").write_text("faults = 3\n")
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    places = {"missing": tmp_path / "none.toml", "bad_toml": tmp_path / "bad.toml", "unknown_key": tmp_path / "unknown.toml",
              "bad_value": tmp_path / "value.toml", "bad_faults": tmp_path / "faults.toml", "no_folder": tmp_path / "no" / "d.mcap", "a_folder": tmp_path,
              "read_only": ro / "d.mcap"}
    argv = [a.format(**places) for a in argv]
    if "-o" not in argv and argv[0] == "simulate" and len(argv) > 1 and "--output-folder-missing" not in argv:
        argv += ["-o", str(tmp_path / "d.mcap")]
    argv = [a for a in argv if a != "--output-folder-missing"]
    try:
        rc = main(argv)
    except SystemExit as exc:  # argparse errors
        rc = exc.code
    finally:
        ro.chmod(0o700)
    err = capsys.readouterr().err
    assert rc == 2
    assert len(err.strip().splitlines()) == 1, err
    assert "Traceback" not in err
    assert not (tmp_path / "d.mcap").exists()
