"""Output paths and killed runs (issue 14, items 6 and 10).

- An output path that cannot be written (an existing file, a folder under a
  file, a read-only parent, a name longer than the file system takes) gives
  one line on stderr and status 2 before any work, and leaves nothing.
- File names made from drive and estimator names are safe: bounded, no
  separators, no control characters, no hidden or ``..`` names.
- A newline (or other control character) in a file name keeps the error
  message on one line.
- Outputs are complete or absent: a killed run leaves only temporaries of
  our naming, never a half output at the final path, and the next run
  removes them; an existing output folder is replaced when it holds only
  what graphpos wrote, refused when it holds anything else.

"Before any work" is shown by giving a drive file that does not exist: the
error names the output path, not the drive.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from graphpos.cli import main
from graphpos.io import write_drive
from graphpos.io.outputs import SAFE_NAME_CHARS, check_output_file, output_folder, safe_name
from graphpos.errors import FileFormatError
from graphpos.sim import simulate
from output_files import export_files  # tests/io, on the import path (conftest.py)

ROOT = os.geteuid() == 0
DEAD_PID = 99999999  # above any pid_max: no such process


@pytest.fixture(scope="module")
def drive_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("drive") / "drive.mcap"
    write_drive(path, simulate("paper-straight", seed=1, duration_s=12.0))
    return path


def cli(capsys, *argv) -> tuple[int, list[str], str]:
    try:
        status = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse
        status = exc.code
    out, err = capsys.readouterr()
    return status, err.strip().splitlines(), out


def _tree(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


def assert_refused(status, err, command, *words) -> None:
    assert status == 2, err
    assert len(err) == 1 and err[0].startswith(f"graphpos {command}: error: "), err
    assert "Traceback" not in err[0] and all(w in err[0] for w in words), (words, err)


# -- output folders that cannot be written -------------------------------------------------------------------------
FOLDER_COMMANDS = {
    "run": ["run", "{drive}", "-e", "dr", "--out-dir", "{out}"],
    "evaluate": ["evaluate", "{drive}", "-e", "dr", "-o", "{out}", "--workers", "1", "--no-progress"],
    "reproduce": ["reproduce", "--quick", "--plaza", "{drive}", "-o", "{out}", "--no-progress"],
    "layout-study": ["layout-study", "nope", "-o", "{out}", "--no-progress"],
    "fault-study": ["fault-study", "nope", "-o", "{out}", "--no-progress"],
}


def _bad_output(tmp_path: Path, case: str) -> tuple[Path, str]:
    """An output folder path that cannot be written, and a word of the error line."""
    (tmp_path / "file").write_text("mine")
    if case == "existing-file":
        return tmp_path / "file", "not a folder"
    if case == "under-a-file":
        return tmp_path / "file" / "out", "is a file, not a folder"
    if case == "long-name":
        return tmp_path / ("x" * 400), "longer than 255 bytes"
    if case == "long-name-inside":
        return tmp_path / ("y" * 300) / "out", "longer than 255 bytes"
    if case == "folder-of-other-files":
        (tmp_path / "theirs").mkdir()
        (tmp_path / "theirs" / "notes.txt").write_text("do not delete")
        return tmp_path / "theirs", "not an output of graphpos"
    if case == "read-only-parent":
        (tmp_path / "locked").mkdir()
        (tmp_path / "locked").chmod(0o555)
        return tmp_path / "locked" / "out", "not writable"
    raise AssertionError(case)


@pytest.mark.parametrize("command", list(FOLDER_COMMANDS))
@pytest.mark.parametrize("case", ["existing-file", "under-a-file", "long-name", "long-name-inside",
                                  "folder-of-other-files", "read-only-parent"])
def test_bad_output_folder_is_refused_before_any_work(capsys, tmp_path, command, case):
    if case == "read-only-parent" and ROOT:
        pytest.skip("root ignores permissions")
    out, word = _bad_output(tmp_path, case)
    before = _tree(tmp_path)
    argv = [a.format(drive=tmp_path / "no-such.mcap", out=out) for a in FOLDER_COMMANDS[command]]
    status, err, _ = cli(capsys, *argv)
    assert_refused(status, err, command, word)
    assert "no-such" not in err[0], "the drive was read before the output path was checked"
    assert _tree(tmp_path) == before
    assert (tmp_path / "file").read_text() == "mine"


FILE_COMMANDS = {
    "simulate": ["simulate", "paper-straight", "--duration", "3", "-o", "{out}"],
    "import plaza": ["import", "plaza", "{drive}", "-o", "{out}"],
    "calibrate": ["calibrate", "{drive}", "-o", "{out}"],
    "ranging fit": ["ranging", "fit", "{drive}", "--truth", "-o", "{out}"],
}


@pytest.mark.parametrize("command", list(FILE_COMMANDS))
@pytest.mark.parametrize("case", ["folder", "under-a-file", "missing-folder", "long-name", "read-only-parent"])
def test_bad_output_file_is_refused_before_any_work(capsys, tmp_path, command, case):
    if case == "read-only-parent" and ROOT:
        pytest.skip("root ignores permissions")
    (tmp_path / "file").write_text("mine")
    out, word = {
        "folder": (tmp_path, "it is a folder"),
        "under-a-file": (tmp_path / "file" / "x.out", "not a folder"),
        "missing-folder": (tmp_path / "nowhere" / "x.out", "does not exist"),
        "long-name": (tmp_path / ("x" * 300 + ".out"), "longer than 255 bytes"),
        "read-only-parent": (tmp_path / "locked" / "x.out", "not writable"),
    }[case]
    if case == "read-only-parent":
        (tmp_path / "locked").mkdir(mode=0o555)
    before = _tree(tmp_path)
    argv = [a.format(drive=tmp_path / "no-such.in", out=out) for a in FILE_COMMANDS[command]]
    status, err, _ = cli(capsys, *argv)
    assert_refused(status, err, command, word)
    assert "no-such" not in err[0]
    assert _tree(tmp_path) == before


def test_output_checks_in_process():
    with pytest.raises(FileFormatError, match="it is a folder"):
        check_output_file(Path("/"))
    with pytest.raises(FileFormatError, match="does not exist"):
        check_output_file(Path("/no/such/folder/x.mcap"))


# -- names -------------------------------------------------------------------------------------------------------
@given(st.text(max_size=500))
@settings(max_examples=300, deadline=None)
def test_safe_name_is_one_plain_file_name(name):
    safe = safe_name(name)
    assert 0 < len(safe) <= SAFE_NAME_CHARS
    assert safe not in (".", "..") and not safe.startswith((".", "-"))
    assert all(c.isascii() and (c.isalnum() or c in "._-") for c in safe), safe


@given(st.text(min_size=SAFE_NAME_CHARS + 1, max_size=300), st.text(min_size=1, max_size=5))
@settings(max_examples=100, deadline=None)
def test_long_names_stay_apart(name, tail):
    """Two names cut to the same length differ in their hash (shorter names differing only in unsafe characters
    may meet: evaluate numbers such drives' folders)."""
    long = "a" * (SAFE_NAME_CHARS + 1)
    assert safe_name(long + name) != safe_name(long + name + tail)


@pytest.mark.filterwarnings("ignore:Glyph")  # the plot titles show the drive's name, control characters and all
@pytest.mark.parametrize("name", ["x" * 400, "a/b/../../c", "..", ".hidden", "line\nbreak", "tab\there", "/", "",
                                  "\x1b[31mred", "dróga 7", "con:aux?*"])
def test_drive_names_make_safe_files(capsys, tmp_path, name):
    """evaluate names a drive's folder after the drive: every such file stays inside the output folder."""
    drive = tmp_path / "d.mcap"
    write_drive(drive, simulate("paper-straight", seed=1, duration_s=6.0).replace(name=name))
    out = tmp_path / "eval"
    status, err, _ = cli(capsys, "evaluate", drive, "-e", "dr", "-o", out, "--workers", "1", "--no-progress")
    assert status == 0, err
    assert {p.name for p in tmp_path.iterdir()} == {"d.mcap", "eval"}
    subs = [p for p in out.iterdir() if p.is_dir()]
    assert len(subs) == 1 and subs[0].name == safe_name(name)
    assert (subs[0] / "estimates.mcap").is_file() and (subs[0] / "dr.csv").is_file()
    for path in out.rglob("*"):
        assert len(path.name.encode()) <= 255 and "\n" not in path.name


@pytest.mark.parametrize("name", ["bad\nname.mcap", "esc\x1bape.mcap", "tab\tname.mcap", "\udcff.mcap"])
def test_control_characters_in_an_input_name_keep_one_line(capsys, tmp_path, name):
    for content in (None, b"not an mcap"):
        path = tmp_path / name
        if content is not None:
            path.write_bytes(content)
        status, err, _ = cli(capsys, "run", path, "-e", "dr", "--out-dir", tmp_path / "out")
        assert_refused(status, err, "run")
        assert repr(name)[1:-1].split(".")[0] in err[0], err
        status, err, _ = cli(capsys, "info", path)
        assert_refused(status, err, "info")


def test_control_characters_in_an_output_name(capsys, tmp_path, drive_file):
    """An output folder named with a newline is valid: it is written, and the lines printed stay lines."""
    out = tmp_path / "out\nput"
    status, err, stdout = cli(capsys, "run", drive_file, "-e", "dr", "--out-dir", out)
    assert status == 0, err
    assert (out / "dr.csv").is_file()
    assert stdout.count("\n") == 1 and "out\\nput" in stdout


# -- replacing an earlier output ---------------------------------------------------------------------------------
def test_rerun_replaces_our_own_output(capsys, tmp_path, drive_file):
    out = tmp_path / "out"
    assert cli(capsys, "run", drive_file, "-e", "dr", "-e", "rfid-ekf", "--out-dir", out)[0] == 0
    assert (out / "rfid-ekf.csv").is_file()
    assert cli(capsys, "run", drive_file, "-e", "dr", "--out-dir", out)[0] == 0
    assert {p.name for p in out.iterdir()} == {*export_files(["dr"]), "run.json"}
    assert _complete(out, "run.json")
    # an evaluate output is ours too, and the other way round
    assert cli(capsys, "evaluate", drive_file, "-e", "dr", "-o", out, "--workers", "1", "--no-progress")[0] == 0
    assert (out / "results.json").is_file() and not (out / "run.json").exists()
    assert cli(capsys, "run", drive_file, "-e", "dr", "--out-dir", out)[0] == 0
    assert not (out / "results.json").exists()


def test_existing_empty_folder_becomes_the_output(capsys, tmp_path, drive_file):
    out = tmp_path / "out"
    out.mkdir()
    assert cli(capsys, "run", drive_file, "-e", "dr", "--out-dir", out)[0] == 0
    assert (out / "dr.csv").is_file()
    assert oct(out.stat().st_mode & 0o777) != oct(0o700), "the temporary folder's mode leaked"


@pytest.mark.parametrize("extra", ["notes.txt", "sub/notes.txt", ".hidden"])
def test_our_output_with_a_file_of_the_user_is_refused(capsys, tmp_path, drive_file, extra):
    out = tmp_path / "out"
    assert cli(capsys, "run", drive_file, "-e", "dr", "--out-dir", out)[0] == 0
    (out / extra).parent.mkdir(exist_ok=True)
    (out / extra).write_text("mine")
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    status, err, _ = cli(capsys, "run", drive_file, "-e", "dr", "--out-dir", out)
    assert_refused(status, err, "run", "graphpos did not write", extra.split("/")[0])
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before


def test_outputs_of_older_versions_are_refused_but_their_debris_is_not(capsys, tmp_path, drive_file):
    """A folder of CSVs without a listing (an older run killed between CSVs) is not ours to delete; a folder
    holding only temporaries of the old naming (``.NAME.<8 random>.tmp``) is debris, and is replaced."""
    old = tmp_path / "old"
    old.mkdir()
    (old / "dr.csv").write_text("t_s\n")
    status, err, _ = cli(capsys, "run", drive_file, "-e", "dr", "--out-dir", old)
    assert_refused(status, err, "run", "not an output of graphpos")
    debris = tmp_path / "debris"
    debris.mkdir()
    (debris / ".estimates.mcap.k2j4h6g8.tmp").write_bytes(b"MCAP half")
    assert cli(capsys, "run", drive_file, "-e", "dr", "--out-dir", debris)[0] == 0
    assert not [p for p in debris.iterdir() if p.name.endswith(".tmp")]


# -- killed runs -------------------------------------------------------------------------------------------------
def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.endswith(".tmp"))


def _complete(out: Path, summary: str) -> bool:
    """The output folder is complete: its summary lists exactly the files in it."""
    listed = json.loads((out / summary).read_text())["output_files"]
    return sorted(listed) == sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file())


def test_stale_temporaries_are_removed_by_the_next_run(capsys, tmp_path, drive_file):
    out = tmp_path / "out"
    dead_folder = tmp_path / f".out.{DEAD_PID}-abcd1234.tmp"  # a run killed while writing
    dead_folder.mkdir()
    (dead_folder / "dr.csv").write_text("t_s\n")
    legacy = tmp_path / ".out.zz9kq2ab.tmp"  # the naming of older versions
    legacy.write_text("half")
    alive = tmp_path / f".out.{os.getpid()}-abcd1234.tmp"  # a run still going (this process)
    alive.mkdir()
    other = tmp_path / f".other.{DEAD_PID}-abcd1234.tmp"  # another target's: not ours to judge here
    other.mkdir()
    theirs = tmp_path / ".out.backup.tmp"  # not our naming
    theirs.write_text("user")
    assert cli(capsys, "run", drive_file, "-e", "dr", "--out-dir", out)[0] == 0
    assert _leftovers(tmp_path) == sorted([alive.name, other.name, theirs.name])
    assert _complete(out, "run.json")


def test_stale_temporaries_of_a_file_are_removed(capsys, tmp_path):
    target = tmp_path / "sim.mcap"
    (tmp_path / f".sim.mcap.{DEAD_PID}-abcd1234.tmp").write_bytes(b"half")
    (tmp_path / ".sim.mcap.ab12cd34.tmp").write_bytes(b"half, old naming")
    (tmp_path / f".sim.mcap.{os.getpid()}-abcd1234.tmp").write_bytes(b"being written")
    status, err, _ = cli(capsys, "simulate", "paper-straight", "--duration", "2", "-o", target)
    assert status == 0, err
    assert _leftovers(tmp_path) == [f".sim.mcap.{os.getpid()}-abcd1234.tmp"]


def _child(code: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_sigkill_while_writing_leaves_no_output(capsys, tmp_path, drive_file):
    """A command killed half-way through writing its folder: nothing at the output path, only a temporary
    beside it, which the next run deletes."""
    out = tmp_path / "out"
    child = _child(
        "import sys, time\n"
        "from pathlib import Path\n"
        "from graphpos.io.outputs import output_folder\n"
        f"with output_folder(Path({str(out)!r}), 'run.json') as folder:\n"
        "    (folder / 'dr.csv').write_text('t_s\\n')\n"
        "    print('written', flush=True)\n"
        "    time.sleep(60)\n")
    try:
        assert child.stdout.readline().strip() == "written"
        child.send_signal(signal.SIGKILL)
        child.wait(10)
    finally:
        child.kill()
    assert not out.exists()
    assert [name.startswith(f".out.{child.pid}-") for name in _leftovers(tmp_path)] == [True]
    assert cli(capsys, "run", drive_file, "-e", "dr", "--out-dir", out)[0] == 0
    assert _leftovers(tmp_path) == [] and _complete(out, "run.json")


#: Code run in the child before ``graphpos run``: pause at a moment of writing, say so, and wait to be killed.
PAUSES = {
    "between-csvs": (
        "import graphpos.io.exports as m\n"
        "real = m.write_atomically\n"
        "def pause(path, data):\n"
        "    real(path, data)\n"
        "    print('paused', flush=True)\n"
        "    time.sleep(60)\n"
        "m.write_atomically = pause\n"),
    "inside-the-mcap": (
        "import graphpos.io.mcap_drive as m\n"
        "def pause(stream, *args):\n"
        "    stream.write(b'\\x89MCAP0\\r\\n' + bytes(5000))\n"
        "    stream.flush()\n"
        "    print('paused', flush=True)\n"
        "    time.sleep(60)\n"
        "m.write_mcap = pause\n"),
}


@pytest.mark.parametrize("earlier", [False, True], ids=["first-run", "rerun"])
@pytest.mark.parametrize("moment", list(PAUSES))
def test_sigkill_during_a_real_run_never_shows_half_an_output(capsys, tmp_path, drive_file, moment, earlier):
    """``graphpos run`` killed while it writes: the output path holds nothing, or the earlier complete output,
    while it writes and after it is killed; the next run deletes the debris."""
    out = tmp_path / "out"
    if earlier:
        assert cli(capsys, "run", drive_file, "-e", "rfid-ekf", "--out-dir", out)[0] == 0
    child = _child("import sys, time\n" + PAUSES[moment] + "from graphpos.cli import main\n"
                   f"sys.exit(main(['run', {str(drive_file)!r}, '-e', 'dr', '-e', 'fusion-ekf', "
                   f"'--out-dir', {str(out)!r}]))\n")
    try:
        assert child.stdout.readline().strip() == "paused", child.stderr.read()
        for _ in range(2):  # while it writes, then once killed
            if earlier:
                assert _complete(out, "run.json") and (out / "rfid-ekf.csv").is_file()
            else:
                assert not out.exists()
            child.send_signal(signal.SIGKILL)
            child.wait(10)
    finally:
        child.kill()
    assert [name.startswith(f".out.{child.pid}-") for name in _leftovers(tmp_path)] == [True]
    assert cli(capsys, "run", drive_file, "-e", "dr", "--out-dir", out)[0] == 0
    assert _leftovers(tmp_path) == [] and _complete(out, "run.json")
    assert {p.name for p in out.iterdir()} == {*export_files(["dr"]), "run.json"}


def test_an_exception_inside_leaves_nothing(tmp_path):
    out = tmp_path / "a" / "b" / "out"
    with pytest.raises(KeyboardInterrupt):
        with output_folder(out, "run.json") as folder:
            (folder / "run.json").write_text("{}")
            raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == [], "the parents made for the output are left"
