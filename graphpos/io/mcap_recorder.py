"""An MCAP file written while ``graphpos live`` runs, readable at any moment.

:class:`McapRecorder` writes the records of :mod:`graphpos.io.mcap_container`
as they come: header, metadata, schemas and channels at once (outside any
chunk), messages into a zstd chunk held in memory that is written with its
message indexes when it reaches its size, when it has been open for its
interval of wall time, or on :meth:`McapRecorder.flush`; the summary
(schemas, channels, statistics, chunk and metadata indexes) and the footer
on :meth:`McapRecorder.close`. Every record reaches the operating system as
soon as it is written, so a writer stopped in any way (even SIGKILL) loses
only its open chunk, and the file up to its last complete chunk reads
(:func:`graphpos.io.mcap_container.read_mcap_contents` reads a file without
footer only when its header's library starts with ``graphpos live``, as
the recorder's does by default).

Messages are JSON (message encoding ``json``, schema encoding
``jsonschema``), encoded one row at a time by :mod:`graphpos.io.mcap_drive`
(:func:`~graphpos.io.mcap_drive.encode_row` ...). Log times need not grow
from message to message (a late reading): each chunk's index carries its
earliest and latest.

The ``mcap`` package's ``Writer`` is not used: it closes a chunk only by
size, with no public way to close one on demand.
"""

from __future__ import annotations

import contextlib
import json
import os
import threading
import time
from pathlib import Path
from types import TracebackType
from typing import Any, Iterator

import numpy as np
import zstandard
from mcap.records import Channel, ChunkIndex, MetadataIndex, Schema, Statistics

from graphpos import __version__
from graphpos.errors import FileFormatError
from graphpos.io.mcap_container import (CHUNK_ZSTD_LEVEL, LIVE_LIBRARY, RecordOutput, finish_file, message_record,
                                        start_file, write_chunk, write_metadata)
from graphpos.io.outputs import check_output_file

#: Uncompressed bytes of message records at which a chunk is closed.
CHUNK_SIZE_BYTES = 256 * 1024
#: Wall time after which a chunk is closed at the next write.
CHUNK_INTERVAL_S = 1.0


class McapRecorder:
    """An incremental MCAP writer whose file reads up to its last complete
    chunk at any moment, even after its process is killed.

    Thread-safe: every method holds one lock, so several threads may write.

    Parameters
    ----------
    path : path-like
        The file (replaced if it exists); its folder must exist.
    library : str
        The header's library string. A file whose library starts with
        ``graphpos live`` reads without footer; another does not.
    chunk_size_bytes : int
        A chunk is closed when its message records reach this many bytes
        (uncompressed).
    chunk_interval_s : float
        ... or at a write when its first message is older than this (wall
        time, monotonic clock). ``graphpos live`` also calls :meth:`flush`
        from a timer, for quiet spells.

    Raises
    ------
    FileFormatError
        The file cannot be written (here or by any later method): one line
        naming it.
    ValueError
        A chunk size under 1 byte or a negative interval; by a later method:
        the recorder is closed, an unknown channel id, a time stamp outside
        the uint64 range (programming errors of the caller).
    """

    def __init__(self, path: str | os.PathLike, library: str = f"{LIVE_LIBRARY} {__version__}",
                 chunk_size_bytes: int = CHUNK_SIZE_BYTES, chunk_interval_s: float = CHUNK_INTERVAL_S) -> None:
        if chunk_size_bytes < 1 or not chunk_interval_s >= 0:
            raise ValueError(f"chunk_size_bytes ({chunk_size_bytes}) must be positive and "
                             f"chunk_interval_s ({chunk_interval_s}) not negative")
        self.path = Path(path)
        self.chunk_size_bytes = int(chunk_size_bytes)
        self.chunk_interval_s = float(chunk_interval_s)
        self._lock = threading.Lock()
        self._compressor = zstandard.ZstdCompressor(level=CHUNK_ZSTD_LEVEL)
        self._schemas: dict[bytes, Schema] = {}
        self._channels: dict[int, Channel] = {}
        self._counts: dict[int, int] = {}
        self._chunk_indexes: list[ChunkIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._start_ns: int | None = None
        self._end_ns = 0
        self._new_chunk()
        self._closed = False
        check_output_file(self.path)
        with self._writing():
            stream = open(self.path, "wb")
            try:
                self._out = RecordOutput(stream)
                start_file(self._out, library)
                stream.flush()
            except BaseException:
                stream.close()
                raise

    # -- writing ------------------------------------------------------------
    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """Write a metadata record (``graphpos.drive`` holds the maps:
        :func:`graphpos.io.mcap_drive.drive_metadata`)."""
        with self._lock, self._writing():
            self._require_open()
            self._metadata_indexes.append(write_metadata(self._out, name, dict(data)))
            self._out.stream.flush()

    def add_channel(self, topic: str, schema: dict[str, Any], metadata: dict[str, str] | None = None) -> int:
        """Write a channel (message encoding ``json``) with its schema
        (encoding ``jsonschema``, named ``schema["title"]``; written once
        for equal schemas).

        Returns
        -------
        int
            The channel id, for :meth:`write`.
        """
        data = json.dumps(schema).encode()
        with self._lock, self._writing():
            self._require_open()
            found = self._schemas.get(data)
            if found is None:
                found = self._schemas[data] = Schema(id=len(self._schemas) + 1, name=schema["title"],
                                                     encoding="jsonschema", data=data)
                self._out.record(found)
            channel = Channel(id=len(self._channels) + 1, topic=topic, message_encoding="json",
                              schema_id=found.id, metadata=dict(metadata or {}))
            self._channels[channel.id] = channel
            self._out.record(channel)
            self._out.stream.flush()
            return channel.id

    def write(self, channel_id: int, log_time_ns: int, payload: bytes, publish_time_ns: int | None = None) -> None:
        """Add one message to the open chunk (closing it when full or old).

        Parameters
        ----------
        channel_id : int
            From :meth:`add_channel`.
        log_time_ns : int
            Log time (:func:`graphpos.io.mcap_drive.log_time_ns`), in
            [0, 2**64).
        payload : bytes
            The message (JSON).
        publish_time_ns : int, optional
            Publish time; defaults to the log time.
        """
        publish_ns = log_time_ns if publish_time_ns is None else publish_time_ns
        with self._lock:
            self._require_open()
            if channel_id not in self._channels:
                raise ValueError(f"{self.path}: no channel {channel_id} (add it with add_channel)")
            if not (0 <= log_time_ns < 2**64 and 0 <= publish_ns < 2**64):
                raise ValueError(f"{self.path}: time stamps must lie in [0, 2**64) ns, got {log_time_ns}, {publish_ns}")
            record = message_record(channel_id, log_time_ns, publish_ns, payload)
            if not self._chunk_ids:
                self._chunk_opened_s = time.monotonic()
            self._chunk_ids.append(channel_id)
            self._chunk_times.append(log_time_ns)
            self._chunk_offsets.append(self._chunk_bytes)
            self._chunk.append(record)
            self._chunk_bytes += len(record)
            self._counts[channel_id] = self._counts.get(channel_id, 0) + 1
            self._start_ns = log_time_ns if self._start_ns is None else min(self._start_ns, log_time_ns)
            self._end_ns = max(self._end_ns, log_time_ns)
            if (self._chunk_bytes >= self.chunk_size_bytes
                    or time.monotonic() - self._chunk_opened_s >= self.chunk_interval_s):
                with self._writing():
                    self._close_chunk()

    def flush(self) -> None:
        """Close the open chunk now: write it and its message indexes, and
        hand everything written to the operating system."""
        with self._lock, self._writing():
            self._require_open()
            self._close_chunk()

    def close(self) -> None:
        """Write the last chunk, the summary and the footer, and close the
        file; a second call does nothing."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            with self._writing(), self._out.stream:
                self._close_chunk()
                statistics = Statistics(
                    message_count=sum(self._counts.values()), schema_count=len(self._schemas),
                    channel_count=len(self._channels), attachment_count=0, metadata_count=len(self._metadata_indexes),
                    chunk_count=len(self._chunk_indexes), message_start_time=self._start_ns or 0,
                    message_end_time=self._end_ns, channel_message_counts=dict(self._counts),
                )
                finish_file(self._out, list(self._schemas.values()), list(self._channels.values()), statistics,
                            self._chunk_indexes, self._metadata_indexes)

    def __enter__(self) -> "McapRecorder":
        return self

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None, traceback: TracebackType | None) -> None:
        self.close()

    # -- internals (called with the lock held) -------------------------------
    def _new_chunk(self) -> None:
        self._chunk: list[bytes] = []
        self._chunk_ids: list[int] = []
        self._chunk_times: list[int] = []
        self._chunk_offsets: list[int] = []
        self._chunk_bytes = 0
        self._chunk_opened_s = 0.0

    def _close_chunk(self) -> None:
        """Write the open chunk (if it holds a message), then flush the file."""
        if self._chunk_ids:
            self._chunk_indexes.append(write_chunk(
                self._out, self._compressor, b"".join(self._chunk), np.array(self._chunk_ids, dtype=np.uint16),
                np.array(self._chunk_times, dtype=np.uint64), np.array(self._chunk_offsets, dtype=np.uint64),
            ))
            self._new_chunk()
        self._out.stream.flush()

    def _require_open(self) -> None:
        if self._closed:
            raise ValueError(f"{self.path}: the recorder is closed")

    @contextlib.contextmanager
    def _writing(self) -> Iterator[None]:
        """Turn an OSError of writing the file into a one-line FileFormatError."""
        try:
            yield
        except OSError as exc:
            raise FileFormatError(f"{self.path}: cannot write ({exc.strerror or exc})") from None
