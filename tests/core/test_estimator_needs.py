"""What an estimator needs, as declared, checked and listed (issue 15, item 7: fkf's listing).

An estimator declares the channels it cannot do without (``required_channels``) and groups of which it
needs one (``required_any``: ``(("rsu", "gnss"),)`` is "rsu or gnss"); :meth:`Estimator.check` refuses a
drive that lacks them and ``graphpos estimators`` lists exactly that.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from graphpos.cli import main
from graphpos.drive import Channel, Drive, RsuMap
from graphpos.errors import MissingChannelError
from graphpos.estimator import Estimator


class Fixes(Estimator):
    """Test estimator declared like liu2016's federated KF: dead reckoning and RSU or GNSS fixes."""

    name = "fixes"
    summary = "test: needs imu, wheel and one kind of fix"
    required_channels = ("imu", "wheel")
    required_any = (("rsu", "gnss"),)
    optional_channels = ("compass", "rsu")

    @classmethod
    def default_config(cls):
        return None

    def start(self, drive):
        pass

    def process(self, measurement):
        return []

    def finish(self):
        raise NotImplementedError


def _drive(*channels: str) -> Drive:
    t = np.arange(3.0)
    columns = {
        "imu": {"t_s": t, "yaw_rate_radps": 0 * t},
        "wheel": {"t_s": t, "speed_mps": 0 * t},
        "compass": {"t_s": t, "yaw_rad": 0 * t},
        "gnss": {"t_s": t, "east_m": t, "north_m": t, "sigma_m": 1 + t},
        "rsu": {"t_s": t, "rsu_id": np.zeros(3), "east_m": t, "north_m": t, "sigma_m": 1 + t},
    }
    return Drive("d", {c: Channel(c, columns[c]) for c in channels}, rsus=RsuMap([0], [0.0], [0.0]))


@pytest.mark.parametrize("declared, text", [
    (((), ()), "-"),
    ((("rfid",), ()), "rfid"),
    ((("imu", "wheel", "rfid"), ()), "imu, wheel, rfid"),
    (((), (("wheel", "imu"),)), "wheel or imu"),
    ((("rfid",), (("wheel", "imu"),)), "rfid and wheel or imu"),
    ((("imu", "wheel"), (("rsu", "gnss"),)), "imu, wheel, and rsu or gnss"),
])
def test_needs_reads_as_a_sentence(declared, text):
    required, any_of = declared
    cls = type("E", (Fixes,), {"required_channels": required, "required_any": any_of})
    assert cls.needs() == text


@pytest.mark.parametrize("channels, missing", [
    (("imu", "wheel", "gnss"), None),
    (("imu", "wheel", "rsu"), None),
    (("imu", "wheel"), "needs a channel of rsu or gnss; drive 'd' has none"),
    (("imu", "gnss"), "needs channel(s) wheel"),
])
def test_check_refuses_what_needs_says(channels, missing):
    drive = _drive(*channels)
    if missing is None:
        Fixes().check(drive)
        assert Fixes().channels_used(drive) == tuple(c for c in ("imu", "wheel", "rsu", "gnss") if c in channels)
    else:
        with pytest.raises(MissingChannelError, match=missing.replace("(", r"\(").replace(")", r"\)")):
            Fixes().check(drive)


def test_the_listing_says_what_the_check_wants(monkeypatch, capsys):
    import graphpos.registry

    monkeypatch.setattr(graphpos.registry, "estimator_classes", lambda: {"fixes": Fixes})
    assert main(["estimators"]) == 0
    assert capsys.readouterr().out.splitlines()[0] == "fixes              needs imu, wheel, and rsu or gnss (+ compass)"
    assert main(["estimators", "--json"]) == 0
    row = json.loads(capsys.readouterr().out)[0]
    assert row["needs"] == "imu, wheel, and rsu or gnss"
    assert row["required_channels"] == ["imu", "wheel"] and row["required_any"] == [["rsu", "gnss"]]
    assert row["optional_channels"] == ["compass"]


def test_fkf_is_listed_with_what_it_refuses_a_drive_without():
    from filters.liu2016 import FederatedKf

    assert FederatedKf.needs() == "imu, wheel, and rsu or gnss"
    with pytest.raises(MissingChannelError, match="rsu or gnss"):
        FederatedKf().check(_drive("imu", "wheel"))
    FederatedKf().check(_drive("imu", "wheel", "gnss"))
