"""The recorder of ``graphpos live``: a file written message by message that
reads whole once closed, up to its last complete chunk at any moment before
(even after SIGKILL), and only for graphpos live; rows in arrival order."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader

from drive_samples import assert_drives_equal, assert_estimates_equal
from graphpos import __version__
from graphpos.cli import main
from graphpos.drive import CHANNEL_NAMES, Channel, Drive, TagMap
from graphpos.errors import DriveError, FileFormatError
from graphpos.estimate import Estimate, OutputRow
from graphpos.io import read_drive, read_estimates, write_drive
from graphpos.io.checks import drive_checks
from graphpos.io.mcap_container import read_mcap_contents
from graphpos.io.mcap_drive import (GEOJSON_SCHEMA, LOCATION_FIX_SCHEMA, POSE_IN_FRAME_SCHEMA, VIEW_RATE_HZ,
                                    channel_schema, drive_metadata, encode_estimate_row, encode_row,
                                    estimate_channel_metadata, estimate_schema, location_fix_payload, log_time_ns,
                                    map_geojson_payload, pose_payload)
from graphpos.io.mcap_recorder import McapRecorder
from graphpos.sim import simulate

SCHEMA_A = {"title": "test.a", "type": "object"}
SCHEMA_B = {"title": "test.b", "type": "object"}


def _messages(n: int, seed: int = 0, max_bytes: int = 120) -> list[tuple[int, int, bytes]]:
    """(channel index 0..2, log time, payload): times jump back now and then, payloads of any bytes."""
    rng = np.random.default_rng(seed)
    times = np.cumsum(rng.integers(-3_000_000, 10_000_000, n)) + 10**9
    return [(int(rng.integers(0, 3)), int(t), rng.bytes(int(rng.integers(0, max_bytes)))) for t in times]


def _record(path, messages, flush_every=None, close=True, **kwargs) -> McapRecorder:
    recorder = McapRecorder(path, **kwargs)
    recorder.add_metadata("test.meta", {"k": "v", "empty": ""})
    ids = [recorder.add_channel("/a", SCHEMA_A, {"note": "first"}), recorder.add_channel("/b", SCHEMA_B),
           recorder.add_channel("/a2", dict(SCHEMA_A))]
    for i, (k, t, payload) in enumerate(messages, start=1):
        recorder.write(ids[k], t, payload, publish_time_ns=t + 1)
        if flush_every and i % flush_every == 0:
            recorder.flush()
    if close:
        recorder.close()
    return recorder


def _by_channel(messages) -> dict[int, list[bytes]]:
    out: dict[int, list[bytes]] = {}
    for k, _, payload in messages:
        out.setdefault(k + 1, []).append(payload)
    return out


# ---------------------------------------------------------------------------
# A closed recording
# ---------------------------------------------------------------------------


def test_closed_recording_reads_bit_exact_with_graphpos_and_the_mcap_library(tmp_path):
    path = tmp_path / "r.mcap"
    messages = _messages(3000)
    _record(path, messages, chunk_size_bytes=8 * 1024)
    contents = read_mcap_contents(path)
    assert not contents.unclosed and contents.library == f"graphpos live {__version__}"
    assert contents.payloads == _by_channel(messages)
    assert contents.metadata == {"test.meta": {"k": "v", "empty": ""}}
    assert [s.name for s in contents.schemas.values()] == ["test.a", "test.b"]  # the same schema once
    assert {c.topic: c.schema_id for c in contents.channels.values()} == {"/a": 1, "/b": 2, "/a2": 1}

    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        got = [(ch.id, msg.log_time, msg.publish_time, msg.data) for _, ch, msg in reader.iter_messages(log_time_order=False)]
        assert {m.name: m.metadata for m in reader.iter_metadata()} == {"test.meta": {"k": "v", "empty": ""}}
    assert got == [(k + 1, t, t + 1, p) for k, t, p in messages]  # file order is write order
    stats = summary.statistics
    assert stats.message_count == len(messages) and stats.channel_message_counts == {
        cid: len(p) for cid, p in _by_channel(messages).items()}
    assert (stats.message_start_time, stats.message_end_time) == (min(m[1] for m in messages), max(m[1] for m in messages))
    assert stats.chunk_count == len(summary.chunk_indexes) > 5 and stats.metadata_count == 1
    assert all(c.compression == "zstd" for c in summary.chunk_indexes)
    # log times go back within chunks: each chunk index spans its messages' times
    starts = [c.chunk_start_offset for c in summary.chunk_indexes]
    with open(path, "rb") as f:
        records = list(StreamReader(f, validate_crcs=True, emit_chunks=True).records)
    chunks = [r for r in records if type(r).__name__ == "Chunk"]
    assert len(chunks) == len(starts)
    for index, chunk in zip(summary.chunk_indexes, chunks):
        assert (index.message_start_time, index.message_end_time) == (chunk.message_start_time, chunk.message_end_time)
        assert index.message_start_time <= index.message_end_time
    # message indexes name every message of their chunk
    with open(path, "rb") as f:
        indexed = sum(len(r.records) for r in StreamReader(f).records if type(r).__name__ == "MessageIndex")
    assert indexed == len(messages)


def test_chunks_close_by_size_by_age_and_on_flush(tmp_path):
    path = tmp_path / "r.mcap"
    with McapRecorder(path, chunk_size_bytes=10**9, chunk_interval_s=0.05) as recorder:
        cid = recorder.add_channel("/a", SCHEMA_A)
        recorder.write(cid, 5, b"one")
        assert read_mcap_contents(path).payloads == {}  # still in the open chunk
        time.sleep(0.1)
        recorder.write(cid, 3, b"two")  # the chunk is older than its interval: written with this message
        assert read_mcap_contents(path).payloads == {cid: [b"one", b"two"]}
        recorder.write(cid, 4, b"three")
        recorder.flush()
        assert read_mcap_contents(path).payloads == {cid: [b"one", b"two", b"three"]}
        recorder.flush()  # nothing open: no empty chunk
    with open(path, "rb") as f:
        assert make_reader(f).get_summary().statistics.chunk_count == 2
    with McapRecorder(path, chunk_size_bytes=1, chunk_interval_s=1e9) as recorder:  # every message fills a chunk
        cid = recorder.add_channel("/a", SCHEMA_A)
        for i in range(7):
            recorder.write(cid, i, b"x")
    with open(path, "rb") as f:
        assert make_reader(f).get_summary().statistics.chunk_count == 7


def test_threads_write_at_once(tmp_path):
    path = tmp_path / "r.mcap"
    n = 2000
    with McapRecorder(path, chunk_size_bytes=4096) as recorder:
        ids = [recorder.add_channel(f"/t{k}", SCHEMA_A) for k in range(4)]

        def work(cid):
            for i in range(n):
                recorder.write(cid, i, f"{cid}:{i}".encode())
                if i % 97 == 0:
                    recorder.flush()

        threads = [threading.Thread(target=work, args=(cid,)) for cid in ids]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
    contents = read_mcap_contents(path)
    assert contents.payloads == {cid: [f"{cid}:{i}".encode() for i in range(n)] for cid in ids}
    assert contents.statistics.message_count == 4 * n


def test_close_is_idempotent_and_final(tmp_path):
    path = tmp_path / "r.mcap"
    recorder = McapRecorder(path)
    cid = recorder.add_channel("/a", SCHEMA_A)
    recorder.write(cid, 1, b"x")
    recorder.close()
    size = path.stat().st_size
    recorder.close()
    assert path.stat().st_size == size
    for call in (lambda: recorder.write(cid, 2, b"y"), recorder.flush, lambda: recorder.add_channel("/b", SCHEMA_B)):
        with pytest.raises(ValueError, match="closed"):
            call()
    with McapRecorder(tmp_path / "e.mcap") as empty:
        with pytest.raises(ValueError, match="no channel 1"):
            empty.write(1, 0, b"")
    contents = read_mcap_contents(tmp_path / "e.mcap")
    assert not contents.unclosed and contents.payloads == {} and contents.statistics.message_count == 0


def test_unwritable_path_is_one_line(tmp_path):
    with pytest.raises(FileFormatError, match="no such folder"):
        McapRecorder(tmp_path / "missing" / "r.mcap")


# ---------------------------------------------------------------------------
# An unclosed recording
# ---------------------------------------------------------------------------


def test_every_cut_reads_up_to_its_last_complete_chunk(tmp_path):
    """The file cut at each byte: what an unclosed recording is at any moment (a closed one cut in its summary too)."""
    path = tmp_path / "r.mcap"
    per_chunk = 6
    messages = _messages(7 * per_chunk + 5, seed=1, max_bytes=12)
    _record(path, messages, flush_every=per_chunk, chunk_size_bytes=10**9, chunk_interval_s=1e9)
    data = path.read_bytes()
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    chunk_ends = sorted(c.chunk_start_offset + c.chunk_length for c in summary.chunk_indexes)
    [meta] = summary.metadata_indexes
    assert len(chunk_ends) == 8 and meta.offset + meta.length < chunk_ends[0]
    header_end = 8 + 9 + int.from_bytes(data[9:17], "little")
    cut_path = tmp_path / "cut.mcap"
    for size in range(1, len(data)):
        cut_path.write_bytes(data[:size])
        if size < header_end:  # not even the header: nothing says who wrote it
            with pytest.raises(FileFormatError, match="truncated MCAP file|not an MCAP file"):
                read_mcap_contents(cut_path)
            continue
        contents = read_mcap_contents(cut_path)
        complete = sum(end <= size for end in chunk_ends)
        assert contents.unclosed, size
        assert contents.payloads == _by_channel(messages[: min(complete * per_chunk, len(messages))]), size
        assert contents.metadata == ({"test.meta": {"k": "v", "empty": ""}} if size >= meta.offset + meta.length else {}), size
    assert not read_mcap_contents(path).unclosed


def test_corrupt_complete_chunk_of_an_unclosed_recording_is_refused(tmp_path):
    path = tmp_path / "r.mcap"
    recorder = _record(path, _messages(200), flush_every=50, close=False, chunk_size_bytes=10**9)
    data = bytearray(path.read_bytes())
    recorder.close()
    with open(path, "rb") as f:
        first = min(make_reader(f).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)
    data[first.chunk_start_offset + first.chunk_length - 3] ^= 0xFF  # inside the compressed messages
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    with pytest.raises(FileFormatError, match="corrupt MCAP file"):
        read_mcap_contents(bad)


@pytest.mark.parametrize("library", ["someone-else", f"graphpos {__version__}", "graphpos-live"])
def test_unclosed_file_of_another_writer_is_refused(tmp_path, library):
    path = tmp_path / "r.mcap"
    recorder = _record(path, _messages(100), flush_every=10, close=False, library=library)
    copy = tmp_path / "copy.mcap"
    copy.write_bytes(path.read_bytes())
    recorder.close()
    assert read_mcap_contents(path).payloads  # closed, it reads
    with pytest.raises(FileFormatError, match=r"truncated MCAP file \(no footer; was writing interrupted\?\)"):
        read_mcap_contents(copy)


WRITER = """
import sys
from graphpos.drive import Drive
from graphpos.io.mcap_drive import channel_schema, drive_metadata, encode_row, log_time_ns
from graphpos.io.mcap_recorder import McapRecorder

recorder = McapRecorder(sys.argv[1], chunk_size_bytes=10**9, chunk_interval_s=1e9)
recorder.add_metadata("graphpos.drive", drive_metadata(Drive("killed", {})))
cid = recorder.add_channel("/wheel", channel_schema("wheel"))
i = 0
while True:
    t_s = i * 0.01
    recorder.write(cid, log_time_ns(t_s), encode_row("wheel", {"t_s": t_s, "speed_mps": (i % 1000) * 0.01 + 0.001}))
    i += 1
    if i % 50 == 0:
        recorder.flush()
        print(i, flush=True)
        if sys.argv[2] == "pause" and i <= 400:  # wait for the reader
            sys.stdin.readline()
    if sys.argv[2] == "pause" and i == 420:  # 20 messages into the open chunk
        print("paused", flush=True)
        sys.stdin.readline()
"""


@pytest.mark.parametrize("moment", ["while-writing", "in-an-open-chunk"])
def test_recording_killed_while_it_writes_reads_up_to_its_last_chunk(tmp_path, capsys, moment):
    """SIGKILL at any moment of writing (a chunk may be cut), or with messages in the open chunk (which are lost):
    the file reads every row of the chunks flushed before, rows a prefix of those written. In the second case
    the file is also read after each flush while its writer waits: every flushed row is there."""
    path = tmp_path / "live.mcap"
    mode = "pause" if moment == "in-an-open-chunk" else "run"
    child = subprocess.Popen([sys.executable, "-c", WRITER, str(path), mode], stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        flushed = []
        for _ in range(8):
            flushed.append(int(child.stdout.readline()))
            if mode == "pause":
                assert len(read_drive(path).wheel) == flushed[-1]  # in the OS, while the writer lives
                child.stdin.write("go on\n")
                child.stdin.flush()
        if mode == "pause":
            assert child.stdout.readline().strip() == "paused"
        child.send_signal(signal.SIGKILL)
        child.wait(10)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait(10)
        for stream in (child.stdin, child.stdout, child.stderr):
            stream.close()
    assert child.returncode == -signal.SIGKILL and flushed[-1] == 400
    drive = read_drive(path)
    assert drive.name == "killed" and drive.params == {"unclosed_recording": True}
    wheel = drive.wheel
    n = len(wheel)
    assert n == 400 if mode == "pause" else n >= 400
    i = np.arange(n)
    assert wheel.t_s.tobytes() == (i * 0.01).tobytes()
    assert wheel.speed_mps.tobytes() == ((i % 1000) * 0.01 + 0.001).tobytes()
    [check] = [c for c in drive_checks(drive) if c["name"] == "closed-file"]
    expected = (f"the recording was not closed (its writer was stopped) and was read up to its last complete chunk, "
                f"ending at t = {wheel.t_s[-1]:.3f} s")
    assert check["verdict"] == "warning" and check["message"] == expected
    assert main(["info", str(path)]) == 0
    out, err = capsys.readouterr()
    assert f"graphpos info: warning: {path}: {expected} (drive check 'closed-file')" in err.splitlines()
    assert any(line.split()[:3] == ["closed-file", "warning", "warning"] for line in out.splitlines())


def test_closed_drive_has_no_unclosed_warning(tmp_path):
    path = tmp_path / "d.mcap"
    write_drive(path, Drive("d", {"wheel": Channel("wheel", {"t_s": [0.0, 1.0], "speed_mps": [1.0, 1.0]})}))
    drive = read_drive(path)
    assert "unclosed_recording" not in drive.params
    assert [c["verdict"] for c in drive_checks(drive) if c["name"] == "closed-file"] == ["ok"]


# ---------------------------------------------------------------------------
# Drives row by row
# ---------------------------------------------------------------------------


def _record_drive(path, drive: Drive, rows: list[OutputRow] = (), fields=(), close=True) -> McapRecorder:
    """A drive recorded as live records it: rows in arrival order, one message each."""
    recorder = McapRecorder(path, chunk_size_bytes=16 * 1024)
    meta = drive_metadata(drive)
    base_s = float(meta["time_base_s"])
    recorder.add_metadata("graphpos.drive", meta)
    ids = {kind: recorder.add_channel(f"/{kind}", channel_schema(kind)) for kind in drive.channels}
    for m in drive.measurements(CHANNEL_NAMES, by="arrival"):
        recorder.write(ids[m.channel], log_time_ns(m.t_s, base_s), encode_row(m.channel, m.values))
    if rows:
        cid = recorder.add_channel("/estimates/live-ekf", estimate_schema(), estimate_channel_metadata("live-ekf", fields, 10.0))
        for row in rows:
            recorder.write(cid, log_time_ns(row.t_s, base_s), encode_estimate_row(row))
    if close:
        recorder.close()
    return recorder


def _output_rows(drive: Drive) -> list[OutputRow]:
    truth = drive.truth
    return [OutputRow(float(t), float(e), float(n), float(ve), None, float(y) if k % 3 else float("nan"),
                      np.array([[0.5, 0.01], [0.01 + 1e-12, 0.25 * k]]))
            for k, (t, e, n, ve, y) in enumerate(zip(truth.t_s[::10], truth.east_m[::10], truth.north_m[::10],
                                                     truth.v_east_mps[::10], truth.yaw_rad[::10]))]


@pytest.fixture(scope="module")
def sim_drive() -> Drive:
    return simulate("paper-straight", seed=0, duration_s=8.0, rfid_latency_s=(0.0, 0.3))


def test_drive_recorded_row_by_row_reads_back_equal(tmp_path, sim_drive):
    path = tmp_path / "live.mcap"
    rows = _output_rows(sim_drive)
    _record_drive(path, sim_drive, rows, fields=("v_east_mps", "yaw_rad", "cov_en_m2"))
    assert_drives_equal(sim_drive, read_drive(path))
    [estimate] = read_estimates(path)
    expected = Estimate.from_rows("live-ekf", rows, rate_hz=10.0)
    assert expected.v_north_mps is None and estimate.v_north_mps is None
    assert_estimates_equal(expected, estimate)


def test_unclosed_drive_recording_reads_a_prefix(tmp_path, sim_drive):
    path = tmp_path / "live.mcap"
    recorder = _record_drive(path, sim_drive, close=False)
    copy = tmp_path / "copy.mcap"
    copy.write_bytes(path.read_bytes())
    recorder.close()
    drive = read_drive(copy)
    assert drive.params == {**sim_drive.params, "unclosed_recording": True}
    assert 0 < sum(len(ch) for ch in drive.channels.values()) < sum(len(ch) for ch in sim_drive.channels.values())
    for kind, ch in drive.channels.items():
        n = len(ch)
        for name, column in ch.columns.items():
            assert np.array_equal(column, sim_drive.channels[kind][name][:n], equal_nan=True), (kind, name)


def test_one_row_encoders_are_the_batch_writers(tmp_path, drive, estimate):
    """Each message write_drive writes is what the one-row encoders give for its row."""
    path = tmp_path / "d.mcap"
    write_drive(path, drive, estimates=[estimate])
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        topics: dict[str, list] = {}
        for _, channel, message in reader.iter_messages(log_time_order=False):
            topics.setdefault(channel.topic, []).append((message.log_time, message.data))
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    assert metadata["graphpos.drive"] == drive_metadata(drive)
    schemas = {s.name: json.loads(s.data) for s in summary.schemas.values()}
    for kind, ch in drive.channels.items():
        assert schemas[f"graphpos.{kind}"] == channel_schema(kind)
        names = list(ch.columns)
        rows = np.column_stack([ch[name] for name in names]).tolist()
        assert [p for _, p in topics[f"/{kind}"]] == [encode_row(kind, dict(zip(names, row))) for row in rows], kind
        assert [t for t, _ in topics[f"/{kind}"]] == [log_time_ns(t) for t in ch.t_s]
    assert schemas["graphpos.estimate"] == estimate_schema()
    assert schemas["foxglove.LocationFix"] == LOCATION_FIX_SCHEMA and schemas["foxglove.PoseInFrame"] == POSE_IN_FRAME_SCHEMA
    assert schemas["foxglove.GeoJSON"] == GEOJSON_SCHEMA and [p for _, p in topics["/map"]] == [map_geojson_payload(drive, drive.origin)]
    est_rows = [OutputRow(*(None if getattr(estimate, f) is None else getattr(estimate, f)[k]
                            for f in ("t_s", "east_m", "north_m", "v_east_mps", "v_north_mps", "yaw_rad", "cov_en_m2")))
                for k in range(len(estimate))]
    assert [p for _, p in topics["/estimates/fusion-ekf"]] == [encode_estimate_row(r) for r in est_rows]
    [channel] = [c for c in summary.channels.values() if c.topic == "/estimates/fusion-ekf"]
    assert channel.metadata == estimate_channel_metadata(estimate.name, ("v_east_mps", "v_north_mps", "yaw_rad", "cov_en_m2"),
                                                         estimate.rate_hz, estimate.wall_time_s, estimate.diagnostics)
    origin = drive.origin
    for t_ns, payload in topics["/estimates/fusion-ekf/pose"]:
        k = int(np.flatnonzero(np.array([log_time_ns(t) for t in estimate.t_s]) == t_ns)[0])
        assert payload == pose_payload(t_ns, estimate.east_m[k], estimate.north_m[k], estimate.yaw_rad[k])
    fixes = topics["/estimates/fusion-ekf/fix"]
    assert len(fixes) <= VIEW_RATE_HZ * (estimate.t_s[-1] - estimate.t_s[0]) + 1
    for t_ns, payload in fixes:
        k = int(np.flatnonzero(np.array([log_time_ns(t) for t in estimate.t_s]) == t_ns)[0])
        cov = estimate.cov_en_m2[k]
        assert payload == location_fix_payload(t_ns, estimate.east_m[k], estimate.north_m[k], (cov[0, 0], cov[1, 1]), origin, "fusion-ekf")
    g = drive.gnss
    assert [p for _, p in topics["/gnss/fix"]] == [
        location_fix_payload(log_time_ns(t), e, n, (s**2, s**2), origin, None) for t, e, n, s in zip(g.t_s, g.east_m, g.north_m, g.sigma_m)]
    assert pose_payload(0, 1.0, 2.0, None) == pose_payload(0, 1.0, 2.0, 0.0)


def test_one_row_encoding_rules():
    row = encode_row("rfid", {"t_s": 0.1, "tag_id": 7.0, "rss": float("nan"), "range_m": float("inf")})
    assert row == b'{"t_s":0.1,"tag_id":7,"rss":null,"range_m":1e999,"true_range_m":null,"bearing_rad":null,"arrival_s":0.1}'
    assert encode_row("rfid", {"t_s": 0.1, "tag_id": 7.5}).startswith(b'{"t_s":0.1,"tag_id":7.5,')  # never rounded
    with pytest.raises(DriveError, match="missing required column 'tag_id'"):
        encode_row("rfid", {"t_s": 0.1})
    with pytest.raises(DriveError, match="unknown column"):
        encode_row("wheel", {"t_s": 0.1, "speed_mps": 1.0, "speed": 1.0})
    with pytest.raises(DriveError, match="unknown channel"):
        encode_row("lidar", {"t_s": 0.1})
    assert encode_estimate_row(OutputRow(1.0, 2.0, -0.0)) == (
        b'{"t_s":1.0,"east_m":2.0,"north_m":-0.0,"v_east_mps":null,"v_north_mps":null,"yaw_rad":null,"cov_en_m2":null}')
    assert estimate_channel_metadata("x", ["yaw_rad"], 5) == {
        "estimator": "x", "fields": "yaw_rad", "rate_hz": "5.0", "wall_time_s": "nan", "diagnostics": "{}"}


# ---------------------------------------------------------------------------
# Rows in arrival order
# ---------------------------------------------------------------------------

TAGS = TagMap([1, 2], [0.0, 5.0], [1.0, -1.0], [1, -1], [0, 0])


def _write_rows(path, kind: str, rows: list[dict[str, float]], library: str = f"graphpos live {__version__}") -> None:
    with McapRecorder(path, library=library) as recorder:
        recorder.add_metadata("graphpos.drive", drive_metadata(Drive("late", {}, tags=TAGS)))
        cid = recorder.add_channel(f"/{kind}", channel_schema(kind))
        for row in rows:
            recorder.write(cid, log_time_ns(row["t_s"]), encode_row(kind, row))


def test_rows_in_arrival_order_read_back_sorted_by_time(tmp_path):
    path = tmp_path / "late.mcap"
    t_s = [1.0, 0.9, 1.2, 1.1, 1.2, 1.3]  # 0.9 and 1.1 arrive late; the two at 1.2 keep their order
    arrival_s = [1.05, 1.1, 1.25, 1.3, 1.3, 1.35]
    rows = [{"t_s": t, "tag_id": 1 + k % 2, "rss": 100.0 + k, "arrival_s": a} for k, (t, a) in enumerate(zip(t_s, arrival_s))]
    _write_rows(path, "rfid", rows)
    rfid = read_drive(path).rfid
    order = [1, 0, 3, 2, 4, 5]
    assert rfid.t_s.tolist() == [t_s[k] for k in order]
    assert rfid.arrival_s.tolist() == [arrival_s[k] for k in order]
    assert rfid.rss.tolist() == [100.0 + k for k in order]
    assert rfid.tag_id.tolist() == [1 + k % 2 for k in order]


@pytest.mark.parametrize("case", ["arrival-goes-back", "no-arrival", "no-arrival-column", "other-writer"])
def test_time_going_back_otherwise_is_still_refused(tmp_path, case):
    path = tmp_path / "late.mcap"
    if case == "other-writer":  # only graphpos live writes rows in arrival order
        _write_rows(path, "rfid", [{"t_s": 1.0, "tag_id": 1, "arrival_s": 1.1}, {"t_s": 0.5, "tag_id": 2, "arrival_s": 1.2}],
                    library=f"graphpos {__version__}")
    elif case == "no-arrival-column":
        _write_rows(path, "wheel", [{"t_s": 1.0, "speed_mps": 1.0}, {"t_s": 0.5, "speed_mps": 1.0}])
    else:
        arrival = [1.2, 1.1] if case == "arrival-goes-back" else [float("nan")] * 2
        _write_rows(path, "rfid", [{"t_s": 1.0, "tag_id": 1, "arrival_s": arrival[0]},
                                   {"t_s": 0.5, "tag_id": 2, "arrival_s": arrival[1]}])
    with pytest.raises(DriveError, match=r"row 1: time goes backwards \(1.0 -> 0.5\)"):
        read_drive(path)


def test_error_in_sorted_rows_names_the_row_of_the_file(tmp_path):
    path = tmp_path / "late.mcap"
    _write_rows(path, "rfid", [{"t_s": 1.0, "tag_id": 1, "arrival_s": 1.1}, {"t_s": 0.5, "tag_id": 2, "arrival_s": 1.2},
                               {"t_s": 1.5, "tag_id": 1, "arrival_s": 1.3}])  # row 2 arrives before it is taken
    with pytest.raises(DriveError, match="channel 'rfid', row 2: arrival_s is before t_s"):
        read_drive(path)
