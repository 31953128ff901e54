"""Issue 14, item 8: the reader does not trust the file system.

What is not a regular file (a FIFO, a device, a socket; symlinks resolved)
is refused before anything is read, so nothing blocks or reads forever; a
drive's magic bytes and footer are checked before the rest, and its records
are read one at a time, so a huge broken file is refused within seconds.
Every reader of a user file is covered: drives (``info``, ``run``,
``evaluate``), a Plaza .mat, an MRCLAM folder, a TOML config, a range
model, a sensor profile. The FIFO cases run the command in a subprocess
with a timeout (a hang fails the test instead of stalling the suite).
"""

from __future__ import annotations

import os
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_hardening_bad_input import DRIVE_COMMANDS, _check
from test_mrclam import synthetic_mrclam

from graphpos.errors import FileFormatError
from graphpos.io import read_drive
from graphpos.io.files import READ_CHUNK_BYTES, read_input

#: A numpy warning would be a second line on the user's stderr.
pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")
COMMANDS = ("info", "run", "evaluate")
#: A test of one file must finish well within this (the old reader took minutes on a 2 GiB file).
QUICK_S = 5.0
SPARSE_BYTES = 2 * 1024**3
MAGIC = b"\x89MCAP0\r\n"


def _subprocess(argv: list[str], cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "graphpos", *argv], cwd=cwd, capture_output=True, text=True, timeout=20)


def _assert_refused(done: subprocess.CompletedProcess, names: str) -> None:
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2, done.stderr
    assert len(lines) == 1 and "Traceback" not in done.stderr, done.stderr
    assert names in lines[0], lines[0]


# -- a FIFO never blocks a reader ---------------------------------------------------------------------------------
FIFO_COMMANDS = {
    **{c: DRIVE_COMMANDS[c] for c in COMMANDS},
    "import-plaza": ["import", "plaza", "{file}", "-o", "{out}/plaza.mcap"],
    "simulate-config": ["simulate", "paper-straight", "--duration", "3", "--config", "{file}", "-o", "{out}/sim.mcap"],
    "range-model": ["run", "{drive}", "-e", "dr", "--range-model", "{file}", "--out-dir", "{out}/run"],
    "evaluate-range-model": ["evaluate", "{drive}", "-e", "dr", "--range-model", "{file}", "-o", "{out}/eval",
                             "--workers", "1", "--no-progress"],
    "profile": ["run", "{drive}", "-e", "dr", "--profile", "{file}", "--out-dir", "{out}/run"],
}


@pytest.mark.parametrize("command", list(FIFO_COMMANDS))
def test_fifo_is_refused_without_blocking(tmp_path, samples, command):
    fifo = tmp_path / "x.mcap"
    os.mkfifo(fifo)
    (tmp_path / "out").mkdir()
    argv = [a.format(file=fifo, out=tmp_path / "out", drive=samples["sim"]) for a in FIFO_COMMANDS[command]]
    _assert_refused(_subprocess(argv, tmp_path), "x.mcap: not a regular file: it is a named pipe (FIFO)")
    assert not any((tmp_path / "out").iterdir())


def test_fifo_in_an_mrclam_folder(tmp_path):
    synthetic_mrclam(tmp_path / "data")
    odometry = tmp_path / "data" / "Robot1_Odometry.dat"
    odometry.unlink()
    os.mkfifo(odometry)
    done = _subprocess(["import", "mrclam", "data", "--robot", "1", "-o", "out.mcap"], tmp_path)
    _assert_refused(done, "Robot1_Odometry.dat: not a regular file")
    assert not (tmp_path / "out.mcap").exists()


def test_symlink_to_dev_zero_in_a_subprocess(tmp_path):
    (tmp_path / "z.mcap").symlink_to("/dev/zero")
    _assert_refused(_subprocess(["info", "z.mcap"], tmp_path), "z.mcap: not a regular file: it is a character device")


# -- other files that are not regular, and huge broken files --------------------------------------------------------
def _symlink(target: str):
    def build(path: Path) -> Path:
        path.symlink_to(target)
        return path

    return build


def _socket(path: Path) -> Path:
    server = socket.socket(socket.AF_UNIX)
    server.bind(str(path))
    server.close()
    return path


def _sparse(head: bytes, tail: bytes = b"") -> callable:
    """A 2 GiB file that is ``head``, zeros (not written: a hole) and ``tail``."""

    def build(path: Path) -> Path:
        with open(path, "wb") as f:
            f.write(head)
            f.truncate(SPARSE_BYTES - len(tail))
            f.seek(0, os.SEEK_END)
            f.write(tail)
        return path

    return build


def _footer() -> bytes:
    """A footer record and the closing magic bytes (no summary)."""
    return struct.pack("<BQQQI", 0x02, 20, 0, 0, 0) + MAGIC


#: case -> (builder(path) -> path, what the one line says)
CASES = {
    "symlink-dev-zero": (_symlink("/dev/zero"), "not a regular file: it is a character device"),
    "symlink-dev-null": (_symlink("/dev/null"), "not a regular file: it is a character device"),
    "socket": (_socket, "not a regular file: it is a socket"),
    "dangling-symlink": (_symlink("nowhere.mcap"), "no such file"),
    "symlink-loop": (lambda p: _symlink(p.name)(p), "cannot read"),
    "magic-then-zeros": (_sparse(MAGIC), "truncated MCAP file (no footer"),
    "zeros-with-footer": (_sparse(MAGIC, _footer()), "corrupt MCAP file: no record at byte 8"),
    "record-past-the-end": (_sparse(MAGIC + struct.pack("<BQ", 0x03, 2**62), _footer()),
                            "corrupt MCAP file: a record (opcode 0x3) runs past the end of the file"),
    "implausible-record": (_sparse(MAGIC + struct.pack("<BQ", 0x0C, SPARSE_BYTES - 64), _footer()),
                           "corrupt MCAP file: a record (opcode 0xc) claims an implausible length"),
    "zeros-only": (_sparse(b""), "not an MCAP file"),
}


@pytest.mark.parametrize("command", COMMANDS)
@pytest.mark.parametrize("case", list(CASES))
def test_special_or_huge_file_is_refused_quickly(capsys, tmp_path, samples, case, command):
    build, names = CASES[case]
    path = build(tmp_path / f"{case}.mcap")
    started = time.perf_counter()
    _check(capsys, tmp_path, command, DRIVE_COMMANDS[command], path, names, valid=False)
    assert time.perf_counter() - started < QUICK_S


def test_a_huge_input_is_refused_before_reading(tmp_path):
    """read_input refuses a file over its limit before reading a byte, and reads one under it in chunks."""
    path = _sparse(b"{")(tmp_path / "model.json")
    started = time.perf_counter()
    with pytest.raises(FileFormatError, match=r"model\.json: too large .*2147483648 bytes"):
        read_input(path)
    assert time.perf_counter() - started < QUICK_S
    data = os.urandom(3 * READ_CHUNK_BYTES + 17)
    (tmp_path / "chunks.bin").write_bytes(data)
    assert read_input(tmp_path / "chunks.bin") == data


def test_valid_drive_through_a_symlink_reads(tmp_path, samples):
    (tmp_path / "link.mcap").symlink_to(samples["sim"])
    assert read_drive(tmp_path / "link.mcap").name == read_drive(samples["sim"]).name
