"""Reading input files the same way everywhere (writing: :mod:`graphpos.io.outputs`).

- :func:`open_input`: an input file opened for reading, or one
  :class:`FileFormatError` line naming the file: missing, a folder, not a
  regular file (a FIFO, a device, a socket: refused before anything is
  read, so nothing blocks or reads forever), unreadable, empty.
- :func:`read_input`: the bytes of such a file, read in chunks of
  :data:`READ_CHUNK_BYTES`, refused without reading when larger than its
  limit (:data:`MAX_INPUT_BYTES` unless the caller gives one).

Drive files are not read whole: :mod:`graphpos.io.mcap_container` checks
their magic bytes and footer first and then walks them record by record.
"""

from __future__ import annotations

import contextlib
import os
import stat
from typing import BinaryIO, Iterator

from graphpos.errors import FileFormatError

#: Largest input file :func:`read_input` reads (a larger one is refused before reading).
MAX_INPUT_BYTES = 1 << 30
#: Bytes read at a time.
READ_CHUNK_BYTES = 1 << 20

#: Kinds of file that are not regular files, as an error names them.
_SPECIAL_FILES = (
    (stat.S_ISFIFO, "a named pipe (FIFO)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


def _require_regular(path: str | os.PathLike, mode: int) -> None:
    """FileFormatError unless ``mode`` (of ``stat``) is a regular file's."""
    if stat.S_ISDIR(mode):
        raise FileFormatError(f"{path}: is a folder, not a file")
    if not stat.S_ISREG(mode):
        kind = next((name for test, name in _SPECIAL_FILES if test(mode)), "a special file")
        raise FileFormatError(f"{path}: not a regular file: it is {kind}")


@contextlib.contextmanager
def open_input(path: str | os.PathLike, allow_empty: bool = False) -> Iterator[tuple[BinaryIO, int]]:
    """An input file opened for binary reading, and its size in bytes.

    The file is opened without blocking (a FIFO with no writer does not
    hang the open) and then checked on the open descriptor, symlinks
    resolved: only a regular file passes.

    Parameters
    ----------
    path : path-like
        The file.
    allow_empty : bool
        Accept a file of 0 bytes (an empty TOML config is valid).

    Raises
    ------
    FileFormatError
        Missing, a folder, not a regular file, unreadable, or empty.
    """
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except FileNotFoundError:
        raise FileFormatError(f"{path}: no such file") from None
    except OSError as exc:  # a folder, a socket (which cannot be opened), no permission ...
        try:
            _require_regular(path, os.stat(path).st_mode)
        except OSError:
            pass
        raise FileFormatError(f"{path}: cannot read ({exc.strerror or exc})") from None
    try:
        info = os.fstat(fd)
        _require_regular(path, info.st_mode)
        if info.st_size == 0 and not allow_empty:
            raise FileFormatError(f"{path}: empty file")
        stream = os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise
    with stream:
        yield stream, info.st_size


def read_input(path: str | os.PathLike, max_bytes: int = MAX_INPUT_BYTES, allow_empty: bool = False) -> bytes:
    """All bytes of an input file (see :func:`open_input`; never empty
    unless ``allow_empty``).

    Raises
    ------
    FileFormatError
        As :func:`open_input`, or the file is larger than ``max_bytes``.
    """
    with open_input(path, allow_empty) as (stream, size_bytes):
        if size_bytes > max_bytes:
            raise FileFormatError(f"{path}: too large to be this kind of input ({size_bytes} bytes, at most {max_bytes})")
        chunks = []
        left = size_bytes
        try:
            while left > 0:
                chunk = stream.read(min(left, READ_CHUNK_BYTES))
                if not chunk:
                    break
                chunks.append(chunk)
                left -= len(chunk)
        except OSError as exc:
            raise FileFormatError(f"{path}: cannot read ({exc.strerror or exc})") from None
    return b"".join(chunks)
