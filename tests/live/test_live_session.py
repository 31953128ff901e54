"""The live session in one process, without sockets: wire format, accounting, a slow estimator, bad options."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import threading
import time

import pytest

from graphpos.drive import Measurement
from graphpos.errors import EstimationError
from graphpos.estimate import OutputRow
from graphpos.io import write_drive
from graphpos.live.feed import LiveFeed
from graphpos.live.malformed import MalformedMessage
from graphpos.live.protocol import Decoder, encode, encode_end
from graphpos.live.session import LiveSession
from graphpos.registry import make_estimator
from graphpos.sim import simulate


@pytest.fixture(scope="module")
def drive():
    return simulate("paper-comprehensive", seed=5, duration_s=8, rfid_latency_s=(0.0, 0.2))


def test_every_measurement_goes_over_the_wire_bit_exact(drive):
    decoder = Decoder(drive)
    view = drive.without_truth()
    for seq, m in enumerate(view.measurements(list(view.channels), by="arrival")):
        got = decoder.decode(encode(m, seq))
        assert got.seq == seq
        assert got.measurement.channel == m.channel and got.measurement.arrival_s == m.arrival_s
        assert list(got.measurement.values) == list(m.values)
        for k, v in m.values.items():
            assert got.measurement.values[k] == v or (math.isnan(v) and math.isnan(got.measurement.values[k])), k
    assert decoder.decode(encode_end(3)).measurement is None


@pytest.mark.parametrize("payload, kind, says", [
    (b"{not json", "json", "not JSON"),
    (b"[1, 2]", "json", "not a JSON object"),
    (b'{"channel": "imu", "t_s": NaN, "yaw_rate_radps": 0}', "json", "not JSON"),
    (b'{"channel": "truth", "t_s": 1}', "channel", "truth is for scoring only"),
    (b'{"channel": "lidar", "t_s": 1}', "channel", "unknown channel 'lidar'"),
    (b'{"channel": "imu", "yaw_rate_radps": 0.1}', "field", "field 't_s' is missing"),
    (b'{"channel": "imu", "t_s": "1.0", "yaw_rate_radps": 0.1}', "field", "not a number"),
    (b'{"channel": "imu", "t_s": true, "yaw_rate_radps": 0.1}', "field", "not a number"),
    (b'{"channel": "imu", "t_s": 1, "yaw_rate_radps": 99}', "field", "outside"),
    (b'{"channel": "rfid", "t_s": 1, "tag_id": 1.5, "rss": 100}', "field", "not a whole number"),
    (b'{"channel": "rfid", "t_s": 1, "tag_id": 999999, "rss": 100}', "id", "not in the site's tag map"),
    (b'{"channel": "rfid", "t_s": 2, "arrival_s": 1, "tag_id": 1, "rss": 100}', "field", "before t_s"),
    (b'{"channel": "imu", "seq": -1, "t_s": 1, "yaw_rate_radps": 0.1}', "field", "seq"),
    (b"x" * 70000, "size", "bytes"),
])
def test_malformed_messages_say_what_is_wrong(drive, payload, kind, says):
    with pytest.raises(MalformedMessage) as bad:
        Decoder(drive).decode(payload)
    assert bad.value.kind == kind and says in str(bad.value) and "\n" not in str(bad.value)


class _Collect:
    def __init__(self):
        self.rows: dict[str, list[OutputRow]] = {}
        self.statuses: list[dict] = []

    def estimate(self, name, row):
        self.rows.setdefault(name, []).append(row)

    def status(self, status):
        self.statuses.append(status)


class _Slow(LiveFeed):
    """fusion-ekf, 20 ms per measurement: far slower than a 200 Hz feed."""

    def process(self, m: Measurement):
        time.sleep(0.02)
        return super().process(m)


def test_a_slow_estimator_reports_its_lag_and_holds_up_neither_input_nor_the_others(drive):
    out = _Collect()
    fast = LiveFeed(make_estimator("fusion-ekf"), drive)
    slow = _Slow(make_estimator("fusion-ekf"), drive)
    slow.name = "slow-fusion-ekf"
    session = LiveSession(drive, [fast, slow], [out], log=lambda line: None)
    stop = threading.Event()
    statuses: list[dict] = []
    runner = threading.Thread(target=lambda: statuses.append(session.run(stop, 0.2, statuses.append)))
    runner.start()
    view = drive.without_truth()
    measurements = list(view.measurements(list(view.channels), by="arrival"))
    t0 = time.monotonic()
    for seq, m in enumerate(measurements[:600]):
        session.receive(encode(m, seq), time.time_ns(), "test")
        time.sleep(0.001)
    session.receive(encode_end(600), time.time_ns(), "test")
    runner.join(120)
    assert not runner.is_alive()
    during = [s for s in statuses if not s["ended"]] or statuses
    lagging = max(s["estimators"]["slow-fusion-ekf"]["queue"] for s in statuses)
    assert lagging > 50 and max(s["estimators"]["slow-fusion-ekf"]["lag_s"] for s in statuses) > 0.5
    assert max(s["estimators"]["fusion-ekf"]["queue"] for s in during) < 50  # the fast one kept up meanwhile
    assert time.monotonic() - t0 > 600 * 0.02  # the slow one was waited for at the end, not dropped
    final = statuses[-1]
    assert final["estimators"]["slow-fusion-ekf"]["status"] == "finished"
    fast_rows, slow_rows = out.rows["fusion-ekf"], out.rows["slow-fusion-ekf"]
    assert len(fast_rows) == len(slow_rows) > 10
    assert max(abs(a.east_m - b.east_m) + abs(a.north_m - b.north_m) for a, b in zip(fast_rows, slow_rows)) == 0.0


@pytest.mark.parametrize("error, traceback_logged", [(RuntimeError("a bug"), True), (EstimationError("a GTSAM failure"), False)])
def test_a_failing_estimator_stops_alone(drive, error, traceback_logged):
    out = _Collect()

    class Broken(LiveFeed):
        def process(self, m):
            if m.t_s > 2.0:
                raise error
            return super().process(m)

    broken = Broken(make_estimator("dr"), drive)
    broken.name = "broken"
    log: list[str] = []
    session = LiveSession(drive, [broken, LiveFeed(make_estimator("dr"), drive)], [out], log=log.append)
    view = drive.without_truth()
    for seq, m in enumerate(view.measurements(list(view.channels), by="arrival")):
        session.receive(encode(m, seq), time.time_ns(), "test")
    session.receive(encode_end(), time.time_ns(), "test")
    final = session.run(threading.Event(), 0.5)
    assert final["estimators"]["broken"]["status"] == "failed" and str(error) in final["estimators"]["broken"]["error"]
    assert final["estimators"]["dr"]["status"] == "finished" and out.rows["dr"][-1].t_s > 7.0
    # a bug's traceback is in the log for a report; an error graphpos raised on purpose says enough itself
    (failure,) = [line for line in log if line.startswith("broken failed")]
    assert ("Traceback (most recent call last)" in failure and "in process" in failure) == traceback_logged


@pytest.mark.parametrize("args, says", [
    (["-e", "graph-batch"], "graph-batch smooths a whole drive"),
    (["-e", "no-such"], "unknown estimator"),
    (["-e", "dr", "--listen", "http://x:1"], "must look like udp://HOST:PORT"),
    (["-e", "dr", "--listen", "udp://127.0.0.1:99999"], "port from 0 to 65535"),
    (["-e", "dr", "--final"], "--final"),
])
def test_bad_live_options_are_one_line(tmp_path, drive, args, says):
    site = tmp_path / "site.mcap"
    write_drive(site, drive)
    done = subprocess.run([sys.executable, "-m", "graphpos", "live", "--site", str(site), "--no-foxglove", "-o", str(tmp_path / "r.mcap"),
                           *args], capture_output=True, timeout=120)
    err = done.stderr.decode().strip()
    assert done.returncode == 2 and len(err.splitlines()) == 1 and says in err, err
    assert not (tmp_path / "r.mcap").exists()


def test_replay_to_nothing_says_so(tmp_path, drive):
    path = tmp_path / "d.mcap"
    write_drive(path, drive)
    done = subprocess.run([sys.executable, "-m", "graphpos", "replay", str(path), "--to", "tcp://127.0.0.1:1"], capture_output=True,
                          timeout=120)
    err = done.stderr.decode().strip()
    assert done.returncode == 2 and len(err.splitlines()) == 1 and "cannot send to tcp://127.0.0.1:1" in err, err


@pytest.mark.skipif(not sys.platform.startswith("linux") or os.geteuid() != 0, reason="SO_RCVBUFFORCE: Linux, as root")
def test_a_udp_listener_gets_its_whole_receive_buffer_beyond_the_kernel_cap():
    """The receive buffer holds about 20 s of readings while the estimators catch up: a privileged listener
    asks past net.core.rmem_max (the kernel reports twice what it allows, its bookkeeping included)."""
    import socket

    from graphpos.live.sources import UDP_BUFFER_BYTES, Address, Listener

    listener = Listener(Address("udp", "127.0.0.1", 0), lambda payload, receipt_ns, where: None)
    try:
        assert listener._sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF) >= UDP_BUFFER_BYTES
    finally:
        listener.close()
