"""``graphpos live`` fed by ``graphpos replay`` over loopback, as a user runs them (issue 16).

- A drive replayed over TCP gives, in the recording, the causal output of
  the offline ``run`` of the same estimators (to 1e-9 m), and a Foxglove
  WebSocket client receives the estimates as they are published.
- A UDP stream with 5 % lost, 5 % duplicated, 5 % reordered and 1 %
  garbled messages runs to the end, every kind of damage counted.
- SIGKILL mid-drive leaves a recording that reads up to its last chunk;
  SIGTERM closes it whole.
"""

from __future__ import annotations

import json
import math
import signal
import socket
import threading
import time

import numpy as np
import pytest
from live_helpers import FoxgloveClient, LiveProcess, replay

from graphpos.io import read_drive, read_estimates, write_drive
from graphpos.io.mcap_container import read_mcap_contents
from graphpos.registry import make_estimator
from graphpos.sim import simulate

ESTIMATORS = ("graph-isam2", "graph-fixed-lag", "fusion-ekf", "rfid-ekf")


@pytest.fixture(scope="module")
def drive_path(tmp_path_factory):
    """30 s of the papers' comprehensive drive, RFID readings arriving 0-0.3 s late."""
    path = tmp_path_factory.mktemp("live") / "drive.mcap"
    write_drive(path, simulate("paper-comprehensive", seed=3, duration_s=30, rfid_latency_s=(0.0, 0.3)))
    return path


def _read_datagrams(sock, into: list) -> None:
    while True:
        try:
            into.append(json.loads(sock.recv(65536)))
        except TimeoutError:
            continue
        except OSError:
            return


def _offline(drive_path, name):
    return make_estimator(name).run(read_drive(drive_path).without_truth())


def test_replayed_drive_gives_the_offline_output_and_reaches_foxglove(drive_path, tmp_path):
    rec = tmp_path / "rec.mcap"
    udp_out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    udp_out.bind(("127.0.0.1", 0))
    udp_out.settimeout(0.5)
    live = LiveProcess("--site", str(drive_path), *(a for n in ESTIMATORS for a in ("-e", n)), "--listen", "tcp://127.0.0.1:0",
                       "--foxglove", "127.0.0.1:0", "--udp-out", f"udp://127.0.0.1:{udp_out.getsockname()[1]}", "-o", str(rec),
                       cwd=tmp_path)
    datagrams = []
    reader = threading.Thread(target=_read_datagrams, args=(udp_out, datagrams), daemon=True)
    reader.start()
    try:
        client = FoxgloveClient(live.foxglove)
        replay(drive_path, live.listen, "--speed", "10", cwd=tmp_path)
        status, final = live.result()
        time.sleep(0.5)
        client.close()
    finally:
        live.kill()
        udp_out.close()
    assert status == 0, "\n".join(live.stderr)
    assert final["ended"] and final["lost"] == 0 and final["malformed_total"] == 0
    recorded = {e.name: e for e in read_estimates(rec)}
    for name in ESTIMATORS:
        offline = _offline(drive_path, name)
        got = recorded[name]
        assert final["estimators"][name]["status"] == "finished"
        assert len(got) == len(offline) > 20
        np.testing.assert_array_equal(got.t_s, offline.t_s)
        assert np.max(np.abs(got.position - offline.position)) <= 1e-9
        if offline.cov_en_m2 is not None:
            np.testing.assert_allclose(got.cov_en_m2, offline.cov_en_m2, rtol=0, atol=1e-9)  # as the positions: 2e-12 m² seen between processes
        # the Foxglove client saw the estimates as published: JSON rows, a LocationFix and a pose each
        seen = client.messages.get(f"/estimates/{name}", [])
        assert len(seen) >= 0.9 * len(offline), f"{name}: {len(seen)} of {len(offline)} estimates reached the client"
        by_t = {t: i for i, t in enumerate(offline.t_s.tolist())}
        for row in seen:
            i = by_t[row["t_s"]]
            assert abs(row["east_m"] - offline.east_m[i]) <= 1e-9 and abs(row["north_m"] - offline.north_m[i]) <= 1e-9
        assert client.schemas[f"/estimates/{name}/fix"] == "foxglove.LocationFix"
        assert len(client.messages[f"/estimates/{name}/fix"]) >= 0.9 * len(offline)
    # every estimate also went out as a UDP JSON datagram
    for name in ESTIMATORS:
        sent = [d for d in datagrams if d["estimator"] == name]
        assert [d["t_s"] for d in sent] == recorded[name].t_s.tolist()
        assert all(math.isfinite(d["lat_deg"]) and math.isfinite(d["lon_deg"]) for d in sent)
    # the recording holds each measurement's receipt-to-publish latency, per estimator
    contents = read_mcap_contents(rec)
    latency = {c.topic: len(contents.payloads.get(cid, [])) for cid, c in contents.channels.items() if c.topic.endswith("/latency")}
    assert latency == {f"/live/{n}/latency": final["estimators"][n]["processed"] for n in ESTIMATORS}
    assert all(final["estimators"][n]["processed"] >= final["accepted"] * 0.03 for n in ESTIMATORS)
    # the recording is a drive: the accepted inputs, which run offline give the same estimate again
    again = make_estimator("graph-isam2").run(read_drive(rec))
    assert np.max(np.abs(again.position - recorded["graph-isam2"].position)) <= 1e-9


def test_a_damaged_udp_stream_runs_to_the_end_with_the_damage_counted(drive_path, tmp_path):
    rec = tmp_path / "rec.mcap"
    live = LiveProcess("--site", str(drive_path), "-e", "graph-isam2", "-e", "fusion-ekf", "--listen", "udp://127.0.0.1:0",
                       "--no-foxglove", "-o", str(rec), cwd=tmp_path)
    try:
        sent = replay(drive_path, live.listen, "--speed", "10", "--loss", "0.05", "--duplicate", "0.05", "--reorder", "0.05",
                      "--malformed", "0.01", "--seed", "7", cwd=tmp_path)
        status, final = live.result()
    finally:
        live.kill()
    assert status == 0, "\n".join(live.stderr)
    assert final["ended"]
    n = sent["messages"]
    assert sent["lost"] > 0.03 * n and sent["duplicated"] > 0.03 * n and sent["reordered"] > 0.03 * n and sum(sent["malformed"].values()) > 0
    assert sent["sent"] == n - sent["lost"] + sent["duplicated"]  # the datagrams of the measurements, no more
    # the end-of-drive message is sent three times: the two copies after it are never read
    assert final["duplicates"] == sent["duplicated"]
    assert final["malformed_total"] == sum(sent["malformed"].values())
    # a garbled message whose seq cannot be read is, to the receiver, a lost one; a loss at the very start is invisible
    assert sent["lost"] + sent["malformed_unreadable"] - 1 <= final["lost"] <= sent["lost"] + sent["malformed_unreadable"]
    # a held-back message arrives after a later one (unless that one was lost)
    assert 0.8 * sent["reordered"] <= final["reordered"] <= sent["reordered"]
    assert sum(final["out_of_order"].values()) > 0  # IMU and wheel samples that came too late to integrate
    for name in ("graph-isam2", "fusion-ekf"):
        e = final["estimators"][name]
        assert e["status"] == "finished", e
    estimates = {e.name: e for e in read_estimates(rec)}
    truth = read_drive(drive_path).truth
    for name, est in estimates.items():
        assert est.t_s[-1] > truth.t_s[-1] - 1.0, f"{name} stopped before the end"
        err = np.hypot(est.east_m - np.interp(est.t_s, truth.t_s, truth.east_m), est.north_m - np.interp(est.t_s, truth.t_s, truth.north_m))
        assert np.sqrt(np.mean(err**2)) < 3.0, f"{name}: RMS {np.sqrt(np.mean(err ** 2)):.2f} m on the damaged stream"


def _wait_for_chunks(rec, min_bytes: int) -> None:
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and (not rec.exists() or rec.stat().st_size < min_bytes):
        time.sleep(0.1)


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_a_stopped_live_leaves_a_recording_that_reads(drive_path, tmp_path, sig):
    import subprocess
    import sys

    rec = tmp_path / "rec.mcap"
    live = LiveProcess("--site", str(drive_path), "-e", "fusion-ekf", "--listen", "udp://127.0.0.1:0", "--no-foxglove",
                       "--quiet", "-o", str(rec), cwd=tmp_path)
    sender = subprocess.Popen([sys.executable, "-m", "graphpos", "replay", str(drive_path), "--to", live.listen, "--speed", "2"],
                              cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        _wait_for_chunks(rec, 40_000)
        live.proc.send_signal(sig)
        live.proc.wait(timeout=60)
    finally:
        sender.kill()
        live.kill()
    drive = read_drive(rec)
    (est,) = read_estimates(rec)
    assert len(drive.imu) > 100 and len(est) > 10
    original = read_drive(drive_path).imu
    n = len(drive.imu)
    np.testing.assert_array_equal(drive.imu.t_s, original.t_s[:n])  # a prefix of what was sent, nothing invented
    if sig == signal.SIGKILL:
        assert drive.params.get("unclosed_recording") is True
    else:
        assert live.proc.returncode == 0
        assert not drive.params.get("unclosed_recording")


def test_the_readmes_two_live_commands_work_as_written(tmp_path):
    """The README's live block, as it stands (the replay sped up 20 times): live exits when the drive ends,
    with both estimators' outputs in the recording."""
    import shlex
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "core"))
    from test_readme_tour import sh_block

    live_line, replay_line = sh_block("## Live: watch a drive in Foxglove as it is driven")
    (tmp_path / "work").mkdir()
    write_drive(tmp_path / "work/straight.mcap", simulate("paper-straight", pattern="accel", seed=3))
    live_args = shlex.split(live_line)
    assert live_args[:2] == ["graphpos", "live"]
    live = LiveProcess(*live_args[2:], cwd=tmp_path)
    try:
        replay_args = shlex.split(replay_line)
        assert replay_args[:2] == ["graphpos", "replay"] and replay_args[-1] == live.listen
        replay(Path(replay_args[2]), replay_args[-1], "--speed", "20", cwd=tmp_path)
        status, final = live.result()
    finally:
        live.kill()
    assert status == 0 and final["ended"], "\n".join(live.stderr)
    assert {e.name for e in read_estimates(tmp_path / "work/live.mcap")} == {"graph-isam2", "fusion-ekf"}
