"""Files written by other tools read; broken or foreign files give one
clear error naming the file (and channel/row where known), never a
traceback and never a partial drive."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from mcap.writer import CompressionType, Writer

from graphpos.errors import DriveError, FileFormatError
from graphpos.io import read_drive, read_estimates, write_drive

SCHEMA = json.dumps({"type": "object"}).encode()


def write_foreign(path: Path, topics: dict[str, tuple[str, str, list[bytes]]], metadata: dict | None = None,
                  chunked: bool = True, compression=CompressionType.LZ4) -> None:
    """A file written with the plain mcap writer: {topic: (schema name,
    message encoding, payloads)}, messages interleaved in topic order."""
    with open(path, "wb") as f:
        writer = Writer(f, use_chunking=chunked, compression=compression)
        writer.start(profile="", library="someone-else")
        if metadata is not None:
            writer.add_metadata("graphpos.drive", metadata)
        ids = {}
        for topic, (schema, encoding, _) in topics.items():
            sid = writer.register_schema(schema, "jsonschema", SCHEMA)
            ids[topic] = writer.register_channel(topic, encoding, sid)
        for topic, (_, _, payloads) in topics.items():
            for i, data in enumerate(payloads):
                writer.add_message(ids[topic], i * 10_000_000, data, i * 10_000_000)
        writer.finish()


def rows(**columns) -> list[bytes]:
    n = len(next(iter(columns.values())))
    return [json.dumps({k: v[i] for k, v in columns.items()}).encode() for i in range(n)]


@pytest.mark.parametrize("chunked", [True, False])
def test_file_from_plain_mcap_writer_reads(tmp_path, chunked):
    path = tmp_path / "other.mcap"
    t = [0.0, 0.01, 0.02, 0.03]
    write_foreign(path, {
        "/vehicle/wheel": ("graphpos.wheel", "json", rows(t_s=t, speed_mps=[1.0, 1.5, 2.0, 2.5], extra=["x"] * 4)),
        "/vehicle/imu": ("graphpos.imu", "json", rows(t_s=t, yaw_rate_radps=[0.1, 0.2, 0.3, None])[:3]),
        "/camera": ("foxglove.CompressedImage", "protobuf", [b"\x00\x01"]),
    }, chunked=chunked)
    drive = read_drive(path)
    assert drive.name == "other" and list(drive.channels) == ["imu", "wheel"]
    assert drive.wheel.speed_mps.tolist() == [1.0, 1.5, 2.0, 2.5]
    assert np.isnan(drive.imu.accel_x_mps2).all() and drive.imu.yaw_rate_radps.tolist() == [0.1, 0.2, 0.3]
    assert read_estimates(path) == []


def test_foreign_file_with_map_metadata(tmp_path):
    path = tmp_path / "other.mcap"
    tags = {"tag_id": [4, 9], "east_m": [0.0, 6.0], "north_m": [3.0, -3.0], "wall_side": [1, -1], "group": [0, 0],
            "layouts": {"optimized": [9]}}
    write_foreign(path, {"/rfid": ("graphpos.rfid", "json", rows(t_s=[1.0, 1.0], tag_id=[4, 9], rss=[120, 99]))},
                  metadata={"name": "by-hand", "tags": json.dumps(tags), "windows": '[{"label": "in_tunnel", "start_s": 0, "end_s": 2}]'})
    drive = read_drive(path)
    assert drive.name == "by-hand" and drive.tags.layouts["optimized"].tolist() == [9]
    assert drive.rfid.tag_id.tolist() == [4.0, 9.0] and drive.rfid.arrival_s.tolist() == [1.0, 1.0]
    assert drive.windows[0].label == "in_tunnel"


# -- bad files -----------------------------------------------------------------

def good_file(tmp_path, drive) -> bytes:
    path = tmp_path / "good.mcap"
    write_drive(path, drive)
    return path.read_bytes()


def test_missing_empty_folder_random(tmp_path):
    cases = {
        "missing.mcap": (None, "no such file"),
        "empty.mcap": (b"", "empty file"),
        "random.mcap": (np.random.default_rng(0).bytes(5000), "not an MCAP file"),
        "text.mcap": (b"t_s,east_m\n0,1\n", "not an MCAP file"),
    }
    for name, (content, reason) in cases.items():
        path = tmp_path / name
        if content is not None:
            path.write_bytes(content)
        with pytest.raises(FileFormatError, match=rf"{name}: {reason}"):
            read_drive(path)
    with pytest.raises(FileFormatError, match="is a folder, not a file"):
        read_drive(tmp_path)


def test_truncated_files(tmp_path, drive):
    data = good_file(tmp_path, drive)
    path = tmp_path / "cut.mcap"
    for cut in (9, 30, len(data) // 3, len(data) // 2, len(data) - 8, len(data) - 1):
        path.write_bytes(data[:cut])
        with pytest.raises(FileFormatError, match=r"cut\.mcap: (truncated|corrupt)"):
            read_drive(path)


def test_corrupt_bytes(tmp_path, drive):
    data = bytearray(good_file(tmp_path, drive))
    path = tmp_path / "flip.mcap"
    rng = np.random.default_rng(1)
    for pos in rng.integers(8, len(data) - 8, 40).tolist():
        bad = bytearray(data)
        bad[pos] ^= 0xFF
        path.write_bytes(bytes(bad))
        try:
            back = read_drive(path)
        except (FileFormatError, DriveError) as exc:
            assert "flip.mcap" in str(exc)
        else:  # a flip in an index or summary record does not touch the data
            assert all(back.channels[k] == ch for k, ch in drive.channels.items())


def test_foreign_topics_only(tmp_path):
    path = tmp_path / "ros.mcap"
    write_foreign(path, {"/camera": ("sensor_msgs/Image", "ros1", [b"\x00"]), "/gps": ("foxglove.LocationFix", "json", [b"{}"])})
    with pytest.raises(FileFormatError, match=r"ros\.mcap: not a graphpos drive .*topics: /camera, /gps"):
        read_drive(path)


def test_graphpos_schema_in_another_encoding(tmp_path):
    path = tmp_path / "pb.mcap"
    write_foreign(path, {"/wheel": ("graphpos.wheel", "protobuf", [b"\x08\x01"])})
    with pytest.raises(FileFormatError, match="pb.mcap: topic /wheel .* message encoding 'protobuf'"):
        read_drive(path)


@pytest.mark.parametrize(
    "payloads, error, message",
    [
        ([b'{"t_s": 0, "speed_mps": 1}', b'{"t_s": 1, "speed_mps": '], FileFormatError, r"topic /wheel, message 1: not valid JSON"),
        ([b'{"t_s": 0, "speed_mps": 1}', b'[0, 1]'], FileFormatError, r"topic /wheel, message 1: expected a JSON object"),
        ([b'{"t_s": 0, "speed_mps": "fast"}'], DriveError, r"channel 'wheel', row 0: field 'speed_mps' is a string \"fast\", not a number"),
        ([b'{"t_s": 0, "speed_mps": [1, 2]}'], DriveError, r"row 0: field 'speed_mps' is an array \[1, 2\], not a number"),
        ([b'{"t_s": 0, "speed_mps": 1' + b"0" * 400 + b"}"], DriveError, r"row 0: field 'speed_mps' is a number 10+\.\.\., out of range"),
        ([b'{"t_s": 0, "speed_mps": 1}', b'{"t_s": 1}'], DriveError, r"channel 'wheel', row 1: field 'speed_mps' is missing"),
        ([b'{"t_s": 0, "speed_mps": 1}', b'{"t_s": 1, "speed_mps": null}'], DriveError, r"row 1: field 'speed_mps' is missing, null"),
        ([b'{"t_s": 0, "speed_mps": 1}', b'{"t_s": 1, "speed_mps": 1e999}'], DriveError, r"row 1: speed_mps is inf"),
        ([b'{"t_s": 1, "speed_mps": 1}', b'{"t_s": 0, "speed_mps": 1}'], DriveError, r"row 1: time goes backwards"),
        ([b'{"t_s": 0, "speed_mps": 3e8}'], DriveError, r"row 0: speed_mps = 3e\+08 is outside"),
        ([b'\xff\xfe{'], FileFormatError, r"message 0: not valid JSON"),
    ],
)
def test_bad_messages_name_file_channel_row(tmp_path, payloads, error, message):
    path = tmp_path / "bad.mcap"
    write_foreign(path, {"/wheel": ("graphpos.wheel", "json", payloads)})
    with pytest.raises(error, match=r"bad\.mcap: .*" + message):
        read_drive(path)


def test_unknown_tag_and_bad_metadata(tmp_path):
    path = tmp_path / "bad.mcap"
    write_foreign(path, {"/rfid": ("graphpos.rfid", "json", rows(t_s=[0.0], tag_id=[5]))})
    with pytest.raises(DriveError, match=r"bad\.mcap: channel 'rfid', row 0: tag id 5 is not in the tag map"):
        read_drive(path)
    wheel = {"/wheel": ("graphpos.wheel", "json", rows(t_s=[0.0], speed_mps=[1.0]))}
    for meta, message in [
        ({"tags": "{not json"}, "metadata 'tags' is not valid JSON"),
        ({"tags": '{"tag_id": [1]}'}, r"metadata 'tags\.east_m' is missing"),
        ({"windows": '[{"label": "x", "start_s": 5, "end_s": 1}]'}, "metadata 'windows': window 'x' has bad bounds"),
        ({"params": "[1, 2]"}, r"metadata 'params' is an array \[1, 2\], not an object"),
        ({"format": "graphpos.drive/9"}, "unsupported drive format 'graphpos.drive/9'"),
    ]:
        write_foreign(path, wheel, metadata=meta)
        with pytest.raises((FileFormatError, DriveError), match=r"bad\.mcap: .*" + message):
            read_drive(path)


# -- bad values in every channel (issue 8 corpus) ------------------------------

MAPS = {
    "tags": json.dumps({"tag_id": [1], "east_m": [0.0], "north_m": [3.0], "wall_side": [1], "group": [0]}),
    "rsus": json.dumps({"rsu_id": [1], "east_m": [0.0], "north_m": [0.0]}),
}


def valid_row(kind: str, t: float) -> dict:
    from graphpos.drive import CHANNEL_SPECS

    row = {}
    for spec in CHANNEL_SPECS[kind]:
        row[spec.name] = 1.0 if spec.lo <= 1.0 <= spec.hi else spec.lo
    row.update(t_s=t, arrival_s=t)
    return row


def channel_file(path: Path, kind: str, rows_: list[dict]) -> None:
    write_foreign(path, {f"/{kind}": (f"graphpos.{kind}", "json", [json.dumps(r).encode() for r in rows_])}, metadata=MAPS)


def required_columns():
    from graphpos.drive import CHANNEL_SPECS

    return [(kind, spec.name) for kind, specs in CHANNEL_SPECS.items() for spec in specs[1:] if spec.required]


@pytest.mark.parametrize("kind, column", required_columns())
@pytest.mark.parametrize("bad, reason", [(None, "is missing, null or NaN"), ("1e999", "is inf"), ("-1e999", "is -inf"), ("1e12", "outside the plausible range")])
def test_bad_value_in_each_channel_names_channel_and_row(tmp_path, kind, column, bad, reason):
    path = tmp_path / f"{kind}.mcap"
    rows_ = [valid_row(kind, 0.0), valid_row(kind, 0.5)]
    payloads = [json.dumps(r).encode() for r in rows_]
    payloads[1] = payloads[1].replace(f'"{column}": {json.dumps(rows_[1][column])}'.encode(), f'"{column}": {json.dumps(bad) if bad is None else bad}'.encode())
    assert payloads[1] != json.dumps(rows_[1]).encode()
    write_foreign(path, {f"/{kind}": (f"graphpos.{kind}", "json", payloads)}, metadata=MAPS)
    if column in ("tag_id", "rsu_id") and bad == "1e12":
        reason = "is not in the"  # a whole number in range, but no such tag/RSU
    with pytest.raises(DriveError, match=rf"{kind}\.mcap: channel '{kind}', row 1: .*{reason}"):
        read_drive(path)


@pytest.mark.parametrize("kind", ["imu", "wheel", "compass", "rfid", "rsu", "gnss", "truth"])
def test_time_backwards_in_each_channel(tmp_path, kind):
    path = tmp_path / "back.mcap"
    channel_file(path, kind, [valid_row(kind, 1.0), valid_row(kind, 2.0), valid_row(kind, 1.5)])
    with pytest.raises(DriveError, match=rf"channel '{kind}', row 2: time goes backwards"):
        read_drive(path)


def test_duplicate_timestamps_one_second_and_empty_channels_read(tmp_path):
    path = tmp_path / "ok.mcap"
    write_foreign(path, {
        "/wheel": ("graphpos.wheel", "json", [json.dumps(valid_row("wheel", t)).encode() for t in (0.0, 0.5, 0.5, 1.0)]),
        "/compass": ("graphpos.compass", "json", []),
    })
    drive = read_drive(path)
    assert drive.wheel.t_s.tolist() == [0.0, 0.5, 0.5, 1.0]
    assert len(drive.compass) == 0 and drive.duration_s == 1.0


def test_file_missing_a_chunk_is_not_read_as_whole(tmp_path, drive, monkeypatch):
    import graphpos.io.mcap_container as container
    from mcap.records import ChunkIndex
    from mcap.stream_reader import StreamReader

    monkeypatch.setattr(container, "CHUNK_SIZE", 4096)
    path = tmp_path / "gap.mcap"
    write_drive(path, drive)
    with open(path, "rb") as f:
        chunk = [r for r in StreamReader(f).records if isinstance(r, ChunkIndex)][2]
    data = path.read_bytes()
    path.write_bytes(data[: chunk.chunk_start_offset] + data[chunk.chunk_start_offset + chunk.chunk_length :])
    with pytest.raises(FileFormatError, match=r"gap\.mcap: corrupt MCAP file: \d+ messages on /\w+, but the summary counts \d+"):
        read_drive(path)
