"""Drive model: validation names channel, row and reason; merging; layouts."""

import numpy as np
import pytest

from graphpos.drive import CHANNEL_SPECS, Channel, Drive, Measurement, RowRun, RsuMap, TagMap, Window
from graphpos.errors import DriveError


def _valid_columns(kind: str, n: int = 5) -> dict[str, np.ndarray]:
    cols = {}
    for spec in CHANNEL_SPECS[kind]:
        if spec.name == "t_s":
            cols[spec.name] = np.arange(n, dtype=float)
        elif spec.name == "arrival_s":
            cols[spec.name] = np.arange(n, dtype=float) + 0.5
        elif spec.integer:
            cols[spec.name] = np.ones(n)
        else:
            cols[spec.name] = np.full(n, max(spec.lo, min(spec.hi, 1.0)))
    return cols


def _tags() -> TagMap:
    return TagMap([1, 2, 3, 4], [0, 6, 12, 18], [3, -3, 3, -3], [1, -1, 1, -1], [0, 0, 1, 1], layouts={"optimized": [1, 2]})


@pytest.mark.parametrize("kind", list(CHANNEL_SPECS))
def test_every_channel_accepts_valid_columns(kind):
    ch = Channel(kind, _valid_columns(kind))
    assert len(ch) == 5
    assert ch == Channel(kind, _valid_columns(kind))


@pytest.mark.parametrize("kind", list(CHANNEL_SPECS))
@pytest.mark.parametrize("bad", [np.nan, np.inf, 1e17])
def test_bad_value_names_channel_row_and_column(kind, bad):
    for spec in CHANNEL_SPECS[kind]:
        if not spec.required and np.isnan(bad):
            continue  # optional columns may be NaN
        cols = _valid_columns(kind)
        cols[spec.name] = cols[spec.name].copy()
        cols[spec.name][3] = bad
        if spec.name == "arrival_s":  # keep arrival after t
            cols[spec.name][3] = bad if not np.isfinite(bad) else 1e17
        with pytest.raises(DriveError) as info:
            Channel(kind, cols)
        err = info.value
        assert err.channel == kind
        assert spec.name in err.reason or "time" in err.reason or "arrival" in err.reason
        assert err.row is not None


def test_time_going_backwards_is_reported_at_its_row():
    cols = _valid_columns("wheel")
    cols["t_s"] = np.array([0.0, 1.0, 2.0, 1.5, 3.0])
    with pytest.raises(DriveError, match=r"channel 'wheel', row 3: time goes backwards"):
        Channel("wheel", cols)


def test_duplicate_timestamps_are_allowed():
    cols = _valid_columns("wheel")
    cols["t_s"] = np.array([0.0, 1.0, 1.0, 2.0, 3.0])
    assert len(Channel("wheel", cols)) == 5


def test_missing_required_column_and_unknown_column():
    cols = _valid_columns("gnss")
    del cols["sigma_m"]
    with pytest.raises(DriveError, match="missing required column 'sigma_m'"):
        Channel("gnss", cols)
    with pytest.raises(DriveError, match="unknown column"):
        Channel("gnss", {**_valid_columns("gnss"), "height_m": np.zeros(5)})


def test_optional_columns_default_to_nan_and_arrival_to_t():
    ch = Channel("rfid", {"t_s": [0.0, 1.0], "tag_id": [1, 2], "rss": [100, 120]})
    assert np.isnan(ch.range_m).all()
    np.testing.assert_array_equal(ch.arrival_s, ch.t_s)


def test_arrival_before_measurement_is_rejected():
    with pytest.raises(DriveError, match="arrival_s is before t_s"):
        Channel("rfid", {"t_s": [0.0, 1.0], "tag_id": [1, 2], "arrival_s": [0.0, 0.5]})


def test_unknown_tag_id_is_rejected_with_its_row():
    rfid = Channel("rfid", {"t_s": [0.0, 1.0], "tag_id": [1, 9]})
    with pytest.raises(DriveError, match=r"channel 'rfid', row 1: tag id 9 is not in the tag map"):
        Drive("d", {"rfid": rfid}, tags=_tags())


def test_unknown_rsu_and_reading_without_fix_or_range():
    rsus = RsuMap([0], [0.0], [0.0])
    bad_id = Channel("rsu", {"t_s": [0.0], "rsu_id": [3], "range_m": [5.0], "sigma_m": [1.0]})
    with pytest.raises(DriveError, match="RSU id 3"):
        Drive("d", {"rsu": bad_id}, rsus=rsus)
    empty = Channel("rsu", {"t_s": [0.0], "rsu_id": [0], "sigma_m": [1.0]})
    with pytest.raises(DriveError, match="fix or a range"):
        Drive("d", {"rsu": empty}, rsus=rsus)


def test_layouts_and_with_layout():
    tags = _tags()
    assert set(tags.layouts) == {"dense", "optimized"}
    rfid = Channel("rfid", {"t_s": [0.0, 1.0, 2.0], "tag_id": [1, 3, 2], "rss": [1, 2, 3]})
    drive = Drive("d", {"rfid": rfid}, tags=tags)
    only = drive.with_layout("optimized")
    np.testing.assert_array_equal(only.rfid.tag_id, [1, 2])
    assert len(only.tags) == 4
    with pytest.raises(DriveError, match="no layout 'sparse'"):
        drive.with_layout("sparse")
    with pytest.raises(DriveError, match="unknown tag id 7"):
        TagMap([1], [0], [0], [0], [0], layouts={"x": [7]})


def test_tag_positions_by_id():
    tags = _tags()
    np.testing.assert_array_equal(tags.positions(np.array([3, 1])), [[12, 3], [0, 3]])


def test_measurements_merge_by_arrival_with_channel_tie_break():
    imu = Channel("imu", {"t_s": [0.0, 1.0, 2.0], "yaw_rate_radps": [0, 0, 0]})
    rfid = Channel("rfid", {"t_s": [0.0, 0.5], "tag_id": [1, 2], "rss": [1, 2], "arrival_s": [1.0, 2.5]})
    drive = Drive("d", {"imu": imu, "rfid": rfid}, tags=_tags())
    by_arrival = [(m.channel, m.t_s) for m in drive.measurements(["imu", "rfid"])]
    assert by_arrival == [("imu", 0.0), ("imu", 1.0), ("rfid", 0.0), ("imu", 2.0), ("rfid", 0.5)]
    by_time = [(m.channel, m.t_s) for m in drive.measurements(["imu", "rfid"], by="t")]
    assert by_time == [("imu", 0.0), ("rfid", 0.0), ("rfid", 0.5), ("imu", 1.0), ("imu", 2.0)]
    assert not drive.has_accelerometers


def test_feed_gives_runs_of_the_merge_as_columns():
    imu = Channel("imu", {"t_s": [0.0, 1.0, 2.0, 3.0], "yaw_rate_radps": [0.1, 0.2, 0.3, 0.4]})
    wheel = Channel("wheel", {"t_s": [0.5, 2.5], "speed_mps": [5.0, 6.0]})
    rfid = Channel("rfid", {"t_s": [0.0, 0.5], "tag_id": [1, 2], "rss": [1, 2], "arrival_s": [1.0, 2.2]})
    drive = Drive("d", {"imu": imu, "wheel": wheel, "rfid": rfid}, tags=_tags())
    for by in ("arrival", "t"):
        items = list(drive.feed(["imu", "wheel", "rfid"], by=by, runs_of=("imu", "wheel")))
        runs = [item for item in items if isinstance(item, RowRun)]
        flat = [m for item in items for m in ([item] if isinstance(item, Measurement) else [item.measurement(i) for i in range(len(item))])]
        assert list(map(repr, flat)) == list(map(repr, drive.measurements(["imu", "wheel", "rfid"], by=by)))  # repr: NaN fields
        assert all(m.channel == "rfid" for m in items if isinstance(m, Measurement))
        assert sum(map(len, runs)) == 6
        for run in runs:
            assert run.key_s == [m.arrival_s if by == "arrival" else m.t_s for m in (run.measurement(i) for i in range(len(run)))]
    first = next(item for item in drive.feed(["imu", "wheel", "rfid"], runs_of=("imu", "wheel")) if isinstance(item, RowRun))
    assert [first.names[c] for c in first.code] == ["imu", "wheel", "imu"]
    np.testing.assert_array_equal(first.columns["speed_mps"], [np.nan, 5.0, np.nan])
    np.testing.assert_array_equal(first.columns["yaw_rate_radps"], [0.1, np.nan, 0.2])


def test_window_bounds_and_drive_duration():
    with pytest.raises(DriveError, match="bad bounds"):
        Window("in_tunnel", 5.0, 1.0)
    wheel = Channel("wheel", {"t_s": [10.0, 12.5], "speed_mps": [1, 1]})
    drive = Drive("d", {"wheel": wheel}, windows=[Window("in_tunnel", 10.0, 11.0)])
    assert drive.duration_s == 2.5
    assert [w.label for w in drive.window("in_tunnel")] == ["in_tunnel"]
    assert drive.window("curve") == []
