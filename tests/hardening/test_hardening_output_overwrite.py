"""A single output file never overwrites what the user did not mean to lose.

``simulate``, ``import``, ``calibrate``, ``ranging fit`` and ``ranging table1
--plot`` write one file.
Its path being one of the command's inputs (the drive, the config or
mapping file, a file inside the imported folder; also through a hard or
symbolic link) is refused before any work: one line naming the path, status
2, the input unchanged byte for byte. An existing file that is not what the
command writes (an MCAP drive; a JSON object; a PNG image) is refused the same way. The
command's own previous output, an empty file and (for a drive) another MCAP
drive are replaced.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from recordings import copy_example, simulated_drive, write_csv_logs
from test_cli_drives import assert_one_line_error, run

from graphpos.errors import FileFormatError
from graphpos.io import read_drive, write_drive
from graphpos.io.outputs import PNG_MAGIC, check_output_file
from graphpos.sim import simulate

#: A numpy warning would be a second line on the user's stderr.
pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")

#: Each command writing one file, with ``{drive}``, ``{logs}``, ``{mapping}``, ``{config}`` and ``{out}`` to fill in.
COMMANDS = {
    "simulate": ["simulate", "paper-straight", "--duration", "20", "--config", "{config}", "-o", "{out}"],
    "import-csv": ["import", "csv", "{logs}", "--mapping", "{mapping}", "-o", "{out}"],
    "calibrate": ["calibrate", "{drive}", "-o", "{out}"],
    "ranging-fit": ["ranging", "fit", "{drive}", "--truth", "-o", "{out}"],
    "ranging-table1": ["ranging", "table1", "--plot", "{out}"],
}
#: What each command writes, as the refusal of a foreign file names it.
WRITES = {"simulate": "an MCAP drive", "import-csv": "an MCAP drive", "calibrate": "a JSON object",
          "ranging-fit": "a JSON object", "ranging-table1": "a PNG image"}
#: Each command's inputs given as its output: (command, the input's key in the sources, the refusal's words).
OWN_INPUTS = [("simulate", "config", "is the command's input config file"),
              ("import-csv", "mapping", "is the command's input mapping file"),
              ("import-csv", "logs/imu.csv", "is inside the command's input CSV folder"),
              ("calibrate", "drive", "is the command's input drive"),
              ("ranging-fit", "drive", "is the command's input drive")]


@pytest.fixture(scope="module")
def sources(tmp_path_factory) -> dict[str, Path]:
    """The inputs of :data:`COMMANDS`: a 20 s simulated drive, a config file, CSV logs and their mapping."""
    folder = tmp_path_factory.mktemp("sources")
    write_drive(folder / "drive.mcap", simulate("paper-straight", seed=1, duration_s=20.0))
    (folder / "config.toml").write_text("[truth]\nrate_hz = 50.0\n")
    recorded = simulated_drive()
    logs = write_csv_logs(recorded, folder / "logs")
    return {"drive": folder / "drive.mcap", "config": folder / "config.toml", "logs": logs,
            "logs/imu.csv": logs / "imu.csv", "mapping": copy_example("mapping_csv.toml", folder, recorded)}


def _argv(command: str, sources: dict[str, Path], out: Path) -> list[str]:
    return [a.format(out=out, **sources) for a in COMMANDS[command]]


def _assert_refused(capsys, command: str, sources: dict[str, Path], out: Path, *fragments: str) -> None:
    """The command refuses ``out`` in one line naming it, and ``out`` keeps its bytes."""
    before = out.read_bytes()
    assert_one_line_error(*run(capsys, *_argv(command, sources, out)), str(out), *fragments)
    assert out.read_bytes() == before


@pytest.mark.parametrize("command, source, refusal", OWN_INPUTS)
def test_own_input_is_refused(capsys, sources, command, source, refusal):
    _assert_refused(capsys, command, sources, sources[source], refusal, "choose another output path")


@pytest.mark.parametrize("link", ["hard", "symbolic"])
@pytest.mark.parametrize("command", ["calibrate", "ranging-fit"])
def test_own_input_through_a_link_is_refused(capsys, tmp_path, sources, command, link):
    out = tmp_path / "model.json"
    if link == "hard":
        os.link(sources["drive"], out)
    else:
        out.symlink_to(sources["drive"])
    _assert_refused(capsys, command, sources, out, "is the command's input drive")


def test_a_new_file_inside_the_imported_folder_is_refused(capsys, sources):
    out = sources["logs"] / "drive.mcap"
    assert_one_line_error(*run(capsys, *_argv("import-csv", sources, out)), str(out),
                          "is inside the command's input CSV folder", "choose another output path")
    assert not out.exists()


@pytest.mark.parametrize("argv, what", [
    (["import", "plaza", "{file}", "-o", "{file}"], "Plaza file"),
    (["import", "rosbag", "{file}", "--mapping", "{mapping}", "-o", "{file}"], "bag"),
    (["import", "mrclam", "{folder}", "--robot", "1", "-o", "{file}"], "dataset folder"),
], ids=["plaza", "rosbag", "mrclam"])
def test_other_imports_refuse_their_input(capsys, tmp_path, sources, argv, what):
    folder = tmp_path / "dataset"
    folder.mkdir()
    source = folder / ("recording.bag" if what == "bag" else "recording.mat")
    source.write_bytes(b"the user's recording\n")
    assert_one_line_error(*run(capsys, *[a.format(file=source, folder=folder, mapping=sources["mapping"])
                                          for a in argv]), str(source), f"the command's input {what}")
    assert source.read_bytes() == b"the user's recording\n"


#: Existing files that no command writes.
FOREIGN = {"text": b"notes of the user\n", "json-list": b"[1, 2, 3]\n", "truncated-json": b'{"kind": "linear"'}


@pytest.mark.parametrize("content", list(FOREIGN))
@pytest.mark.parametrize("command", list(COMMANDS))
def test_foreign_file_is_refused(capsys, tmp_path, sources, command, content):
    out = tmp_path / "existing"
    out.write_bytes(FOREIGN[content])
    _assert_refused(capsys, command, sources, out, f"exists and is not {WRITES[command]}",
                    "remove it or choose another name")


@pytest.mark.parametrize("command", ["calibrate", "ranging-fit"])
def test_json_command_refuses_a_drive(capsys, tmp_path, sources, command):
    out = tmp_path / "other.mcap"
    out.write_bytes(sources["drive"].read_bytes())
    _assert_refused(capsys, command, sources, out, "exists and is not a JSON object")


@pytest.mark.parametrize("command", list(COMMANDS))
def test_own_previous_output_and_an_empty_file_are_replaced(capsys, tmp_path, sources, command):
    out = tmp_path / "output"
    out.touch()
    for _ in range(2):
        status, stdout, err = run(capsys, *_argv(command, sources, out))
        assert status == 0, err
        assert f"wrote {out}" in stdout
    if WRITES[command] == "an MCAP drive":
        assert len(read_drive(out).truth) > 0
    elif WRITES[command] == "a PNG image":
        assert out.read_bytes().startswith(PNG_MAGIC)
    else:
        assert isinstance(json.loads(out.read_text()), dict)


def test_simulate_replaces_another_drive(capsys, tmp_path, sources):
    out = tmp_path / "other.mcap"
    out.write_bytes(sources["drive"].read_bytes())
    status, _, err = run(capsys, *_argv("simulate", sources, out))
    assert status == 0, err
    assert read_drive(out).duration_s == pytest.approx(20.0, abs=0.1)


def test_special_file_is_refused_without_blocking(tmp_path):
    fifo = tmp_path / "out.mcap"
    os.mkfifo(fifo)
    with pytest.raises(FileFormatError, match="not a regular file"):
        check_output_file(fifo, kind="mcap")


def test_an_input_that_cannot_be_looked_at_is_left_to_its_reader(capsys, tmp_path):
    loop = tmp_path / "loop.mcap"
    loop.symlink_to(loop)
    assert_one_line_error(*run(capsys, "calibrate", loop, "-o", tmp_path / "profile.json"), f"{loop}: cannot read")
