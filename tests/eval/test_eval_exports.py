"""Trajectory exports (graphpos.io.exports) and the evaluation CLI."""

from __future__ import annotations

import csv
import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from graphpos.cli import main
from graphpos.drive import GeoOrigin
from graphpos.estimate import CSV_COLUMNS, Estimate
from graphpos.io import write_drive
from graphpos.io.exports import csv_text, export_estimate, geojson_dict, kml_text, tum_text


@pytest.fixture
def estimate():
    return Estimate("fusion-ekf", [0.0, 1.0], [0.0, 100.0], [0.0, 0.0], yaw_rad=[0.0, np.pi / 2],
                    cov_en_m2=np.tile(np.diag([1.0, 2.0]), (2, 1, 1)))


def test_tum_quaternion_is_the_yaw(estimate):
    rows = np.loadtxt(tum_text(estimate).splitlines())
    assert rows.shape == (2, 8)
    assert rows[1, :3] == pytest.approx([1.0, 100.0, 0.0])
    assert rows[1, 6:] == pytest.approx([np.sin(np.pi / 4), np.cos(np.pi / 4)])  # qz, qw
    assert rows[0, 4:] == pytest.approx([0, 0, 0, 1])


def test_geojson_and_kml_put_the_track_at_the_origin(estimate):
    origin = GeoOrigin(45.0, 7.0)
    coords = np.array(geojson_dict(estimate, origin)["features"][0]["geometry"]["coordinates"])
    assert coords[0] == pytest.approx([7.0, 45.0])
    # 100 m east at 45 deg N is about 100 / (111.3 km * cos 45) degrees of longitude
    assert coords[1, 0] - 7.0 == pytest.approx(100 / (111320 * np.cos(np.radians(45))), rel=5e-3)
    root = ET.fromstring(kml_text([estimate], origin))
    text = [e.text for e in root.iter() if e.tag.endswith("coordinates")][0]
    first = [float(v) for v in text.split()[0].split(",")[:2]]
    assert first == pytest.approx([7.0, 45.0])


def test_csv_has_the_estimate_columns(estimate):
    rows = list(csv.reader(csv_text(estimate).splitlines()))
    assert tuple(rows[0]) == CSV_COLUMNS
    assert float(rows[2][1]) == 100.0 and rows[2][3] == "" and float(rows[2][7]) == 2.0


def test_export_writes_four_files(tmp_path, estimate):
    paths = export_estimate(estimate, GeoOrigin(), tmp_path)
    assert sorted(paths) == ["csv", "geojson", "kml", "tum"]
    assert json.loads(paths["geojson"].read_text())["type"] == "FeatureCollection"
    assert not list(tmp_path.glob(".*tmp"))


def test_cli_evaluate_writes_the_folder(tmp_path, drive, test_estimators, capsys):
    write_drive(tmp_path / "d.mcap", drive)
    code = main(["evaluate", str(tmp_path / "d.mcap"), "-e", "noisy-truth", "-o", str(tmp_path / "out"),
                 "--workers", "1", "--no-progress"])
    assert code == 0
    assert (tmp_path / "out" / "results.json").exists()
    assert (tmp_path / "out" / "straight" / "estimates.mcap").exists()


def test_cli_evaluate_without_truth_exits_2(tmp_path, drive, test_estimators, capsys):
    write_drive(tmp_path / "bare.mcap", drive.replace(channels={"wheel": drive.wheel}))
    code = main(["evaluate", str(tmp_path / "bare.mcap"), "-e", "noisy-truth", "-o", str(tmp_path / "out")])
    assert code == 2
    assert "evaluate needs truth" in capsys.readouterr().err


def test_cli_evaluate_failure_exits_1_with_summary(tmp_path, drive, test_estimators, capsys):
    write_drive(tmp_path / "d.mcap", drive)
    code = main(["evaluate", str(tmp_path / "d.mcap"), "-e", "noisy-truth,broken", "-o", str(tmp_path / "out"),
                 "--workers", "1", "--no-progress"])
    assert code == 1
    assert "broken on straight: RuntimeError: boom" in capsys.readouterr().err


def test_cli_unknown_estimator_exits_2(tmp_path, drive, test_estimators, capsys):
    write_drive(tmp_path / "d.mcap", drive)
    assert main(["evaluate", str(tmp_path / "d.mcap"), "-e", "nope", "-o", str(tmp_path / "out")]) == 2
    assert "unknown estimator" in capsys.readouterr().err
