"""Fixtures of the hardening tests (``samples``, ``small``: drive files shared by the corpora).

The bad-input corpus builds on the I/O tests' sample files (a hand-built
drive with every channel, a synthetic Plaza .mat): their folder is put on the
import path so the samples are written once, not copied.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "io"))


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """A short drive with every channel, maps, windows and params (quick to rewrite)."""
    from drive_samples import every_channel_drive

    from graphpos.io import write_drive

    path = tmp_path_factory.mktemp("small") / "every.mcap"
    write_drive(path, every_channel_drive(n=40))
    return path


@pytest.fixture(scope="module")
def samples(tmp_path_factory):
    """Good source files: the hand-built every-channel drive, a short simulated drive, a synthetic Plaza .mat."""
    from drive_samples import every_channel_drive
    from plaza_samples import synthetic_plaza

    from graphpos.io import write_drive
    from graphpos.sim import simulate

    folder = tmp_path_factory.mktemp("good")
    write_drive(folder / "every.mcap", every_channel_drive())
    sim = simulate("paper-straight", seed=1, duration_s=12.0)
    write_drive(folder / "sim.mcap", sim)
    write_drive(folder / "one-second.mcap", simulate("paper-straight", seed=1, duration_s=1.0))
    write_drive(folder / "no-truth.mcap", sim.replace(channels={k: v for k, v in sim.channels.items() if k != "truth"}))
    synthetic_plaza(folder / "plaza.mat")
    return {"every": folder / "every.mcap", "sim": folder / "sim.mcap", "one-second": folder / "one-second.mcap",
            "no-truth": folder / "no-truth.mcap", "mat": folder / "plaza.mat"}
