"""The README's tour runs as it stands on a fresh clone, without ``../shared/`` (issue 15, item 7).

Each ``sh`` block is taken from README.md and run in a temporary folder laid out as a clone (its
``.venv`` is this checkout's): the tour must succeed and write nothing but ``work/``. A ``graphpos`` line
runs in this process (:func:`graphpos.cli.main` with the line's words, as the console script does,
without its second of start-up each), any other line by bash after ``. .venv/bin/activate``. The
real-data block runs when ``../shared/data`` holds the datasets and, on a clone without them, its first
import must fail in one line (bash, as it stands) that says where the file comes from.
"""

from __future__ import annotations

import os
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
SHARED = REPO.parent / "shared"
DATASETS = (SHARED / "data/plaza/Plaza1.mat", SHARED / "data/mrclam/MRCLAM_Dataset6")


def sh_block(heading: str) -> list[str]:
    """The command lines of the first ``sh`` block after the README heading ``heading``."""
    text = (REPO / "README.md").read_text(encoding="utf-8")
    after = text.split(f"\n{heading}\n", 1)[1]
    block = after.split("```sh\n", 1)[1].split("\n```", 1)[0]
    return [line for line in block.splitlines() if line.strip()]


def clone(tmp_path: Path) -> tuple[Path, dict[str, str]]:
    """A folder standing for a fresh clone (``tmp_path/clone``, its ``.venv`` the virtual environment these
    tests run in), and the environment to run in (its own home, for the files evo and matplotlib keep there)."""
    venv = Path(sys.prefix)
    if not (venv / "bin" / "activate").is_file():
        pytest.skip("the tests do not run in a virtual environment (the README's .venv)")
    folder = tmp_path / "clone"
    folder.mkdir()
    (folder / ".venv").symlink_to(venv)
    (tmp_path / "home").mkdir()
    env = {**os.environ, "HOME": str(tmp_path / "home"), "MPLBACKEND": "Agg"}
    env.pop("VIRTUAL_ENV", None)
    return folder, env


def run_lines(lines: list[str], cwd: Path, env: dict[str, str]) -> subprocess.CompletedProcess:
    """``lines`` run by bash in ``cwd``, stopping at the first that fails."""
    script = "set -eo pipefail\ntrap 'echo \"README line failed: $BASH_COMMAND\" >&2' ERR\n" + "\n".join(lines)
    return subprocess.run(["bash", "-c", script], cwd=cwd, env=env, capture_output=True, text=True, timeout=900)


def run_tour(lines: list[str], cwd: Path, env: dict[str, str], monkeypatch) -> str:
    """Every line of a block in ``cwd`` (module docstring); what the shell lines printed."""
    from graphpos.cli import main

    monkeypatch.chdir(cwd)
    printed = []
    for line in lines:
        words = shlex.split(line, comments=True)
        if words == [".", ".venv/bin/activate"]:
            continue  # the shell lines below activate it themselves
        if words[0] == "graphpos":
            assert main(words[1:]) == 0, line
        else:
            done = run_lines([". .venv/bin/activate", line], cwd, env)
            assert done.returncode == 0, f"{line}: {done.stderr[-3000:]}"
            printed.append(done.stdout)
    return "".join(printed)


def test_the_tour_writes_only_into_work():
    lines = sh_block("## A short tour")
    assert lines[0] == ". .venv/bin/activate" and lines[1] == "mkdir -p work"
    for line in lines[2:]:
        words = shlex.split(line, comments=True)
        outputs = [words[i + 1] for i, w in enumerate(words[:-1]) if w in ("-o", "--out")]
        assert all(o.startswith("work/") for o in outputs), line
        assert "../shared" not in line and "--out-dir" not in line, line


def test_the_tour_runs_on_a_fresh_clone(tmp_path, monkeypatch):
    folder, env = clone(tmp_path)
    monkeypatch.setenv("HOME", env["HOME"])
    printed = run_tour(sh_block("## A short tour"), folder, env, monkeypatch)
    assert sorted(os.listdir(folder)) == [".venv", "work"]
    work = folder / "work"
    for name in ("run/truth.tum", "run/graph-isam2.tum", "run/estimates.mcap", "run/estimates_ros2/metadata.yaml",
                 "evaluation/results.json", "smoothed/run.json", "layout/results.json", "online/run.json", "rss.json"):
        assert (work / name).exists(), name
    assert "rmse" in printed and "/graphpos/graph_isam2/odometry" in printed  # evo_ape's statistics, evo_traj's topics


@pytest.mark.skipif(not all(p.exists() for p in DATASETS), reason="the real datasets are not in ../shared/data")
def test_the_real_data_block_runs_with_the_datasets(tmp_path, monkeypatch):
    folder, env = clone(tmp_path)
    (tmp_path / "shared").symlink_to(SHARED)
    (folder / "work").mkdir()
    run_tour(sh_block("### Real data"), folder, env, monkeypatch)
    assert (folder / "work" / "plaza1.mcap").is_file() and (folder / "work" / "robot3.mcap").is_file()


def test_the_real_data_block_says_where_the_data_comes_from(tmp_path):
    folder, env = clone(tmp_path)
    (folder / "work").mkdir()
    first = sh_block("### Real data")[0]
    assert first.startswith("graphpos import plaza ../shared/")
    done = run_lines([". .venv/bin/activate", first], folder, env)
    assert done.returncode == 2
    lines = [line for line in done.stderr.splitlines() if not line.startswith("README line failed")]
    assert len(lines) == 1 and lines[0].startswith("graphpos import plaza: error: ../shared/data/plaza/Plaza1.mat: no such file")
    assert "github.com/borglab/gtsam" in lines[0] and "examples/Data/Plaza1_.mat" in lines[0]
    assert not os.listdir(folder / "work")


@pytest.mark.slow
def test_the_planning_block_runs_on_a_fresh_clone(tmp_path, monkeypatch):
    folder, env = clone(tmp_path)
    monkeypatch.setenv("HOME", env["HOME"])
    run_tour(sh_block("## Planning a tag layout"), folder, env, monkeypatch)
    for name in ("plan/layout.toml", "plan/plan.png", "plan/report.html", "planned.mcap", "planned/results.json"):
        assert (folder / "work" / name).exists(), name
