"""MCAP round trips: lossless, time-ordered, indexed, viewable."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from mcap.reader import make_reader

from graphpos.drive import Channel, Drive, GeoOrigin
from graphpos.estimate import Estimate
from graphpos.io import read_drive, read_estimates, write_drive
from graphpos.io.geo import enu_to_geodetic

from drive_samples import assert_drives_equal, assert_estimates_equal


def test_every_channel_round_trips_exactly(tmp_path, drive):
    path = tmp_path / "d.mcap"
    write_drive(path, drive)
    assert_drives_equal(drive, read_drive(path))
    assert read_estimates(path) == []


def test_estimates_round_trip_exactly(tmp_path, drive, estimate):
    position_only = Estimate("multilateration", estimate.t_s[::10], estimate.east_m[::10], estimate.north_m[::10], rate_hz=1.0)
    path = tmp_path / "d.mcap"
    write_drive(path, drive, estimates=[estimate, position_only])
    back = read_estimates(path)
    assert [e.name for e in back] == ["fusion-ekf", "multilateration"]
    assert_estimates_equal(estimate, back[0])
    assert_estimates_equal(position_only, back[1])
    assert_drives_equal(drive, read_drive(path))


def test_origin_argument_is_stored(tmp_path, drive):
    path = tmp_path / "d.mcap"
    origin = GeoOrigin(51.5, -0.12, 10.0)
    write_drive(path, drive, origin=origin)
    assert read_drive(path).origin == origin


def test_negative_times_and_empty_channels(tmp_path):
    drive = Drive("neg", {
        "wheel": Channel("wheel", {"t_s": [-5.5, -0.25, 0.0, 3.0], "speed_mps": [1.0, 2.0, -0.0, 5e-324]}),
        "compass": Channel("compass", {"t_s": [], "yaw_rad": []}),
    })
    path = tmp_path / "d.mcap"
    write_drive(path, drive)
    back = read_drive(path)
    assert_drives_equal(drive, back)
    assert np.signbit(back.wheel.speed_mps[2])


def _summary(path):
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        messages = [(ch.topic, schema.name, msg.log_time, msg.data) for schema, ch, msg in reader.iter_messages(log_time_order=False)]
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    return summary, messages, metadata


def test_file_is_zstd_chunked_indexed_and_time_ordered(tmp_path, drive, estimate):
    path = tmp_path / "d.mcap"
    write_drive(path, drive, estimates=[estimate])
    summary, messages, metadata = _summary(path)
    assert summary.statistics.message_count == len(messages)
    assert summary.chunk_indexes and all(c.compression == "zstd" for c in summary.chunk_indexes)
    assert all(c.message_index_offsets for c in summary.chunk_indexes)
    log_times = [m[2] for m in messages]
    assert log_times == sorted(log_times)
    counts = {}
    for topic, *_ in messages:
        counts[topic] = counts.get(topic, 0) + 1
    for kind, ch in drive.channels.items():
        assert counts[f"/{kind}"] == len(ch)
    assert "graphpos.drive" in metadata


def test_viewing_topics_use_foxglove_schemas(tmp_path, drive, estimate):
    path = tmp_path / "d.mcap"
    write_drive(path, drive, estimates=[estimate])
    _, messages, _ = _summary(path)
    schemas = {topic: schema for topic, schema, _, _ in messages}
    assert schemas["/truth/fix"] == schemas["/gnss/fix"] == schemas["/rsu/fix"] == "foxglove.LocationFix"
    assert schemas["/truth/pose"] == schemas["/estimates/fusion-ekf/pose"] == "foxglove.PoseInFrame"
    assert schemas["/map"] == "foxglove.GeoJSON"
    assert schemas["/imu"] == "graphpos.imu"
    fixes = [json.loads(d) for topic, _, _, d in messages if topic == "/truth/fix"]
    truth = drive.truth
    # thinned to the first sample of each 0.1 s bin
    assert len(fixes) == np.unique(np.floor(truth.t_s * 10)).size < len(truth)
    lat, lon = enu_to_geodetic(truth.east_m[:1], truth.north_m[:1], drive.origin)
    assert fixes[0]["latitude"] == pytest.approx(lat[0]) and fixes[0]["longitude"] == pytest.approx(lon[0])
    poses = [json.loads(d) for topic, _, _, d in messages if topic == "/truth/pose"]
    q = poses[3]["pose"]["orientation"]
    assert 2 * np.arctan2(q["z"], q["w"]) == pytest.approx(truth.yaw_rad[30])
    gnss = json.loads(next(d for topic, _, _, d in messages if topic == "/gnss/fix"))
    assert gnss["position_covariance"][0] == gnss["position_covariance"][4] == drive.gnss.sigma_m[0] ** 2
    assert gnss["position_covariance_type"] == 2
    est_fix = json.loads(next(d for topic, _, _, d in messages if topic == "/estimates/fusion-ekf/fix"))
    assert est_fix["position_covariance"][0] == estimate.cov_en_m2[0, 0, 0]
    geo = json.loads(json.loads(next(d for topic, _, _, d in messages if topic == "/map"))["geojson"])
    assert len(geo["features"]) == len(drive.tags) + len(drive.rsus)
    # every message is standard JSON (no NaN literals)
    for _, _, _, data in messages:
        json.loads(data, parse_constant=lambda c: pytest.fail(f"non-standard JSON constant {c}"))


def test_geodetic_conversion_scale():
    origin = GeoOrigin(45.0, 7.0)
    lat, lon = enu_to_geodetic(np.array([0.0, 1000.0, 0.0]), np.array([0.0, 0.0, 1000.0]), origin)
    # 1 km north is about 1/111.1 deg at 45 deg; 1 km east is that over cos(45 deg)
    assert lat[2] - lat[0] == pytest.approx(1000 / 111132.0, rel=2e-3)
    assert lon[1] - lon[0] == pytest.approx(1000 / (111412.0 * np.cos(np.radians(45))), rel=2e-3)
    # ENU tangent plane (tests/io/test_geo.py): 1 km east lies 8 cm south of the origin's parallel
    assert lat[1] == pytest.approx(origin.lat_deg, abs=1e-6) and lon[2] == pytest.approx(origin.lon_deg, abs=1e-12)


def test_write_is_atomic_and_replaces(tmp_path, drive):
    path = tmp_path / "d.mcap"
    path.write_bytes(b"old")
    write_drive(path, drive)
    assert_drives_equal(drive, read_drive(path))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.mcap"]
    umask = os.umask(0)
    os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~umask  # not the temporary file's 0600


def test_failed_write_leaves_nothing(tmp_path, drive):
    from graphpos.errors import ConfigError

    path = tmp_path / "d.mcap"
    bad = drive.replace(params={"f": object()})
    with pytest.raises(ConfigError, match="params"):
        write_drive(path, bad)
    dup = Estimate("x", [0.0], [0.0], [0.0])
    with pytest.raises(ConfigError, match="twice"):
        write_drive(path, drive, estimates=[dup, dup])
    assert list(tmp_path.iterdir()) == []


def _scenario_cases():
    from graphpos.sim import SCENARIOS

    return [(name, pattern) for name, scenario in SCENARIOS.items() for pattern in scenario.patterns]


@pytest.mark.parametrize("scenario, pattern", _scenario_cases())
def test_every_scenario_and_pattern_round_trips(tmp_path, scenario, pattern):
    from graphpos.sim import simulate

    drive = simulate(scenario, pattern=pattern, seed=7, duration_s=40.0, rfid_latency_s=(0.0, 0.3))
    path = tmp_path / "s.mcap"
    write_drive(path, drive)
    assert_drives_equal(drive, read_drive(path))


def test_mcap_library_reads_file_and_message_indexes_point_at_messages(tmp_path, drive, estimate):
    from mcap.records import Chunk, ChunkIndex, Message, MessageIndex
    from mcap.stream_reader import StreamReader, breakup_chunk, get_chunk_data_stream

    path = tmp_path / "d.mcap"
    write_drive(path, drive, estimates=[estimate])
    # a streaming pass with every CRC checked, chunks expanded by the library
    with open(path, "rb") as f:
        streamed = [r for r in StreamReader(f, validate_crcs=True).records if isinstance(r, Message)]
    summary, messages, _ = _summary(path)
    assert len(streamed) == len(messages) == summary.statistics.message_count
    # each message index entry names a message of its channel at its log time
    with open(path, "rb") as f:
        records = list(StreamReader(f, emit_chunks=True).records)
    chunks = [r for r in records if isinstance(r, Chunk)]
    indexes = [r for r in records if isinstance(r, MessageIndex)]
    assert len([r for r in records if isinstance(r, ChunkIndex)]) == len(chunks) == len(summary.chunk_indexes)
    entries = 0
    chunk_of_index = np.searchsorted([c.chunk_start_offset for c in summary.chunk_indexes],
                                     [o for c in summary.chunk_indexes for o in c.message_index_offsets.values()], side="right") - 1
    for index, k in zip(indexes, chunk_of_index):
        stream, _ = get_chunk_data_stream(chunks[k])
        data = stream.read(chunks[k].uncompressed_size)
        for log_time, offset in index.records:
            opcode, channel_id, _, logged = data[offset], *np.frombuffer(data[offset + 9 : offset + 23], dtype="<u2,<u4,<u8")[0]
            assert (opcode, channel_id, logged) == (0x05, index.channel_id, log_time)
            entries += 1
    assert entries == len(messages)
    assert sum(len([m for m in breakup_chunk(c) if isinstance(m, Message)]) for c in chunks) == len(messages)


def test_every_message_conforms_to_its_channel_schema(tmp_path, drive, estimate):
    import jsonschema

    path = tmp_path / "d.mcap"
    write_drive(path, drive, estimates=[estimate])
    with open(path, "rb") as f:
        reader = make_reader(f)
        validators = {}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
            if schema.id not in validators:
                spec = json.loads(schema.data)
                jsonschema.Draft202012Validator.check_schema(spec)
                validators[schema.id] = jsonschema.Draft202012Validator(spec)
            validators[schema.id].validate(json.loads(message.data))
    assert len(validators) == len({"imu", "wheel", "compass", "rfid", "rsu", "gnss", "truth"}) + 4  # + fix, pose, map, estimate
