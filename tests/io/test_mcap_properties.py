"""Property tests (hypothesis): any valid drive round-trips exactly; no byte
string makes the reader fail with anything but a GraphposError."""

from __future__ import annotations

import numpy as np
import pytest
from drive_samples import assert_drives_equal, assert_estimates_equal, every_channel_drive
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from graphpos.drive import CHANNEL_SPECS, Channel, Drive, GeoOrigin, RsuMap, TagMap, Window
from graphpos.errors import GraphposError
from graphpos.estimate import Estimate
from graphpos.io import read_drive, read_estimates, read_mcap, write_drive

SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def bounded(lo: float, hi: float):
    return st.floats(min_value=lo, max_value=hi, allow_nan=False, allow_infinity=False)


@st.composite
def channels(draw, kind: str, tag_ids: list[int], rsu_ids: list[int]):
    n = draw(st.integers(0, 12))
    t = np.sort(np.array(draw(st.lists(bounded(-1e6, 1e6), min_size=n, max_size=n)), dtype=float))
    columns = {"t_s": t}
    for spec in CHANNEL_SPECS[kind][1:]:
        if spec.name == "arrival_s":
            late = np.array(draw(st.lists(bounded(0.0, 10.0), min_size=n, max_size=n)), dtype=float)
            columns[spec.name] = t + late
        elif spec.name == "tag_id":
            columns[spec.name] = np.array(draw(st.lists(st.sampled_from(tag_ids), min_size=n, max_size=n)), dtype=float)
        elif spec.name == "rsu_id":
            columns[spec.name] = np.array(draw(st.lists(st.sampled_from(rsu_ids), min_size=n, max_size=n)), dtype=float)
        else:
            value = bounded(spec.lo, spec.hi)
            if not spec.required:
                value = st.one_of(st.just(np.nan), value)
            columns[spec.name] = np.array(draw(st.lists(value, min_size=n, max_size=n)), dtype=float)
    if kind == "rsu":  # every reading needs a fix or a range
        columns["range_m"] = np.where(np.isnan(columns["east_m"]) | np.isnan(columns["north_m"]),
                                      np.nan_to_num(columns["range_m"], nan=1.0), columns["range_m"])
    return Channel(kind, columns)


json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-2**53, 2**53) | bounded(-1e300, 1e300) | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=6), inner, max_size=3),
    max_leaves=8,
)


@st.composite
def drives(draw):
    tag_ids = draw(st.lists(st.integers(0, 2**40), min_size=1, max_size=6, unique=True))
    k = len(tag_ids)
    tags = TagMap(
        tag_ids,
        draw(st.lists(bounded(-1e7, 1e7), min_size=k, max_size=k)),
        draw(st.lists(bounded(-1e7, 1e7), min_size=k, max_size=k)),
        draw(st.lists(st.sampled_from([-1, 0, 1]), min_size=k, max_size=k)),
        draw(st.lists(st.integers(-1, 100), min_size=k, max_size=k)),
        layouts={name: draw(st.lists(st.sampled_from(tag_ids), max_size=k, unique=True))
                 for name in draw(st.lists(st.text(min_size=1, max_size=10), max_size=3, unique=True))},
    )
    rsu_ids = draw(st.lists(st.integers(0, 1000), min_size=1, max_size=3, unique=True))
    m = len(rsu_ids)
    rsus = RsuMap(rsu_ids, draw(st.lists(bounded(-1e5, 1e5), min_size=m, max_size=m)),
                  draw(st.lists(bounded(-1e5, 1e5), min_size=m, max_size=m)))
    kinds = draw(st.lists(st.sampled_from(list(CHANNEL_SPECS)), unique=True, max_size=len(CHANNEL_SPECS)))
    windows = tuple(
        Window(label, start, start + length)
        for label, start, length in draw(st.lists(st.tuples(st.text(max_size=12), bounded(-1e6, 1e6), bounded(0, 1e4)), max_size=3))
    )
    return Drive(
        name=draw(st.text(max_size=20)),
        channels={kind: draw(channels(kind, tag_ids, rsu_ids)) for kind in kinds},
        tags=tags,
        rsus=rsus,
        windows=windows,
        origin=GeoOrigin(draw(bounded(-89, 89)), draw(bounded(-180, 180)), draw(bounded(-100, 9000))),
        params=draw(st.dictionaries(st.text(max_size=8), json_values, max_size=4)),
    )


@SETTINGS
@given(drive=drives())
def test_valid_drives_round_trip(tmp_path, drive):
    path = tmp_path / "d.mcap"
    write_drive(path, drive)
    assert_drives_equal(drive, read_drive(path))


@SETTINGS
@given(n=st.integers(0, 8), data=st.data())
def test_estimates_round_trip(tmp_path, n, data):
    def column(nullable: bool):
        values = st.floats(allow_nan=nullable, allow_infinity=True, width=64)
        return np.array(data.draw(st.lists(values, min_size=n, max_size=n)), dtype=float)

    optional = data.draw(st.sets(st.sampled_from(["v_east_mps", "v_north_mps", "yaw_rad", "cov_en_m2"])))
    est = Estimate(
        name=data.draw(st.text(min_size=1, max_size=10).filter(lambda s: "/" not in s)),
        t_s=np.sort(column(False)), east_m=column(False), north_m=column(False),
        v_east_mps=column(True) if "v_east_mps" in optional else None,
        v_north_mps=column(True) if "v_north_mps" in optional else None,
        yaw_rad=column(True) if "yaw_rad" in optional else None,
        cov_en_m2=column(True).repeat(4).reshape(n, 2, 2) if "cov_en_m2" in optional else None,
        rate_hz=data.draw(st.floats()), diagnostics=data.draw(st.dictionaries(st.text(max_size=5), json_values, max_size=3)),
    )
    path = tmp_path / "e.mcap"
    write_drive(path, every_channel_drive(20), estimates=[est])
    (back,) = read_estimates(path)
    assert_estimates_equal(est, back)


def assert_reader_fails_cleanly(path):
    try:
        read_mcap(path)
    except GraphposError as exc:
        assert str(path) in str(exc)
        assert "\n" not in str(exc)


@SETTINGS
@given(data=st.binary(max_size=2000), magic=st.booleans())
def test_arbitrary_bytes_never_crash_the_reader(tmp_path, data, magic):
    path = tmp_path / "x.mcap"
    path.write_bytes((b"\x89MCAP0\r\n" if magic else b"") + data)
    assert_reader_fails_cleanly(path)


@pytest.fixture(scope="module")
def valid_file_bytes(tmp_path_factory) -> bytes:
    path = tmp_path_factory.mktemp("valid") / "v.mcap"
    drive = every_channel_drive(60)
    write_drive(path, drive, estimates=[Estimate("e", drive.truth.t_s, drive.truth.east_m, drive.truth.north_m)])
    return path.read_bytes()


@SETTINGS
@given(edits=st.lists(st.tuples(st.floats(0, 1, exclude_max=True), st.sampled_from(["flip", "cut", "insert", "delete"]), st.binary(min_size=1, max_size=8)),
                      min_size=1, max_size=4))
def test_damaged_files_never_crash_the_reader(tmp_path, valid_file_bytes, edits):
    data = bytearray(valid_file_bytes)
    for where, how, junk in edits:
        i = int(where * len(data)) if data else 0
        if how == "flip" and data:
            data[i] ^= junk[0] or 1
        elif how == "cut":
            del data[i:]
        elif how == "insert":
            data[i:i] = junk
        else:
            del data[i : i + len(junk)]
    path = tmp_path / "x.mcap"
    path.write_bytes(bytes(data))
    assert_reader_fails_cleanly(path)
