"""Importer of CSV logs, through a mapping file (:mod:`graphpos.io.mapping`).

A data logger writes one CSV file per sensor, or one wide file for several.
Each channel section of the mapping names its ``file`` (relative to the
folder given on the command line), its ``time`` column, its ``fields``
(input -> column) and their ``units``; the first line of a file names its
columns. In a file that several channels share, a row whose cells of a
channel's fields are all empty holds no reading of that channel and is
skipped (the time column does not count). Every other cell read must be a
number, or empty (or NaN): where the drive column is optional it is absent
(NaN), elsewhere it is a gap in that sensor, its row dropped and counted
in the drive's ``import_notes`` (the time, ids and ``inf`` are refused);
an error names the file, the line and the column.
"""

from __future__ import annotations

import os
from pathlib import Path

from graphpos.drive import Drive
from graphpos.errors import ConfigError, FileFormatError
from graphpos.io.mapping import ChannelMapping, RawChannel, build_drive, load_mapping, read_csv_table

_Table = tuple[list[str], list[list[str]], list[int]]


def _raw(cm: ChannelMapping, path: Path, table: _Table) -> RawChannel:
    """The cells of one channel's columns, rows without its readings skipped."""
    header, rows, lines = table
    fields = {**cm.read_fields(), "time": cm.time, **({"arrival": cm.arrival} if cm.arrival else {})}
    index = {}
    for name, column in fields.items():
        if isinstance(column, str):
            if column not in header:
                raise ConfigError(f"{cm.where}: column '{column}' ({name}) is not in {path} (its columns: {', '.join(header)})")
            index[name] = header.index(column)
    readings = [j for name, j in index.items() if name not in ("time", "arrival")]
    kept = [i for i, row in enumerate(rows) if not readings or any(row[j].strip() for j in readings)]
    values = {name: [rows[i][j] for i in kept] for name, j in index.items()}
    kept_lines = [lines[i] for i in kept]
    return RawChannel(cm, str(path), fields, values, lambda row: f"line {kept_lines[row]}", "column")


def import_csv(folder: str | os.PathLike, mapping: str | os.PathLike) -> Drive:
    """Read CSV logs as a drive, through a mapping file.

    Parameters
    ----------
    folder : path-like
        The folder holding the files the mapping names.
    mapping : path-like
        The mapping file (TOML; format: :mod:`graphpos.io.mapping`).

    Returns
    -------
    Drive
        Named after the folder; ``params`` records the source, the mapping,
        each channel's file and ``import_notes`` (rows dropped as gaps or
        repeats, sorted, or at one time with other values).

    Raises
    ------
    FileFormatError
        A file cannot be read, or a cell is not valid (naming the file, the
        line and the column).
    ConfigError
        The mapping is wrong, or names a column a file does not have.
    """
    loaded = load_mapping(mapping, "csv")
    folder = Path(folder)
    if not folder.is_dir():
        raise FileFormatError(f"{folder}: {'not a folder' if folder.exists() else 'no such folder'}")
    tables: dict[tuple[Path, str], _Table] = {}
    raws = []
    for cm in loaded.channels.values():
        path = folder / cm.source
        if (path, cm.delimiter) not in tables:
            tables[path, cm.delimiter] = read_csv_table(path, cm.delimiter)
        raws.append(_raw(cm, path, tables[path, cm.delimiter]))
    params = {"source": "csv", "folder": folder.resolve().name, "mapping": loaded.path.name,
              "files": {cm.channel: cm.source for cm in loaded.channels.values()}}
    return build_drive(loaded, raws, name=folder.resolve().name, params=params)
