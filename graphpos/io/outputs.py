"""Writing outputs the same way everywhere: complete or absent, never half-written.

- :func:`output_folder`: the folder a command writes (``run``, ``evaluate``,
  ``reproduce``, ``layout-study``, ``fault-study``). The command writes into a
  temporary sibling folder, which is renamed into place when it ends without
  an exception; until then the output path holds what it held before.
- :func:`atomic_output`: one file (``simulate``, ``import``, ``calibrate``,
  ``ranging fit``, and every file inside an output folder), written through
  a temporary sibling file and renamed into place.
- :func:`check_output_folder`, :func:`check_output_file`: the checks both
  make, for a command to call before any work, so that an output path that
  cannot be written fails in one line at once, not after the estimators ran.
- :func:`safe_name`: a file name made from a drive's or an estimator's name.

An existing output folder is replaced only when it is empty or holds exactly
what graphpos wrote into it: the summary of every output folder (``run.json``
or ``results.json``, :data:`SUMMARIES`) lists its files under
``output_files``. A folder holding anything else (files of the user's, or an
output of an older graphpos without that list) is refused, never deleted.
The previous output is renamed away, the new one renamed in, the old one
deleted. A single output file is cared for the same way
(:func:`check_output_file` with the command's ``inputs`` and ``kind``): it
is never one of the command's inputs (nor inside an input folder), and an
existing file there is replaced only when it is empty or what the command
writes (an MCAP drive, a JSON object, :data:`OUTPUT_KINDS`), so that a
re-run replaces its own output and nothing else.

Temporaries are named ``.<target name>.<pid>-<random>.tmp`` beside their
target. One whose process is gone is debris of a killed run (SIGKILL, power
loss) and the next write to the same target deletes it, as it does the
``.<target name>.<8 random>.tmp`` files of graphpos versions that did not
name the process.

Every failure to write is a :class:`~graphpos.errors.FileFormatError` naming
the path, so the command line shows it in one line.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import shutil
import stat
import tempfile
from pathlib import Path
from typing import BinaryIO, Callable, Iterator, Mapping

from graphpos.errors import FileFormatError
from graphpos.io.files import MAX_INPUT_BYTES, READ_CHUNK_BYTES, open_input
from graphpos.io.mcap_container import MCAP0_MAGIC

#: The summary files of output folders (JSON objects): :func:`output_folder` lists the folder's files in them
#: (key ``output_files``), which marks a folder as graphpos's own.
SUMMARIES = ("run.json", "results.json")
#: Longest file name, in bytes, of the file systems we write to (ext4, APFS, NTFS).
NAME_MAX_BYTES = 255
#: Longest name :func:`safe_name` makes, in characters.
SAFE_NAME_CHARS = 64
#: How much of the target's name a temporary's name carries, in bytes (the rest of 255 is for pid and random).
_TEMP_STEM_BYTES = 200
#: What follows ``.<target name>`` in a temporary's name: ``.<pid>-<random>.tmp``, or the ``.<8 random>.tmp``
#: of older versions.
_TEMP_TAIL = r"\.(?:(?P<pid>\d+)-[a-z0-9_]+|[a-z0-9_]{8})\.tmp"


def safe_name(name: str) -> str:
    """A file name from a drive's or an estimator's name.

    Letters, digits, ``.``, ``_`` and ``-`` are kept; any other run of
    characters (path separators, spaces, newlines and other control
    characters) becomes one ``_``. Dots, underscores and dashes are stripped
    from both ends (no hidden file, no ``..``, nothing that reads as an
    option). A result longer than :data:`SAFE_NAME_CHARS` is cut and ends
    in 8 hex digits of the name's hash, so that two long names stay apart;
    ``unnamed`` when nothing is left.
    """
    text = re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._-")
    if len(text) > SAFE_NAME_CHARS:
        digest = hashlib.sha1(name.encode("utf-8", "surrogatepass")).hexdigest()[:8]
        text = f"{text[: SAFE_NAME_CHARS - 9]}-{digest}"
    return text or "unnamed"


# -- checks ----------------------------------------------------------------------------------------------------
def _stat(path: Path, shown: Path) -> os.stat_result | None:
    """``os.stat`` of ``path`` (following links), None when it does not exist."""
    try:
        return path.stat()
    except (FileNotFoundError, NotADirectoryError):
        return None
    except OSError as exc:
        raise FileFormatError(f"{shown}: cannot write ({exc.strerror or exc})") from None


def _check_names(path: Path) -> None:
    for part in path.parts:
        if len(os.fsencode(part)) > NAME_MAX_BYTES:
            raise FileFormatError(f"{path}: cannot write (a name in it is longer than {NAME_MAX_BYTES} bytes)")


def _check_writable_folder(folder: Path, shown: Path) -> None:
    if not os.access(folder, os.W_OK | os.X_OK):
        raise FileFormatError(f"{shown}: cannot write (folder {folder} is not writable)")


def check_output_file(path: str | os.PathLike, inputs: Mapping[str, str | os.PathLike | None] | None = None,
                      kind: str | None = None) -> None:
    """Check that ``path`` can be written as a file: an existing, writable
    folder, not a folder itself, none of the command's inputs, and not an
    existing file of another kind than the command writes.

    Parameters
    ----------
    path : path-like
        The output file.
    inputs : mapping of str to path-like or None, optional
        The command's inputs, each under the words naming it (``{"drive":
        args.drive}``; None: an optional input not given). ``path`` must be
        none of the input files (the same file by ``os.path.samefile`` or by
        resolved path) and not inside an input folder.
    kind : {"mcap", "json", "png"}, optional
        What the command writes (:data:`OUTPUT_KINDS`): an existing file at
        ``path`` is replaced only when it is empty or of this kind. None: any
        regular file is replaced (the files inside an output folder).

    Raises
    ------
    FileFormatError
        One line naming the path and what is wrong.
    """
    path = Path(path)
    _check_names(path)
    found = _stat(path, path)
    if found is not None and stat.S_ISDIR(found.st_mode):
        raise FileFormatError(f"{path}: cannot write (it is a folder)")
    folder = path.absolute().parent
    found_folder = _stat(folder, path)
    if found_folder is None:
        raise FileFormatError(f"{path}: cannot write (no such folder: {folder} does not exist)")
    if not stat.S_ISDIR(found_folder.st_mode):
        raise FileFormatError(f"{path}: cannot write ({folder} is not a folder)")
    _check_writable_folder(folder, path)
    for what, source in (inputs or {}).items():
        if source is not None:
            _check_not_input(path, found, what, Path(source))
    if found is not None and kind is not None:
        _check_kind(path, kind)


def _check_not_input(path: Path, found: os.stat_result | None, what: str, source: Path) -> None:
    """Refuse an output ``path`` (``found``: its ``os.stat``, or None) that is the input file ``source`` or lies
    inside the input folder ``source``.

    An input that cannot be looked at (missing, a symlink loop, no permission) is left to its reader to refuse.
    """
    try:
        source_found = source.stat()
    except OSError:
        source_found = None
    target = Path(os.path.realpath(path))
    if source_found is not None and stat.S_ISDIR(source_found.st_mode):
        if target.is_relative_to(os.path.realpath(source)):
            raise FileFormatError(f"{path}: is inside the command's input {what} {source}; choose another output path")
    elif target == Path(os.path.realpath(source)) or (
            found is not None and source_found is not None and os.path.samestat(found, source_found)):
        raise FileFormatError(f"{path}: is the command's input {what} {source}; choose another output path")


def _check_kind(path: Path, kind: str) -> None:
    """Refuse an existing output file that is neither empty nor of the ``kind`` the command writes."""
    what, holds = OUTPUT_KINDS[kind]
    with open_input(path, allow_empty=True) as (stream, size_bytes):
        if size_bytes == 0 or holds(stream, size_bytes):
            return
    raise FileFormatError(f"{path}: exists and is not {what}; remove it or choose another name")


def _holds_mcap(stream: BinaryIO, size_bytes: int) -> bool:
    """Whether the file begins with the magic bytes of MCAP."""
    return stream.read(len(MCAP0_MAGIC)) == MCAP0_MAGIC


def _holds_json_object(stream: BinaryIO, size_bytes: int) -> bool:
    """Whether the file is one JSON object (refused unread when larger than an input graphpos reads)."""
    if size_bytes > MAX_INPUT_BYTES or not stream.read(READ_CHUNK_BYTES).lstrip().startswith(b"{"):
        return False
    stream.seek(0)
    try:
        return isinstance(json.loads(stream.read()), dict)
    except (ValueError, RecursionError):  # not JSON, not UTF-8, or nested too deep to read
        return False


#: The eight bytes every PNG file begins with.
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _holds_png(stream: BinaryIO, size_bytes: int) -> bool:
    """Whether the file begins with the PNG signature."""
    return stream.read(len(PNG_MAGIC)) == PNG_MAGIC


#: What a single-file command writes (``kind`` of :func:`check_output_file`): the words naming it, and the
#: test that an existing file (open, and its size in bytes) holds it.
OUTPUT_KINDS: dict[str, tuple[str, Callable[[BinaryIO, int], bool]]] = {
    "mcap": ("an MCAP drive", _holds_mcap),
    "json": ("a JSON object", _holds_json_object),
    "png": ("a PNG image", _holds_png),
}


def check_output_folder(path: str | os.PathLike, parents: bool = True) -> None:
    """Check, without changing anything, that ``path`` can become an output folder.

    It must be an empty folder, or a previous output folder of graphpos
    holding nothing but what graphpos wrote (see the module docstring), in a
    writable folder; or absent, its first existing ancestor a writable
    folder (the missing folders are created).

    Parameters
    ----------
    path : path-like
    parents : bool
        Whether missing parent folders may be created; if not, the parent
        must exist.

    Raises
    ------
    FileFormatError
        One line naming the path and what is wrong.
    """
    path = Path(path)
    _check_names(path)
    found = _stat(path, path)
    if found is not None:
        if not stat.S_ISDIR(found.st_mode):
            raise FileFormatError(f"{path}: exists and is not a folder")
        _check_replaceable(path.resolve(), path)
        _check_writable_folder(path.resolve().parent, path)
        return
    ancestor = path.absolute().parent
    while (found := _stat(ancestor, path)) is None:
        if not parents:
            raise FileFormatError(f"{path}: cannot write (no such folder: {ancestor} does not exist)")
        ancestor = ancestor.parent
    if not stat.S_ISDIR(found.st_mode):
        raise FileFormatError(f"{path}: cannot write ({ancestor} is a file, not a folder)")
    _check_writable_folder(ancestor, path)


def _check_replaceable(folder: Path, shown: Path) -> None:
    """Refuse an existing folder holding anything graphpos did not write."""
    listed = _listed_files(folder)
    allowed = {*listed, *(str(p) for f in listed for p in Path(f).parents)}
    for root, dirs, files in os.walk(folder):
        dirs[:] = [d for d in dirs if not _stale_temporary(d)]  # debris, deleted with the folder
        for name in dirs + files:
            rel = os.path.relpath(os.path.join(root, name), folder)
            if rel not in allowed and not _stale_temporary(name):
                what = ("is not empty and is not an output of graphpos" if not listed
                        else f"holds {rel!r}, which graphpos did not write")
                raise FileFormatError(f"{shown}: the folder exists and {what}; choose another output folder "
                                      "or empty it")


def _listed_files(folder: Path) -> list[str]:
    """The files a summary of :data:`SUMMARIES` in ``folder`` lists (the summary among them), or none."""
    for name in SUMMARIES:
        try:
            files = json.loads((folder / name).read_text(encoding="utf-8"))["output_files"]
        except (OSError, ValueError, KeyError, TypeError):
            continue
        if isinstance(files, list) and name in files:
            return [f for f in files if isinstance(f, str)]
    return []


# -- temporaries -----------------------------------------------------------------------------------------------
def _temp_stem(target: Path) -> str:
    """The target's name as its temporaries carry it (cut to fit in a file name)."""
    return os.fsencode(target.name)[:_TEMP_STEM_BYTES].decode("utf-8", "ignore") or "output"


def _temp_prefix(target: Path) -> str:
    return f".{_temp_stem(target)}.{os.getpid()}-"


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    if pid <= 0:  # os.kill(0, ...) would mean our own process group
        return False
    try:
        os.kill(pid, 0)
    except (ProcessLookupError, OverflowError):
        return False
    except PermissionError:  # another user's process
        return True
    return True


def _stale_temporary(name: str, stem: str | None = None) -> bool:
    """Whether ``name`` is a temporary of our naming whose process is gone (or unknown: older versions).

    ``stem``: only temporaries of the target that :func:`_temp_stem` names so; None: of any target.
    """
    head = r"\..+" if stem is None else r"\." + re.escape(stem)
    match = re.fullmatch(head + _TEMP_TAIL, name, flags=re.DOTALL)
    return match is not None and (match["pid"] is None or not _alive(int(match["pid"])))


def clean_stale(target: Path) -> None:
    """Delete the temporaries of ``target`` left beside it by runs that were killed."""
    stem = _temp_stem(target)
    try:
        names = os.listdir(target.parent)
    except OSError:
        return
    for name in names:
        if _stale_temporary(name, stem):
            _remove(target.parent / name)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(OSError):
            path.unlink()


def _usual_mode(path: str | os.PathLike, folder: bool) -> None:
    """0777 (folder) or 0666 (file) less the umask, not the 0700/0600 of a temporary."""
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(path, (0o777 if folder else 0o666) & ~umask)


# -- writing ---------------------------------------------------------------------------------------------------
@contextlib.contextmanager
def atomic_output(path: str | os.PathLike) -> Iterator[BinaryIO]:
    """A binary stream whose content replaces ``path`` when the block ends
    without an exception (and is discarded otherwise).

    The file gets the usual permissions (0666 less the umask), not the
    temporary file's 0600. The folder must exist (:func:`check_output_file`).
    Stale temporaries of the same file are deleted first.

    Raises
    ------
    FileFormatError
        The file cannot be written: one line naming it.
    """
    path = Path(path)
    check_output_file(path)
    clean_stale(path)
    try:
        fd, tmp_name = tempfile.mkstemp(dir=path.parent, prefix=_temp_prefix(path), suffix=".tmp")
    except OSError as exc:
        raise FileFormatError(f"{path}: cannot write ({exc.strerror or exc})") from None
    try:
        with os.fdopen(fd, "wb") as stream:
            yield stream
        _usual_mode(tmp_name, folder=False)
        os.replace(tmp_name, path)
    except OSError as exc:
        Path(tmp_name).unlink(missing_ok=True)
        raise FileFormatError(f"{path}: cannot write ({exc.strerror or exc})") from None
    except BaseException:
        Path(tmp_name).unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def output_folder(path: str | os.PathLike, summary: str) -> Iterator[Path]:
    """A temporary folder to write a command's output into; it becomes ``path`` when the block ends.

    On entry: :func:`check_output_folder`, stale temporaries of ``path``
    deleted, missing parent folders and the temporary sibling folder
    created. When the block ends without an exception and the summary was
    written, the list of the folder's files is added to the summary and the
    folder renamed into place (an earlier output of graphpos there
    replaced); otherwise the temporary folder and the parents made for it
    are deleted, and ``path`` keeps what it held.

    Parameters
    ----------
    path : path-like
        The output folder.
    summary : str
        The command's summary file, one of :data:`SUMMARIES`: a JSON object
        the command writes into the top of the folder. A block that ends
        without writing it leaves nothing (there was nothing complete to
        show).

    Yields
    ------
    Path
        The temporary folder; files written into it appear at the same
        relative paths under ``path``.

    Raises
    ------
    FileFormatError
        ``path`` cannot be written or replaced: one line naming it.
    """
    shown = Path(path)
    check_output_folder(shown)
    final = shown.resolve()
    made = _make_parents(final.parent, shown)
    committed = False
    try:
        clean_stale(final)
        try:
            temp = Path(tempfile.mkdtemp(dir=final.parent, prefix=_temp_prefix(final), suffix=".tmp"))
        except OSError as exc:
            raise FileFormatError(f"{shown}: cannot write ({exc.strerror or exc})") from None
        try:
            yield temp
            if (temp / summary).is_file():
                _commit(temp, summary, final, shown)
                committed = True
        finally:
            if temp.exists():
                shutil.rmtree(temp, ignore_errors=True)
    finally:
        if not committed:
            for folder in reversed(made):
                with contextlib.suppress(OSError):
                    folder.rmdir()


def _make_parents(folder: Path, shown: Path) -> list[Path]:
    """Create ``folder`` and its missing parents; the ones created, outermost first."""
    missing = []
    while _stat(folder, shown) is None:
        missing.append(folder)
        folder = folder.parent
    made = []
    try:
        for folder in reversed(missing):
            folder.mkdir()
            made.append(folder)
    except OSError as exc:
        for folder in reversed(made):
            with contextlib.suppress(OSError):
                folder.rmdir()
        raise FileFormatError(f"{shown}: cannot write ({exc.strerror or exc})") from None
    return made


def _commit(temp: Path, summary: str, final: Path, shown: Path) -> None:
    """List ``temp``'s files in its summary and rename it to ``final``, replacing an earlier output there."""
    files = sorted(os.path.relpath(os.path.join(root, f), temp) for root, _, names in os.walk(temp) for f in names)
    record = json.loads((temp / summary).read_text(encoding="utf-8"))
    with atomic_output(temp / summary) as stream:
        stream.write((json.dumps({**record, "output_files": files}, indent=1) + "\n").encode())
    _usual_mode(temp, folder=True)
    try:
        if _stat(final, shown) is None:
            os.rename(temp, final)
            return
        _check_replaceable(final, shown)  # again: the run may have taken hours
        old = Path(tempfile.mkdtemp(dir=final.parent, prefix=_temp_prefix(final), suffix=".tmp"))
        os.replace(final, old)
        os.rename(temp, final)
    except OSError as exc:
        raise FileFormatError(f"{shown}: cannot write ({exc.strerror or exc})") from None
    shutil.rmtree(old, ignore_errors=True)
