"""Every scenario's drive (with latency and faults) survives the MCAP file losslessly."""

from __future__ import annotations

import numpy as np
import pytest

from graphpos.sim import SCENARIOS, simulate

io = pytest.importorskip("graphpos.io")


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_round_trip(name, tmp_path):
    drive = simulate(name, seed=7, duration_s=40.0, rfid_latency_s=(0.5, 2.0),
                     faults={"dropped_samples": {"fraction": 0.01}, "wheel_slip": {"start_s": 5, "duration_s": 5}})
    path = tmp_path / f"{name}.mcap"
    io.write_drive(path, drive)
    back = io.read_drive(path)
    assert set(back.channels) == set(drive.channels)
    for channel, ch in drive.channels.items():
        assert back.channels[channel] == ch, channel
    assert back.tags == drive.tags and back.rsus == drive.rsus
    assert back.windows == drive.windows
    assert back.params == drive.params
    assert np.isclose(back.duration_s, drive.duration_s)
