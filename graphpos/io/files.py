"""Reading input files and writing output files the same way everywhere.

- :func:`read_input`: a file's bytes, or one :class:`FileFormatError` line
  naming the file (missing, a folder, unreadable, empty).
- :func:`atomic_output`: write through a temporary file in the same folder
  and rename it into place, so a failure never leaves a partial file that
  looks whole; OS errors become :class:`FileFormatError`.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import BinaryIO, Iterator

from graphpos.errors import FileFormatError


def read_input(path: Path) -> bytes:
    """All bytes of an input file (never empty)."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise FileFormatError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise FileFormatError(f"{path}: is a folder, not a file") from None
    except OSError as exc:
        raise FileFormatError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if not data:
        raise FileFormatError(f"{path}: empty file")
    return data


@contextlib.contextmanager
def atomic_output(path: Path) -> Iterator[BinaryIO]:
    """A binary stream whose content replaces ``path`` when the block ends
    without an exception (and is discarded otherwise).

    The file gets the usual permissions (0666 less the umask), not the
    temporary file's 0600. The folder must exist.
    """
    if path.is_dir():
        raise FileFormatError(f"{path}: cannot write (it is a folder)")
    if not path.parent.is_dir():
        raise FileFormatError(f"{path}: cannot write (folder {path.parent} does not exist)")
    try:
        fd, tmp_name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as exc:
        raise FileFormatError(f"{path}: cannot write ({exc.strerror or exc})") from None
    try:
        with os.fdopen(fd, "wb") as stream:
            yield stream
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp_name, 0o666 & ~umask)
        os.replace(tmp_name, path)
    except OSError as exc:
        Path(tmp_name).unlink(missing_ok=True)
        raise FileFormatError(f"{path}: cannot write ({exc.strerror or exc})") from None
    except BaseException:
        Path(tmp_name).unlink(missing_ok=True)
        raise
