"""The writer encodes a column's floats with msgspec in one call
(:func:`graphpos.io.mcap_drive.float_texts`) and fills whole channels of
messages from templates; every message is byte for byte what it wrote with
Python's repr per value (the reference encoders here): random bit patterns,
subnormals, -0.0, both sides of each place where msgspec's layout of a float
leaves repr's (1e-9, 1e-4, 1e16), NaN as null, +-inf as +-1e999, integer
ids beyond 2**53. The ROS 2 bag's messages, encoded as one array, are byte
for byte rosbags' serialization of each."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from drive_samples import every_channel_drive
from test_mcap_fast_decode import AWKWARD, assert_same_columns, assert_same_estimates, random_floats

from graphpos.colors import rgb_of
from graphpos.drive import CHANNEL_SPECS, GeoOrigin
from graphpos.estimate import Estimate
from graphpos.io import read_drive, read_estimates, write_drive
from graphpos.io.geo import enu_to_geodetic
from graphpos.io.mcap_container import read_mcap_contents
from graphpos.io.mcap_drive import (_ESTIMATE_FIELDS, VIEW_RATE_HZ, _encode_columns, _estimate_payloads, _location_fixes,
                                    _poses, _thin, _time_ns, float_texts)
from graphpos.io.ros2_bag import _messages

BOUNDARIES = [v for edge in (1e-9, 1e-5, 1e-4, 1e16) for v in (np.nextafter(edge, 0.0), edge, np.nextafter(edge, np.inf))]
ADVERSARIAL = np.concatenate([
    AWKWARD, BOUNDARIES, np.negative(BOUNDARIES), [1e-7, -1e-7, 1.5e-5, 0.00012, 9999999999999998.0, 1e17, 2.0**63],
    [np.nan, np.inf, -np.inf, -np.nan],
    random_floats(3000, seed=11),
    np.random.default_rng(12).uniform(-10, 10, 600) * 10.0 ** np.random.default_rng(13).integers(-12, 18, 600),
])
WHOLE_IDS = np.array([0.0, 1.0, -1.0, 2.0**53, 2.0**53 + 2, -(2.0**53) - 2, 2.0**62, 2.0**63 - 1024, -(2.0**63), 12345678901.0])


# ---------------------------------------------------------------------------
# The writer before msgspec: repr per value
# ---------------------------------------------------------------------------


def old_text(x: float) -> str:
    return "null" if math.isnan(x) else ("1e999" if x > 0 else "-1e999") if math.isinf(x) else repr(float(x))


def old_column(values: np.ndarray, integer: bool = False) -> list[str]:
    """An integer column as JSON integers when every value is whole within int64, else as floats."""
    values = np.asarray(values, dtype=np.float64)
    whole = integer and all(math.isfinite(v) and v == round(v) and abs(v) < 2.0**63 for v in values.tolist())
    return [str(int(v)) for v in values.tolist()] if whole else [old_text(v) for v in values.tolist()]


def old_object(fields: list[tuple[str, str]]) -> bytes:
    return ("{" + ",".join(f'"{name}":{value}' for name, value in fields) + "}").encode()


def old_channel(kind: str, columns: dict[str, np.ndarray]) -> list[bytes]:
    specs = CHANNEL_SPECS[kind]
    texts = [old_column(columns[s.name], s.integer) for s in specs]
    return [old_object(list(zip([s.name for s in specs], row))) for row in zip(*texts)]


def old_estimate(columns: list[np.ndarray | None]) -> list[bytes]:
    *vectors, cov = columns
    n = len(vectors[0])
    texts = [[old_text(v) for v in arr.tolist()] if arr is not None else ["null"] * n for arr in vectors]
    cov_texts = ["null"] * n if cov is None else ["[" + ",".join(map(old_text, c.ravel().tolist())) + "]" for c in np.asarray(cov)]
    return [old_object(list(zip(_ESTIMATE_FIELDS, row))) for row in zip(*texts, cov_texts)]


def old_stamp(ns: int) -> str:
    return f'{{"sec":{ns // 1_000_000_000},"nsec":{ns % 1_000_000_000}}}'


def old_poses(t_ns: np.ndarray, east_m, north_m, yaw_rad) -> list[bytes]:
    yaw = np.zeros(t_ns.size) if yaw_rad is None else np.nan_to_num(np.asarray(yaw_rad, dtype=np.float64))
    return [old_object([("timestamp", old_stamp(ns)), ("frame_id", '"enu"'), (
        "pose", f'{{"position":{{"x":{old_text(x)},"y":{old_text(y)},"z":0.0}},'
                f'"orientation":{{"x":0.0,"y":0.0,"z":{old_text(z)},"w":{old_text(w)}}}}}')])
        for ns, x, y, z, w in zip(t_ns.tolist(), np.asarray(east_m).tolist(), np.asarray(north_m).tolist(),
                                  np.sin(yaw / 2).tolist(), np.cos(yaw / 2).tolist())]


def old_fixes(t_ns: np.ndarray, east_m, north_m, var_m2, origin: GeoOrigin, colored_as: str | None) -> list[bytes]:
    lat, lon = enu_to_geodetic(east_m, north_m, origin)
    color = None if colored_as is None else json.dumps(dict(zip("rgba", (*rgb_of(colored_as), 1.0))))
    out = []
    for k, ns in enumerate(t_ns.tolist()):
        cov = ("[0,0,0,0,0,0,0,0,0]", "0") if var_m2 is None else (
            f"[{old_text(var_m2[0][k])},0,0,0,{old_text(var_m2[1][k])},0,0,0,0]", "2")
        fields = [("timestamp", old_stamp(ns)), ("frame_id", '"enu"'), ("latitude", old_text(lat[k])), ("longitude", old_text(lon[k])),
                  ("altitude", repr(float(origin.alt_m))), ("position_covariance", cov[0]), ("position_covariance_type", cov[1])]
        out.append(old_object(fields + ([("color", color)] if color else [])))
    return out


# ---------------------------------------------------------------------------
# Tests
# ---------------------------------------------------------------------------


def test_float_texts_are_repr_per_value_and_read_back_bit_exact():
    texts = float_texts(ADVERSARIAL)
    assert texts == [old_text(v).encode() for v in ADVERSARIAL.tolist()]
    finite = np.isfinite(ADVERSARIAL)
    back = np.array([float(t) for t, ok in zip(texts, finite) if ok])
    assert (back.view(np.uint64) == ADVERSARIAL[finite].view(np.uint64)).all()
    assert float_texts(ADVERSARIAL, nan=b"", inf=b"I", minus_inf=b"-I") == [
        b"" if math.isnan(v) else b"I" if v == math.inf else b"-I" if v == -math.inf else repr(v).encode() for v in ADVERSARIAL.tolist()]
    assert float_texts(np.zeros(0)) == [] and float_texts(np.full(3, np.nan)) == [b"null"] * 3


@pytest.mark.parametrize("kind", list(CHANNEL_SPECS))
@pytest.mark.parametrize("n", [0, 1, 977])
def test_channel_messages_are_written_as_before(kind, n):
    rng = np.random.default_rng(n)
    columns = {s.name: np.resize(rng.permutation(WHOLE_IDS if s.integer else ADVERSARIAL), n) for s in CHANNEL_SPECS[kind]}
    assert _encode_columns(kind, columns) == old_channel(kind, columns)
    ids = [s.name for s in CHANNEL_SPECS[kind] if s.integer]
    if ids and n:  # an id that is not whole: the column is written as floats, as before
        columns[ids[0]] = columns[ids[0]].copy()
        columns[ids[0]][-1] = 2.5
        assert _encode_columns(kind, columns) == old_channel(kind, columns)


@pytest.mark.parametrize("n", [0, 1, 800])
@pytest.mark.parametrize("optional", [True, False])
def test_estimate_messages_are_written_as_before(n, optional):
    rng = np.random.default_rng(n)
    column = lambda: np.resize(rng.permutation(ADVERSARIAL), n)  # noqa: E731
    columns = [column(), column(), column()] + ([column() for _ in range(3)] + [column().repeat(4).reshape(n, 2, 2) * -1]
                                               if optional else [None] * 4)
    if optional and n:
        columns[4] = None  # one quantity not estimated among the others
    assert _estimate_payloads(columns) == old_estimate(columns)


@pytest.mark.parametrize("n", [0, 1, 500])
def test_view_messages_are_written_as_before(n):
    rng = np.random.default_rng(n)
    column = lambda: np.resize(rng.permutation(ADVERSARIAL), n)  # noqa: E731
    t_ns = _time_ns(np.sort(rng.uniform(-5, 2e10, n)), -10.0)
    east, north, yaw = column(), column(), column()
    assert _poses(t_ns, east, north, yaw) == old_poses(t_ns, east, north, yaw)
    assert _poses(t_ns, east, north, None) == old_poses(t_ns, east, north, None)
    origin = GeoOrigin(lat_deg=48.1, lon_deg=11.5, alt_m=1e-5)
    with np.errstate(all="ignore"):  # geodetic conversion of inf and 1e308 metres
        var = (column(), column())
        assert _location_fixes(t_ns, east, north, var, origin) == old_fixes(t_ns, east, north, var, origin, None)
        assert _location_fixes(t_ns, east, north, None, origin, "graph-batch") == old_fixes(t_ns, east, north, None, origin, "graph-batch")


def test_drive_file_is_written_as_before_and_reads_back_bit_exact(tmp_path):
    drive = every_channel_drive()
    n = 700
    rng = np.random.default_rng(5)
    column = lambda: np.resize(rng.permutation(ADVERSARIAL), n)  # noqa: E731
    t = np.sort(rng.uniform(0, 5, n))
    estimates = [Estimate("adversarial", t, column(), column(), column(), column(), column(),
                          cov_en_m2=column().repeat(4).reshape(n, 2, 2)),
                 Estimate("plain", t[:10], column()[:10], column()[:10])]
    path = tmp_path / "drive.mcap"
    with np.errstate(all="ignore"):
        write_drive(path, drive, estimates)
    contents = read_mcap_contents(path)
    payloads = {channel.topic: contents.payloads.get(cid, []) for cid, channel in contents.channels.items()}
    for kind, channel in drive.channels.items():
        assert payloads[f"/{kind}"] == old_channel(kind, channel.columns), kind
    for est in estimates:
        assert payloads[f"/estimates/{est.name}"] == old_estimate([getattr(est, name) for name in _ESTIMATE_FIELDS])
        keep = _thin(est.t_s, VIEW_RATE_HZ)
        yaw = None if est.yaw_rad is None else est.yaw_rad[keep]
        t_ns = _time_ns(est.t_s[keep], 0.0)
        assert payloads[f"/estimates/{est.name}/pose"] == old_poses(t_ns, est.east_m[keep], est.north_m[keep], yaw)
        var = None if est.cov_en_m2 is None else (est.cov_en_m2[keep, 0, 0], est.cov_en_m2[keep, 1, 1])
        with np.errstate(all="ignore"):
            want = old_fixes(t_ns, est.east_m[keep], est.north_m[keep], var, drive.origin, est.name)
        assert payloads[f"/estimates/{est.name}/fix"] == want
    keep = _thin(drive.truth.t_s, VIEW_RATE_HZ)
    t_ns, truth, gnss = _time_ns(drive.truth.t_s[keep], 0.0), drive.truth, drive.gnss
    assert payloads["/truth/pose"] == old_poses(t_ns, truth.east_m[keep], truth.north_m[keep], truth.yaw_rad[keep])
    assert payloads["/truth/fix"] == old_fixes(t_ns, truth.east_m[keep], truth.north_m[keep], None, drive.origin, "truth")
    assert payloads["/gnss/fix"] == old_fixes(_time_ns(gnss.t_s, 0.0), gnss.east_m, gnss.north_m, (gnss.sigma_m**2, gnss.sigma_m**2),
                                              drive.origin, None)
    back = read_drive(path)
    for kind, channel in drive.channels.items():
        assert_same_columns(channel.columns, back.channels[kind].columns)
    assert_same_estimates(estimates, read_estimates(path))


def rosbags_messages(est: Estimate) -> list[bytes]:
    """The CDR of each output epoch as rosbags' serializer gives it (the ROS 2 bag's messages before one array)."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    T = store.types
    vector, n = T["geometry_msgs/msg/Vector3"], len(est)
    yaw = np.zeros(n) if est.yaw_rad is None else np.nan_to_num(est.yaw_rad)
    nan = np.full(n, np.nan)
    forward = est.v_east_mps * np.cos(yaw) + est.v_north_mps * np.sin(yaw) if est.has_velocity else nan
    left = -est.v_east_mps * np.sin(yaw) + est.v_north_mps * np.cos(yaw) if est.has_velocity else nan
    out = []
    for k in range(n):
        whole = math.floor(est.t_s[k])
        nanos = int(np.round((est.t_s[k] - whole) * 1e9))
        covariance = np.zeros((6, 6))
        if est.cov_en_m2 is not None:
            covariance[:2, :2] = est.cov_en_m2[k]
        msg = T["nav_msgs/msg/Odometry"](
            header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=whole + nanos // 10**9, nanosec=nanos % 10**9),
                                            frame_id="map"),
            child_frame_id="base_link",
            pose=T["geometry_msgs/msg/PoseWithCovariance"](
                pose=T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=est.east_m[k], y=est.north_m[k], z=0.0),
                                                 orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=np.sin(yaw[k] / 2),
                                                                                               w=np.cos(yaw[k] / 2))),
                covariance=covariance.ravel()),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](
                twist=T["geometry_msgs/msg/Twist"](linear=vector(x=forward[k], y=left[k], z=0.0), angular=vector(x=np.nan, y=np.nan, z=np.nan)),
                covariance=np.zeros(36)),
        )
        out.append(bytes(store.serialize_cdr(msg, "nav_msgs/msg/Odometry")))
    return out


@pytest.mark.parametrize("n", [0, 1, 300])
@pytest.mark.parametrize("optional", [True, False])
def test_ros2_bag_messages_are_rosbags_cdr(monkeypatch, n, optional):
    monkeypatch.setattr("graphpos.io.ros2_bag._BATCH_MESSAGES", 128)
    rng = np.random.default_rng(n)
    column = lambda: np.resize(rng.permutation(ADVERSARIAL), n)  # noqa: E731
    t = np.sort(rng.uniform(-2e9, 2e9, n))
    t[: n // 2] = np.round(t[: n // 2], 9)  # whole nanoseconds, and times that round up to the next second
    if n > 2:
        t[1] = 12.9999999999
    with np.errstate(all="ignore"):  # the velocity turned by yaw of inf and 1e308
        est = (Estimate("x", t, column(), column(), column(), column(), column(), cov_en_m2=column().repeat(4).reshape(n, 2, 2))
               if optional else Estimate("x", t, column(), column()))
        record_ns, data = zip(*_messages(est)) if n else ([], [])
        want = rosbags_messages(est)
    assert list(data) == want
    assert list(record_ns) == [max(int(np.frombuffer(m[4:8], "<i4")[0]) * 10**9 + int(np.frombuffer(m[8:12], "<u4")[0]), 0) for m in want]
