"""`graphpos ranging` commands: output shapes and user mistakes (exit 2, one line on stderr)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from graphpos.cli import main
from graphpos.drive import Channel, Drive, TagMap
from graphpos.ranging import LinearCalibration, load_range_model
from graphpos.ranging.table1 import PUBLISHED_TABLE1


def _write_drive_or_skip(path, drive):
    io = pytest.importorskip("graphpos.io")
    if not hasattr(io, "write_drive"):
        pytest.skip("graphpos.io.write_drive not available yet")
    io.write_drive(path, drive)


def _ranged_drive(with_truth: bool) -> Drive:
    rng = np.random.default_rng(3)
    true = rng.uniform(1, 20, 120)
    columns = {"t_s": np.arange(120.0), "tag_id": np.resize([1, 2], 120), "range_m": 1.07 * true + 0.05}
    if with_truth:
        columns["true_range_m"] = true
    tags = TagMap([1, 2], [0.0, 30.0], [5.0, 5.0], [1, -1], [0, 0])
    return Drive("cli-test", {"rfid": Channel("rfid", columns)}, tags=tags)


def test_table1_json(capsys):
    assert main(["ranging", "table1", "--json"]) == 0
    figures = json.loads(capsys.readouterr().out)
    assert set(figures) == set(PUBLISHED_TABLE1)
    for row in figures.values():
        for kind in ("lssvm", "propagation"):
            assert np.isfinite(row[kind]["mean"]) and row[kind]["std"] > 0


def test_table1_text_shows_paper_figures_and_plots(capsys, tmp_path):
    figure = tmp_path / "fig6-7.png"
    assert main(["ranging", "table1", "--plot", str(figure)]) == 0
    out = capsys.readouterr().out
    assert "10.43" in out and "tunnel" in out
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_fit_writes_a_loadable_model(tmp_path, capsys):
    drive_path = tmp_path / "drive.mcap"
    _write_drive_or_skip(drive_path, _ranged_drive(with_truth=True))
    model_path = tmp_path / "model.json"
    assert main(["ranging", "fit", str(drive_path), "--truth", "-o", str(model_path)]) == 0
    model = load_range_model(model_path)
    assert isinstance(model, LinearCalibration) and model.scale == pytest.approx(1.07)
    assert main(["ranging", "show", str(model_path)]) == 0
    assert "linear range model" in capsys.readouterr().out
    assert main(["ranging", "check", str(drive_path), "--range-model", str(model_path)]) == 0
    out = capsys.readouterr().out
    assert "RMS/sigma" in out and out.strip().splitlines()[-1].startswith("all")


@pytest.mark.parametrize(
    "argv, message",
    [
        (["ranging", "fit", "DRIVE", "-o", "OUT"], "pass --truth"),
        (["ranging", "fit", "missing.mcap", "--truth", "-o", "OUT"], "no such file"),
        (["ranging", "fit", "DRIVE", "--truth", "-o", "nowhere/model.json"], "no such folder"),
        (["ranging", "fit", "NOTRUTH", "--truth", "-o", "OUT"], "no truth"),
        (["ranging", "fit", "DRIVE", "--truth", "-o", "OUT", "--kind", "propagation"], "no 'rss' readings"),
        (["ranging", "show", "missing.json"], "no such file"),
        (["ranging", "check", "NOTRUTH"], "no truth"),
        (["ranging", "check", "DRIVE", "--range-model", "missing.json"], "no such file"),
        (["ranging", "table1", "--seed", "-3"], "non-negative"),
        (["ranging", "table1", "--plot", "nowhere/f.png"], "no such folder"),
    ],
)
def test_user_mistakes_exit_2(argv, message, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    if "DRIVE" in argv or "NOTRUTH" in argv:
        _write_drive_or_skip(tmp_path / "DRIVE", _ranged_drive(with_truth=True))
        _write_drive_or_skip(tmp_path / "NOTRUTH", _ranged_drive(with_truth=False))
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


@pytest.mark.parametrize("argv", [["ranging"], ["ranging", "table1", "--seed", "x"], ["ranging", "fit", "D"]])
def test_bad_options_exit_2(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert capsys.readouterr().err.count("\n") == 1
