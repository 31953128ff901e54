"""Simulator parameters ``sensors`` and ``rfid.reader_range_m``: a vehicle's sensor set and reader range."""

from __future__ import annotations

import numpy as np
import pytest

from graphpos.errors import ConfigError
from graphpos.sim import simulate


def test_a_sensor_set_drops_channels_and_leaves_the_others_bit_identical():
    full = simulate("paper-straight", seed=3)
    some = simulate("paper-straight", seed=3, overrides={"sensors": "imu, rfid"})
    assert sorted(some.channels) == ["imu", "rfid", "truth"]
    for name in some.channels:
        assert some.channels[name] == full.channels[name], name


def test_a_shorter_reader_range_hears_only_the_nearer_tags():
    full = simulate("paper-straight", seed=3)
    near = simulate("paper-straight", seed=3, overrides={"rfid": {"reader_range_m": 5.0}})
    assert full.rfid.true_range_m.max() > 8.0 and 4.0 < near.rfid.true_range_m.max() <= 5.0
    kept = full.rfid.true_range_m <= 5.0
    assert np.array_equal(near.rfid.t_s, full.rfid.t_s[kept]) and np.array_equal(near.rfid.tag_id, full.rfid.tag_id[kept])


@pytest.mark.parametrize("overrides, needle", [({"sensors": "imu,radar"}, "sensors"), ({"sensors": " , "}, "sensors"),
                                               ({"rfid": {"reader_range_m": 9.5}}, "reader_range_m"),
                                               ({"rfid": {"reader_range_m": 0.0}}, "reader_range_m")])
def test_bad_sensor_sets_and_reader_ranges_are_refused(overrides, needle):
    with pytest.raises(ConfigError, match=needle):
        simulate("paper-straight", seed=0, overrides=overrides)
