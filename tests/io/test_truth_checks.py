"""Truth checks (graphpos.io.checks): known convention errors in synthetic
drives are measured, the Plaza importer corrects a reversed heading, and
`graphpos info` prints the checks."""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.io
from plaza_samples import synthetic_plaza, turned_heading_copy

from graphpos.cli import main
from graphpos.drive import Channel, Drive, TagMap
import graphpos.io.checks as checks_module
from graphpos.io import write_drive
from graphpos.io.checks import heading_check, robust_line, truth_checks
from graphpos.io.plaza import import_plaza


def checked_drive(
    *,
    range_scale: float = 1.0,
    range_offset_m: float = 0.0,
    outlier_share: float = 0.0,
    gyro_bias_dps: float = 0.0,
    gyro_scale: float = 1.0,
    wheel_scale: float = 1.0,
    yaw_offset_rad: float = 0.0,
    yaw_drift_dps: float = 0.0,
    give_true_ranges: bool = False,
    seed: int = 1,
) -> Drive:
    """A 400 s drive at up to 5 m/s, weaving and with two stops, truth at
    10 Hz, gyro and wheel at 50 Hz, ranges to six tags at 5 Hz, with the
    given errors. ``yaw_offset_rad`` and ``yaw_drift_dps`` corrupt the truth
    yaw (a reversed heading; one integrated from a biased gyro)."""
    rng = np.random.default_rng(seed)
    dt = 0.02
    t = np.arange(0.0, 400.0 + dt / 2, dt)
    speed = 5.0 * np.clip(np.minimum(np.abs(t - 130.0), np.abs(t - 270.0)) / 10.0, 0.0, 1.0)  # stops at 130 s and 270 s
    rate = np.deg2rad(12.0) * np.sin(2 * np.pi * t / 47.0) + np.deg2rad(2.0)
    yaw = np.r_[0.0, np.cumsum((rate[1:] + rate[:-1]) / 2 * dt)]
    v_east, v_north = speed * np.cos(yaw), speed * np.sin(yaw)
    east = np.r_[0.0, np.cumsum((v_east[1:] + v_east[:-1]) / 2 * dt)]
    north = np.r_[0.0, np.cumsum((v_north[1:] + v_north[:-1]) / 2 * dt)]
    k = slice(None, None, 5)  # truth at 10 Hz
    truth_yaw = yaw + yaw_offset_rad + np.deg2rad(yaw_drift_dps) * t
    nan10 = np.full(t[k].size, np.nan)
    truth = Channel("truth", {"t_s": t[k], "east_m": east[k], "north_m": north[k], "v_east_mps": v_east[k],
                              "v_north_mps": v_north[k], "yaw_rad": truth_yaw[k], "yaw_rate_radps": nan10,
                              "accel_x_mps2": nan10, "accel_y_mps2": nan10})
    gyro = gyro_scale * rate + np.deg2rad(gyro_bias_dps) + rng.normal(0.0, np.deg2rad(0.5), t.size)
    nan = np.full(t.size, np.nan)
    imu = Channel("imu", {"t_s": t, "accel_x_mps2": nan, "accel_y_mps2": nan, "yaw_rate_radps": gyro})
    wheel = Channel("wheel", {"t_s": t, "speed_mps": wheel_scale * speed + rng.normal(0.0, 0.05, t.size)})
    tag_xy = np.column_stack([np.linspace(east.min(), east.max(), 6), np.linspace(north.min(), north.max(), 6)[::-1]])
    tags = TagMap(np.arange(6), tag_xy[:, 0], tag_xy[:, 1], np.zeros(6), np.full(6, -1))
    j = slice(None, None, 10)  # ranges at 5 Hz
    tag = rng.integers(0, 6, t[j].size)
    true = np.hypot(east[j] - tag_xy[tag, 0], north[j] - tag_xy[tag, 1])
    reading = range_scale * true + range_offset_m + rng.normal(0.0, 0.1, true.size)
    bad = rng.random(true.size) < outlier_share
    reading[bad] += rng.uniform(3.0, 20.0, int(bad.sum()))  # multipath: long
    rfid = Channel("rfid", {"t_s": t[j], "tag_id": tag, "range_m": reading,
                            "true_range_m": true if give_true_ranges else np.full(true.size, np.nan)})
    return Drive("checked", {"imu": imu, "wheel": wheel, "rfid": rfid, "truth": truth}, tags=tags)


def test_clean_drive_is_ok():
    checks = truth_checks(checked_drive())
    assert {name: c["verdict"] for name, c in checks.items()} == {
        "heading": "ok", "ranges": "ok", "odometry": "ok", "turn": "ok"}
    assert checks["heading"]["median_abs_diff_deg"] < 0.5 and checks["heading"]["share_over_90deg"] == 0.0
    assert checks["ranges"]["scale"] == pytest.approx(1.0, abs=0.005)
    assert checks["ranges"]["sigma_m"] == pytest.approx(0.1, rel=0.2)
    assert checks["odometry"]["scale"] == pytest.approx(1.0, abs=0.005)
    turn = checks["turn"]
    assert turn["bias_dps"] == pytest.approx(0.0, abs=0.05) and turn["scale"] == pytest.approx(1.0, abs=0.01)
    assert turn["course_bias_dps"] == pytest.approx(0.0, abs=0.05)
    assert turn["turn_ratio"] == pytest.approx(1.0, abs=0.01)
    # plain JSON: no NaN, no numpy scalars
    assert json.loads(json.dumps(checks, allow_nan=False)) == checks


@pytest.mark.parametrize("give_true_ranges", [False, True])
def test_long_ranges_with_outliers(give_true_ranges):
    checks = truth_checks(checked_drive(range_scale=1.07, range_offset_m=0.2, outlier_share=0.03,
                                        give_true_ranges=give_true_ranges))
    ranges = checks["ranges"]
    assert ranges["scale"] == pytest.approx(1.07, abs=0.005)
    assert ranges["offset_m"] == pytest.approx(0.2, abs=0.05)
    assert ranges["sigma_m"] == pytest.approx(0.1, rel=0.2)
    assert ranges["outlier_share"] == pytest.approx(0.03, abs=0.01)
    assert ranges["outlier_rule"] == "|residual| > 5 robust sigma"
    assert ranges["verdict"] == "scaled"


def test_gyro_bias_and_scale():
    turn = truth_checks(checked_drive(gyro_bias_dps=-0.3))["turn"]
    assert turn["bias_dps"] == pytest.approx(-0.3, abs=0.05)
    assert turn["course_bias_dps"] == pytest.approx(-0.3, abs=0.05)
    assert turn["scale"] == pytest.approx(1.0, abs=0.01)
    assert turn["verdict"] == "biased"
    turn = truth_checks(checked_drive(gyro_scale=1.05))["turn"]
    assert turn["scale"] == pytest.approx(1.05, abs=0.01) and turn["verdict"] == "scaled"
    assert truth_checks(checked_drive(gyro_scale=-1.0))["turn"]["verdict"] == "sign flipped"


def test_reversed_heading_detected_and_rates_unaffected():
    drive = checked_drive(yaw_offset_rad=np.pi, gyro_bias_dps=-0.3)
    checks = truth_checks(drive)
    heading = checks["heading"]
    assert heading["verdict"] == "reversed"
    assert heading["median_abs_diff_deg"] > 175 and heading["share_over_90deg"] == 1.0
    assert abs(heading["offset_deg"]) == pytest.approx(180.0, abs=1.0)
    # a constant offset leaves the truth yaw rate alone
    assert checks["turn"]["bias_dps"] == pytest.approx(-0.3, abs=0.05)
    assert heading_check(checked_drive().truth)["verdict"] != "reversed"
    # wrapped and unwrapped truth yaw read the same
    wrapped = drive.truth.replace(yaw_rad=np.angle(np.exp(1j * drive.truth.yaw_rad)))
    assert heading_check(wrapped)["verdict"] == "reversed"


def test_truth_heading_from_a_biased_gyro_drifts():
    # the truth yaw integrated from the gyro: the yaw fit cannot see the bias, the course fit can
    checks = truth_checks(checked_drive(gyro_bias_dps=-0.3, yaw_drift_dps=-0.3))
    heading = checks["heading"]
    assert heading["verdict"] == "drifting"
    assert heading["drift_dps"] == pytest.approx(-0.3, abs=0.02)
    turn = checks["turn"]
    assert turn["bias_dps"] == pytest.approx(0.0, abs=0.05)
    assert turn["course_bias_dps"] == pytest.approx(-0.3, abs=0.05)
    assert turn["verdict"] == "biased vs course"


def test_other_heading_errors_are_inconsistent():
    drive = checked_drive()
    from_north = drive.truth.replace(yaw_rad=np.pi / 2 - drive.truth.yaw_rad)  # compass heading left unconverted
    assert heading_check(from_north)["verdict"] == "inconsistent"
    quarter = drive.truth.replace(yaw_rad=drive.truth.yaw_rad + np.pi / 2)
    assert heading_check(quarter)["verdict"] == "inconsistent"


def test_wheel_scale():
    odometry = truth_checks(checked_drive(wheel_scale=1.03))["odometry"]
    assert odometry["scale"] == pytest.approx(1.03, abs=0.005) and odometry["verdict"] == "scaled"
    assert odometry["span_s"] == pytest.approx(399.9, abs=0.2)


def test_no_truth_no_checks():
    drive = checked_drive()
    assert truth_checks(drive.replace(channels={k: v for k, v in drive.channels.items() if k != "truth"})) == {}
    only_truth = drive.replace(channels={"truth": drive.truth})
    assert list(truth_checks(only_truth)) == ["heading"]


def test_standing_truth_is_unknown():
    truth = checked_drive().truth
    standing = truth.replace(v_east_mps=np.zeros(len(truth)), v_north_mps=np.zeros(len(truth)))
    check = heading_check(standing)
    assert check["verdict"] == "unknown" and check["moving_samples"] == 0


def test_robust_line_ignores_outliers():
    rng = np.random.default_rng(0)
    x = rng.uniform(0, 50, 2000)
    y = 1.07 * x + 0.3 + rng.normal(0, 0.2, x.size)
    y[:200] += 30.0
    fit = robust_line(x, y)
    assert fit["slope"] == pytest.approx(1.07, abs=0.002) and fit["intercept"] == pytest.approx(0.3, abs=0.05)
    assert fit["outlier_share"] == pytest.approx(0.1, abs=0.005)
    assert robust_line(np.ones(5), np.ones(5)) is None


# -- the Plaza importer ------------------------------------------------------


def test_plaza_reversed_heading_corrected(tmp_path):
    path = tmp_path / "circle.mat"
    synthetic_plaza(path)
    plain = import_plaza(path)
    assert "import_notes" not in plain.params
    turned = tmp_path / "turned.mat"
    turned_heading_copy(path, turned)
    drive = import_plaza(turned)
    notes = drive.params["import_notes"]
    assert len(notes) == 1 and "180 deg from the direction of motion" in notes[0] and "corrected" in notes[0]
    assert np.allclose(np.angle(np.exp(1j * (drive.truth.yaw_rad - plain.truth.yaw_rad))), 0.0, atol=1e-9)
    assert truth_checks(drive)["heading"]["verdict"] == "ok"
    # a quarter turn is not a reversal: kept, with a note
    turned_heading_copy(path, turned, np.pi / 2)
    drive = import_plaza(turned)
    assert "kept as recorded" in drive.params["import_notes"][0]
    assert heading_check(drive.truth)["verdict"] == "inconsistent"


def test_plaza1_left_alone(plaza1):
    drive = import_plaza(plaza1)
    assert "import_notes" not in drive.params
    gt = scipy.io.loadmat(plaza1)["GT"]
    assert np.array_equal(drive.truth.yaw_rad, np.unwrap(gt[:, 3]))
    checks = truth_checks(drive)
    assert checks["heading"]["verdict"] == "ok"
    assert checks["ranges"]["scale"] == pytest.approx(1.069, abs=0.005)
    assert checks["odometry"]["verdict"] == checks["turn"]["verdict"] == "ok"


def test_plaza1_reversed_round_trip(plaza1, tmp_path):
    turned = tmp_path / "Plaza1-reversed.mat"
    turned_heading_copy(plaza1, turned)
    reversed_truth = import_plaza(turned)
    original = import_plaza(plaza1)
    assert reversed_truth.params["import_notes"][0].startswith("truth heading (GT column 4) was 180 deg")
    # corrected: the same heading as Plaza1's (up to whole turns)
    turns = (reversed_truth.truth.yaw_rad - original.truth.yaw_rad) / (2 * np.pi)
    assert np.allclose(turns, np.round(turns), atol=1e-9) and np.ptp(np.round(turns)) == 0
    assert reversed_truth.imu == original.imu and reversed_truth.rfid == original.rfid
    assert truth_checks(reversed_truth)["heading"]["verdict"] == "ok"


# -- the command line ---------------------------------------------------------


def run(capsys, *argv):
    status = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return status, out, err


def test_info_prints_the_checks(tmp_path, capsys):
    path = tmp_path / "d.mcap"
    write_drive(path, checked_drive(range_scale=1.07, gyro_bias_dps=-0.3, yaw_offset_rad=np.pi))
    status, out, _ = run(capsys, "info", path)
    assert status == 0
    block = out[out.index("truth checks"):].splitlines()[1:]
    lines = {line.split()[0]: line for line in block}
    assert list(lines) == ["heading", "ranges", "odometry", "turn"]
    assert lines["heading"].split()[1] == "reversed:"
    assert float(lines["ranges"].split("reading = ")[1].split()[0]) == pytest.approx(1.07, abs=0.005)
    assert lines["ranges"].split()[1] == "scaled:"
    assert lines["odometry"].split()[1] == "ok:"
    assert "bias -0.3" in lines["turn"] and lines["turn"].split()[1] == "biased:"
    status, out, _ = run(capsys, "info", path, "--json")
    checks = json.loads(out)["truth_checks"]
    assert checks["heading"]["verdict"] == "reversed"
    assert checks["ranges"]["scale"] == pytest.approx(1.07, abs=0.005)
    assert checks["turn"]["bias_dps"] == pytest.approx(-0.3, abs=0.05)


def test_info_without_truth_has_no_checks(tmp_path, capsys):
    drive = checked_drive()
    path = tmp_path / "d.mcap"
    write_drive(path, drive.replace(channels={k: v for k, v in drive.channels.items() if k != "truth"}))
    status, out, _ = run(capsys, "info", path)
    assert status == 0 and "truth checks" not in out
    assert "truth_checks" not in json.loads(run(capsys, "info", path, "--json")[1])


def test_import_plaza_warns_of_a_corrected_heading(tmp_path, capsys):
    mat = tmp_path / "circle.mat"
    synthetic_plaza(mat)
    status, out, err = run(capsys, "import", "plaza", mat, "-o", tmp_path / "plain.mcap")
    assert status == 0 and err == ""
    turned = tmp_path / "turned.mat"
    turned_heading_copy(mat, turned)
    status, out, err = run(capsys, "import", "plaza", turned, "-o", tmp_path / "turned.mcap")
    assert status == 0 and "wrote" in out
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("graphpos import plaza: warning: truth heading (GT column 4) was 180 deg")
    info = json.loads(run(capsys, "info", tmp_path / "turned.mcap", "--json")[1])
    assert info["params"]["import_notes"] == [lines[0].removeprefix("graphpos import plaza: warning: ")]
    assert info["truth_checks"]["heading"]["verdict"] == "ok"
