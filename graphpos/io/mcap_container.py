"""The MCAP container: writing whole topics at once, reading every record.

Both directions use the ``mcap`` package's record classes for every record
except the two that occur once per message, which are packed here in bulk:
the mcap package's ``Writer.add_message`` and ``StreamReader`` cost 4-7 us
per message in Python, too slow for an hour-long drive (1.2 million
messages). The files are standard MCAP (``mcap`` reads them with CRC checks;
``tests/io/test_mcap_drive.py``):

    magic, Header, Metadata..., Schema..., Channel...,
    (Chunk, MessageIndex per channel)..., DataEnd,
    summary: Schema..., Channel..., Statistics, ChunkIndex..., MetadataIndex...,
    SummaryOffset per group, Footer, magic

Chunks are zstd-compressed, about :data:`CHUNK_SIZE` bytes uncompressed, with
a CRC of their content. The record writers (:class:`RecordOutput`,
:func:`start_file`, :func:`write_metadata`, :func:`write_chunk`,
:func:`finish_file`) also serve the incremental writer of ``graphpos live``
(:mod:`graphpos.io.mcap_recorder`), whose unclosed files (no summary, no
footer) :func:`read_mcap_contents` reads up to their last complete record.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field
from io import BytesIO
from itertools import chain
from pathlib import Path
from typing import BinaryIO

import lz4.frame
import numpy as np
import zstandard
from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

from graphpos.errors import FileFormatError
from graphpos.io.files import open_input

#: The magic bytes at both ends of an MCAP file (``mcap.writer.MCAP0_MAGIC``, here because importing
#: ``mcap.writer`` costs every reading command importlib.metadata).
MCAP0_MAGIC = b"\x89MCAP0\r\n"

#: Uncompressed bytes of message records per chunk.
CHUNK_SIZE = 4 * 1024 * 1024
#: zstd level of the chunks: 4x faster than the default level, as small on this data.
CHUNK_ZSTD_LEVEL = 1

# A message record's fixed part: opcode, record length, channel id,
# sequence, log time, publish time (MCAP spec, "Message").
_MESSAGE_HEADER = np.dtype([("op", "u1"), ("len", "<u8"), ("cid", "<u2"), ("seq", "<u4"), ("log", "<u8"), ("pub", "<u8")])
_MESSAGE_RECORD = struct.Struct("<BQHIQQ")  # the same fields, one message at a time
_RECORD_HEADER = struct.Struct("<BQ")
_MESSAGE_CHANNEL = struct.Struct("<H")
_MESSAGE_START = struct.Struct("<BQH")  # a record header and, in a message, its channel id
#: Start of the header's library string of ``graphpos live`` recordings:
#: the only files read without a footer (:func:`read_mcap_contents`).
LIVE_LIBRARY = "graphpos live"
#: Largest record (and chunk content) read: a larger one is a corrupt file.
_MAX_RECORD_BYTES = 2**30
#: A footer record: opcode, length, summary start, summary offset start, summary CRC.
_FOOTER_BYTES = 1 + 8 + 8 + 8 + 4


@dataclass
class Topic:
    """All messages of one channel, to be written at once.

    ``log_ns`` is the message log (and publish) time; ``order_ns`` the key
    that merges topics in the file (non-decreasing per topic).
    """

    topic: str
    schema_name: str
    schema: bytes
    log_ns: np.ndarray
    payloads: list[bytes]
    metadata: dict[str, str] = field(default_factory=dict)

    @property
    def order_ns(self) -> np.ndarray:
        return np.maximum.accumulate(self.log_ns) if self.log_ns.size else self.log_ns


class RecordOutput:
    """A stream and the offset of the next byte written to it (the file is
    written from its first byte)."""

    def __init__(self, stream: BinaryIO) -> None:
        self.stream = stream
        self.offset = 0
        self.builder = RecordBuilder()

    def write(self, data: bytes) -> int:
        """Write bytes; returns their offset in the file."""
        at = self.offset
        self.stream.write(data)
        self.offset += len(data)
        return at

    def record(self, record) -> tuple[int, int]:
        """Write one mcap record; returns (offset, length)."""
        record.write(self.builder)
        data = self.builder.end()
        return self.write(data), len(data)


def message_record(channel_id: int, log_ns: int, publish_ns: int, payload: bytes) -> bytes:
    """One message record (sequence 0), as it stands in a chunk."""
    return _MESSAGE_RECORD.pack(Opcode.MESSAGE, 22 + len(payload), channel_id, 0, log_ns, publish_ns) + payload


def _message_index(channel_id: int, log_ns: np.ndarray, offsets: np.ndarray) -> bytes:
    entries = np.column_stack([log_ns, offsets]).astype("<u8").tobytes()
    return _RECORD_HEADER.pack(Opcode.MESSAGE_INDEX, 6 + len(entries)) + struct.pack("<HI", channel_id, len(entries)) + entries


def _chunk_bounds(sizes: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) message ranges of about CHUNK_SIZE bytes each."""
    ends = np.cumsum(sizes)
    cut = np.flatnonzero(np.diff(ends // CHUNK_SIZE) > 0) + 1
    edges = [0, *cut.tolist(), sizes.size]
    return [(a, b) for a, b in zip(edges[:-1], edges[1:]) if b > a]


def start_file(out: RecordOutput, library: str) -> None:
    """The magic bytes and the header record."""
    out.write(MCAP0_MAGIC)
    out.record(Header(profile="", library=library))


def write_metadata(out: RecordOutput, name: str, values: dict[str, str]) -> MetadataIndex:
    """One metadata record; returns its summary index entry."""
    offset, length = out.record(Metadata(name=name, metadata=values))
    return MetadataIndex(offset=offset, length=length, name=name)


def write_chunk(out: RecordOutput, compressor: zstandard.ZstdCompressor, data: bytes, channel_ids: np.ndarray,
                log_ns: np.ndarray, offsets: np.ndarray) -> ChunkIndex:
    """One zstd chunk of message records and its message indexes (one per
    channel); returns its summary index entry.

    Parameters
    ----------
    out : RecordOutput
    compressor : zstandard.ZstdCompressor
    data : bytes
        The message records, back to back (at least one).
    channel_ids, log_ns, offsets : array of int
        Channel id, log time and offset in ``data`` of each message record.
    """
    compressed = compressor.compress(data)
    start_ns, end_ns = int(log_ns.min()), int(log_ns.max())
    chunk = Chunk(compression="zstd", data=compressed, message_start_time=start_ns, message_end_time=end_ns,
                  uncompressed_crc=zlib.crc32(data), uncompressed_size=len(data))
    start, length = out.record(chunk)
    index_offsets = {}
    index_start = out.offset
    for cid in np.unique(channel_ids).tolist():
        pick = channel_ids == cid
        index_offsets[cid] = out.write(_message_index(cid, log_ns[pick], offsets[pick]))
    return ChunkIndex(
        message_start_time=start_ns, message_end_time=end_ns, chunk_start_offset=start, chunk_length=length,
        message_index_offsets=index_offsets, message_index_length=out.offset - index_start, compression="zstd",
        compressed_size=len(compressed), uncompressed_size=len(data),
    )


def finish_file(out: RecordOutput, schemas: list[Schema], channels: list[Channel], statistics: Statistics,
                chunk_indexes: list[ChunkIndex], metadata_indexes: list[MetadataIndex]) -> None:
    """The data end record, the summary (schemas, channels, statistics,
    chunk and metadata indexes, an offset per group), the footer and the
    closing magic bytes."""
    out.record(DataEnd(data_section_crc=0))
    summary_start = out.offset
    summary = RecordBuilder()
    offsets = []
    for opcode, records in (
        (Opcode.SCHEMA, schemas),
        (Opcode.CHANNEL, channels),
        (Opcode.STATISTICS, [statistics]),
        (Opcode.CHUNK_INDEX, chunk_indexes),
        (Opcode.METADATA_INDEX, metadata_indexes),
    ):
        group_start = summary.count
        for record in records:
            record.write(summary)
        if summary.count > group_start:
            offsets.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + group_start,
                                         group_length=summary.count - group_start))
    summary_offset_start = summary_start + summary.count
    for record in offsets:
        record.write(summary)
    data = summary.end()
    crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, summary_offset_start), zlib.crc32(data))
    out.write(data)
    out.record(Footer(summary_start=summary_start, summary_offset_start=summary_offset_start, summary_crc=crc))
    out.write(MCAP0_MAGIC)


def write_mcap(stream: BinaryIO, library: str, metadata: dict[str, dict[str, str]], topics: list[Topic]) -> None:
    """Write a complete MCAP file of the given topics, merged by ``order_ns``
    (ties keep topic order, and each topic keeps its message order)."""
    out = RecordOutput(stream)
    start_file(out, library)
    metadata_indexes = [write_metadata(out, name, values) for name, values in metadata.items()]
    schemas: dict[str, Schema] = {}
    channels = []
    for topic in topics:
        if topic.schema_name not in schemas:
            schemas[topic.schema_name] = Schema(id=len(schemas) + 1, name=topic.schema_name, encoding="jsonschema", data=topic.schema)
        channels.append(Channel(id=len(channels) + 1, topic=topic.topic, message_encoding="json",
                                schema_id=schemas[topic.schema_name].id, metadata=topic.metadata))
    for record in chain(schemas.values(), channels):
        out.record(record)

    counts = [len(t.payloads) for t in topics]
    total = sum(counts)
    log_ns = np.concatenate([t.log_ns.astype(np.uint64) for t in topics]) if topics else np.zeros(0, np.uint64)
    order = np.argsort(np.concatenate([t.order_ns for t in topics]), kind="stable") if total else np.zeros(0, np.int64)
    channel_id = np.repeat(np.arange(1, len(topics) + 1, dtype=np.uint16), counts)[order]
    log_ns = log_ns[order]
    everything = [p for t in topics for p in t.payloads]
    payloads = [everything[i] for i in order.tolist()]
    headers = np.zeros(total, dtype=_MESSAGE_HEADER)
    lengths = np.fromiter(map(len, payloads), dtype=np.uint64, count=total)
    headers["op"] = Opcode.MESSAGE
    headers["len"] = lengths + 22
    headers["cid"] = channel_id
    headers["log"] = headers["pub"] = log_ns
    chunk_indexes = []
    compressor = zstandard.ZstdCompressor(level=CHUNK_ZSTD_LEVEL)
    for a, b in _chunk_bounds(lengths + 31):
        raw_headers = headers[a:b].tobytes()
        parts = [raw_headers[i : i + 31] for i in range(0, len(raw_headers), 31)]
        data = b"".join(chain.from_iterable(zip(parts, payloads[a:b])))
        offsets = np.r_[0, np.cumsum(lengths[a:b] + 31)[:-1]].astype(np.uint64)
        chunk_indexes.append(write_chunk(out, compressor, data, channel_id[a:b], log_ns[a:b], offsets))

    statistics = Statistics(
        message_count=total, schema_count=len(schemas), channel_count=len(channels), attachment_count=0,
        metadata_count=len(metadata), chunk_count=len(chunk_indexes),
        message_start_time=int(log_ns.min()) if total else 0, message_end_time=int(log_ns.max()) if total else 0,
        channel_message_counts={cid: n for cid, n in enumerate(counts, start=1) if n},
    )
    finish_file(out, list(schemas.values()), channels, statistics, chunk_indexes, metadata_indexes)


# ---------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------


class _Corrupt(Exception):
    """Internal: the MCAP byte structure is broken."""


#: Records whose content a reader uses; any other record is skipped unread.
_USED_OPCODES = frozenset({Opcode.HEADER, Opcode.SCHEMA, Opcode.CHANNEL, Opcode.METADATA, Opcode.STATISTICS,
                           Opcode.MESSAGE, Opcode.CHUNK})


class McapContents:
    """What an MCAP file holds: schemas and channels by id, the payloads of
    each channel's messages in file order, metadata records by name (the
    first of each name), the writer's library string; ``unclosed``: the file
    is a recording its writer never closed, read up to its last complete
    record (:func:`read_mcap_contents`)."""

    def __init__(self) -> None:
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.payloads: dict[int, list[bytes]] = {}
        self.metadata: dict[str, dict[str, str]] = {}
        self.library = ""
        self.statistics: Statistics | None = None
        self.unclosed = False

    def _record(self, opcode: int, body: bytes | memoryview) -> None:
        if opcode == Opcode.SCHEMA:
            schema = Schema.read(ReadDataStream(BytesIO(body)))
            self.schemas[schema.id] = schema
        elif opcode == Opcode.CHANNEL:
            channel = Channel.read(ReadDataStream(BytesIO(body)))
            self.channels[channel.id] = channel
        elif opcode == Opcode.METADATA:
            meta = Metadata.read(ReadDataStream(BytesIO(body)))
            self.metadata.setdefault(meta.name, meta.metadata)
        elif opcode == Opcode.HEADER:
            self.library = Header.read(ReadDataStream(BytesIO(body))).library
        elif opcode == Opcode.STATISTICS:
            self.statistics = Statistics.read(ReadDataStream(BytesIO(body)))
        elif opcode == Opcode.MESSAGE:  # outside chunks (inside, _walk_chunk reads them faster)
            if len(body) < 22:
                raise _Corrupt("a message record is too short")
            (cid,) = _MESSAGE_CHANNEL.unpack_from(body)
            self.payloads.setdefault(cid, []).append(bytes(body[22:]))
        elif opcode == Opcode.CHUNK:
            self._walk_chunk(_chunk_data(body))

    def _walk_chunk(self, data: bytes) -> None:
        """Walk the records of a chunk's content (mostly messages)."""
        pos, end = 0, len(data)
        unpack = _RECORD_HEADER.unpack_from
        unpack_message = _MESSAGE_START.unpack_from
        message = int(Opcode.MESSAGE)
        payloads = self.payloads
        while pos < end:
            if pos + 11 <= end:  # the channel id is read with the header: it counts only for a message
                opcode, length, cid = unpack_message(data, pos)
            elif pos + 9 <= end:
                opcode, length = unpack(data, pos)
            else:
                raise _Corrupt("a record header is cut off")
            start = pos + 9
            pos = start + length
            if pos > end:
                raise _Corrupt(f"a record (opcode {opcode:#x}) runs past the end of the chunk")
            if opcode == message:
                if length < 22:
                    raise _Corrupt("a message record is too short")
                bucket = payloads.get(cid)
                if bucket is None:
                    bucket = payloads[cid] = []
                bucket.append(data[start + 22 : pos])
            elif opcode == 0 or opcode in (Opcode.CHUNK, Opcode.FOOTER):
                raise _Corrupt(f"opcode {opcode:#x} inside a chunk")
            else:
                self._record(opcode, memoryview(data)[start:pos])

    def _walk_file(self, stream: BinaryIO, end_at: int, unclosed: bool) -> None:
        """Walk the records from the stream's position to offset ``end_at``
        (the footer), reading only the records in :data:`_USED_OPCODES`,
        one at a time.

        ``unclosed``: the file has no footer and ``end_at`` is its size; the
        walk ends at the data end record, or before a record the file ends
        inside (cut off by its writer's stop).
        """
        pos = stream.tell()
        while pos < end_at:
            if unclosed and pos + 9 > end_at:
                return
            header = stream.read(9)
            if len(header) < 9:
                raise _Corrupt("a record header is cut off")
            opcode, length = _RECORD_HEADER.unpack(header)
            if opcode == 0:
                raise _Corrupt(f"no record at byte {pos} (opcode 0)")
            if opcode == Opcode.FOOTER:
                raise _Corrupt(f"a footer record at byte {pos}, before the end of the file")
            if unclosed and opcode == Opcode.DATA_END:
                return  # the summary that may follow is the writer's, cut off or not: the data is all read
            pos += 9 + length
            if pos > end_at:
                if unclosed and length <= _MAX_RECORD_BYTES:
                    return
                raise _Corrupt(f"a record (opcode {opcode:#x}) runs past the end of the file")
            if opcode not in _USED_OPCODES:
                stream.seek(pos)
                continue
            if length > _MAX_RECORD_BYTES:
                raise _Corrupt(f"a record (opcode {opcode:#x}) claims an implausible length of {length} bytes")
            body = stream.read(length)
            if len(body) < length:
                raise _Corrupt("the file ends inside a record")
            self._record(opcode, body)


def _chunk_data(body: bytes | memoryview) -> bytes:
    chunk = Chunk.read(ReadDataStream(BytesIO(body)))
    if chunk.uncompressed_size > _MAX_RECORD_BYTES:
        raise _Corrupt("a chunk claims an implausible size")
    if chunk.compression == "zstd":
        data = zstandard.ZstdDecompressor().decompress(chunk.data, max_output_size=chunk.uncompressed_size)
    elif chunk.compression == "":
        data = chunk.data
    elif chunk.compression == "lz4":  # other writers' choice; lz4 comes with mcap
        data = lz4.frame.decompress(chunk.data)
    else:
        raise _Corrupt(f"unsupported chunk compression {chunk.compression!r}")
    if len(data) != chunk.uncompressed_size:
        raise _Corrupt("a chunk's size does not match its header")
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise _Corrupt("a chunk fails its CRC check")
    return data


def _live_header(stream: BinaryIO, size_bytes: int) -> bool:
    """True when the record after the magic bytes is a header whose library
    starts with :data:`LIVE_LIBRARY` (the stream is left anywhere)."""
    header = stream.read(9)
    if len(header) < 9:
        return False
    opcode, length = _RECORD_HEADER.unpack(header)
    if opcode != Opcode.HEADER or len(MCAP0_MAGIC) + 9 + length > size_bytes:
        return False  # not a header, or one cut off
    try:
        library = Header.read(ReadDataStream(BytesIO(stream.read(length)))).library
    except Exception:  # noqa: BLE001 - any failure decoding the bytes: not a header
        return False
    return library.startswith(LIVE_LIBRARY)


def _data_bounds(stream: BinaryIO, size_bytes: int, path: Path) -> tuple[int, bool]:
    """Where the walk of the records ends, and whether the file is an
    unclosed recording of ``graphpos live``; checked with the magic bytes
    at both ends before anything else is read.

    A file with a footer ends its walk at the footer. A file without one is
    refused, unless its header names :data:`LIVE_LIBRARY` as its writer: its
    records are then walked to the end of the file. The stream is left
    after the opening magic bytes.
    """
    if stream.read(len(MCAP0_MAGIC)) != MCAP0_MAGIC:
        raise FileFormatError(f"{path}: not an MCAP file (no MCAP magic bytes at the start)")
    footer_at = size_bytes - len(MCAP0_MAGIC) - _FOOTER_BYTES
    if footer_at >= len(MCAP0_MAGIC):
        stream.seek(footer_at)
        tail = stream.read(_FOOTER_BYTES + len(MCAP0_MAGIC))
        if tail[_FOOTER_BYTES:] == MCAP0_MAGIC and _RECORD_HEADER.unpack_from(tail) == (Opcode.FOOTER, _FOOTER_BYTES - 9):
            stream.seek(len(MCAP0_MAGIC))
            return footer_at, False
    stream.seek(len(MCAP0_MAGIC))
    if _live_header(stream, size_bytes):
        stream.seek(len(MCAP0_MAGIC))
        return size_bytes, True
    raise FileFormatError(f"{path}: truncated MCAP file (no footer; was writing interrupted?)")


def read_mcap_contents(path: Path) -> McapContents:
    """Every schema, channel, message payload and metadata record of an MCAP
    file; FileFormatError for a missing, empty, special, foreign, truncated
    or corrupt file.

    The magic bytes at both ends and the footer are checked first; then the
    records are read one at a time (a record is at most
    :data:`_MAX_RECORD_BYTES`), skipping those nothing reads (indexes,
    attachments), so a broken file is refused without reading it whole.

    A file without a footer is truncated and refused, except an unclosed
    recording of ``graphpos live`` (:class:`graphpos.io.mcap_recorder.McapRecorder`,
    whose header's library starts with :data:`LIVE_LIBRARY`): its records
    are read from the start up to the last complete one (a chunk or record
    the file ends inside is left out; a complete one that is corrupt is
    still an error), and ``unclosed`` is set in the result.
    """
    contents = McapContents()
    with open_input(path) as (stream, size_bytes):
        end_at, contents.unclosed = _data_bounds(stream, size_bytes, path)
        try:
            contents._walk_file(stream, end_at, contents.unclosed)
        except _Corrupt as exc:
            raise FileFormatError(f"{path}: corrupt MCAP file: {exc}") from None
        except OSError as exc:
            raise FileFormatError(f"{path}: cannot read ({exc.strerror or exc})") from None
        except Exception as exc:  # noqa: BLE001 - any failure decoding corrupt bytes is a corrupt file
            raise FileFormatError(f"{path}: corrupt MCAP file ({type(exc).__name__}: {exc})") from None
    unknown = set(contents.payloads) - set(contents.channels)
    if unknown:
        raise FileFormatError(f"{path}: corrupt MCAP file: messages on channel id {min(unknown)}, which is never defined")
    stats = contents.statistics
    if stats is not None:  # a whole file has every message its summary counts
        found = {cid: len(p) for cid, p in contents.payloads.items()}
        for cid in sorted(set(found) | set(stats.channel_message_counts)):
            if found.get(cid, 0) != stats.channel_message_counts.get(cid, 0):
                topic = contents.channels[cid].topic if cid in contents.channels else f"channel id {cid}"
                raise FileFormatError(f"{path}: corrupt MCAP file: {found.get(cid, 0)} messages on {topic}, "
                                      f"but the summary counts {stats.channel_message_counts[cid] if cid in stats.channel_message_counts else 0}")
        if sum(found.values()) != stats.message_count:
            raise FileFormatError(f"{path}: corrupt MCAP file: {sum(found.values())} messages, but the summary counts {stats.message_count}")
    return contents
