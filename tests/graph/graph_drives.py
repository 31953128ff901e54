"""Small synthetic drives for the graph tests (independent of graphpos.sim)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from graphpos.drive import Channel, Drive, TagMap
from graphpos.ranging.model import LinearCalibration

PLAZA = Path(__file__).resolve().parents[2] / "../shared/data/plaza/Plaza1.mat"
MRCLAM6 = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "mrclam" / "MRCLAM_Dataset6"


def mrclam_drive(robot: int) -> Drive:
    """MRCLAM6 robot ``robot``'s drive (with its truth), or the test skipped when the data are absent."""
    import pytest

    from graphpos.io.mrclam import import_mrclam

    if not MRCLAM6.exists():
        pytest.skip(f"MRCLAM Dataset 6 not found at {MRCLAM6}")
    return import_mrclam(MRCLAM6, robot)

RANGE_SIGMA_M = 0.3
#: The synthetic drive's wheel and gyro have no scale error and its range
#: errors are independent (no per-tag shadowing): graph configs that say so.
#: (With the default turn-rate scale density, 0.02/sqrt(s), graph-batch's
#: ANEES over 25 planar drives was 1.72, under the 95 % band [1.76, 2.26].)
SYNTHETIC_MODEL = {"wheel_scale_density_per_sqrt_s": 1e-3, "turn_scale_density_per_sqrt_s": 1e-3, "range_sigma_scale": 1.0}


def synthetic_drive(
    duration_s: float = 40.0,
    seed: int = 0,
    noise: bool = True,
    speed_mps: float = 5.0,
    turn_radps: float = 0.0,
    tag_spacing_m: float = 6.0,
    tag_gap: tuple[float, float] | None = None,
    max_range_m: float = 9.0,
    rfid_latency_s: tuple[float, float] | None = None,
    accelerometers: bool = True,
    stop: tuple[float, float] | None = None,
    range_scale: float = 1.0,
    walls: tuple[int, ...] = (+1, -1),
    beacons: list[tuple[float, float, int]] | None = None,
    compass: bool = True,
    absolute_from_s: float | None = None,
    turn_after_s: float | None = None,
) -> Drive:
    """A vehicle at ``speed_mps`` (turning at ``turn_radps`` after 1/3 of the drive) past wall tags.

    Tags sit on both walls (north = +/-3 m) every ``tag_spacing_m`` along the
    east axis, and also along the curve's walls; ``tag_gap`` (east interval)
    leaves a stretch without tags. ``stop`` = (start_s, end_s) holds the
    vehicle still. IMU/wheel at 100 Hz, compass 10 Hz, RFID 1 Hz.

    Start-up options: ``walls`` picks the walls that carry tags (+1 left,
    -1 right, of the initial direction); ``beacons`` replaces the wall tags
    by explicit ``(east_m, north_m, wall_side)`` tags; ``compass=False``
    drops the compass; ``absolute_from_s`` drops every range and compass
    reading before that time (odometry only until then); ``turn_after_s``
    moves the start of the turn (default: a third of the drive).
    """
    rng = np.random.default_rng(seed)
    dt = 0.01
    t = np.arange(0.0, duration_s + 1e-9, dt)
    v = np.full_like(t, speed_mps)
    # gentle start: accelerate over the first 2 s from 0.5 speed
    v *= np.clip(0.5 + 0.25 * t, 0.5, 1.0)
    if stop is not None:
        ramp = np.interp(t, [stop[0] - 2, stop[0], stop[1], stop[1] + 2], [1, 0, 0, 1])
        v *= ramp
    w = np.where(t > (duration_s / 3 if turn_after_s is None else turn_after_s), turn_radps, 0.0)
    yaw = np.concatenate(([0.0], np.cumsum(w[:-1] * dt)))
    e = np.concatenate(([0.0], np.cumsum(v[:-1] * np.cos(yaw[:-1]) * dt)))
    n = np.concatenate(([0.0], np.cumsum(v[:-1] * np.sin(yaw[:-1]) * dt)))
    ax = np.gradient(v, dt)
    ay = v * w
    # tags along the travelled path, both sides, every tag_spacing_m of arc
    s = np.concatenate(([0.0], np.cumsum(v[:-1] * dt)))
    marks = np.arange(0.0, s[-1] + 10, tag_spacing_m)
    idx = np.clip(np.searchsorted(s, marks), 0, t.size - 1)
    te, tn, side = [], [], []
    for i in idx if beacons is None else ():
        if tag_gap is not None and tag_gap[0] <= e[i] <= tag_gap[1]:
            continue
        for sd in (+1, -1):
            if sd not in walls:
                continue
            te.append(e[i] - sd * 3.0 * np.sin(yaw[i]))
            tn.append(n[i] + sd * 3.0 * np.cos(yaw[i]))
            side.append(sd)
    for be, bn, bs in beacons or ():
        te.append(float(be))
        tn.append(float(bn))
        side.append(int(bs))
    ids = np.arange(len(te))
    tags = TagMap(ids, np.array(te), np.array(tn), np.array(side), np.full(len(te), -1))

    def noisy(x, sigma):
        return x + rng.normal(0, sigma, x.shape) if noise else x

    imu_cols = {"t_s": t, "yaw_rate_radps": noisy(w, np.radians(0.2))}
    if accelerometers:
        imu_cols.update(accel_x_mps2=noisy(ax, 0.1), accel_y_mps2=noisy(ay, 0.1))
    tc = t[::10]
    rt, rid, rr, rtrue = [], [], [], []
    for i in range(0, t.size, 100):
        d = np.hypot(np.array(te) - e[i], np.array(tn) - n[i])
        for j in np.nonzero(d <= max_range_m)[0]:
            rt.append(t[i])
            rid.append(j)
            rtrue.append(d[j])
            rr.append(max(range_scale * d[j] + (rng.normal(0, RANGE_SIGMA_M) if noise else 0.0), 0.0))
    rt = np.array(rt)
    if absolute_from_s is not None:
        late_enough = rt >= absolute_from_s
        rt, rid, rr, rtrue = rt[late_enough], list(np.array(rid, dtype=np.int64)[late_enough]), list(np.array(rr)[late_enough]), list(np.array(rtrue)[late_enough])
    arrival = rt.copy()
    if rfid_latency_s is not None:
        arrival = rt + np.random.default_rng([seed, 1]).uniform(*rfid_latency_s, rt.size)  # own stream: same sensor noise
        order = np.argsort(rt, kind="stable")
        rt, arrival = rt[order], arrival[order]
    wheel_speed = noisy(v, 0.1)
    compass_yaw = noisy(yaw[::10], np.radians(2.0))
    compass_yaw = np.where(np.abs(compass_yaw) > np.pi, np.angle(np.exp(1j * compass_yaw)), compass_yaw)  # a compass reads wrapped angles
    heading_seen = tc >= (absolute_from_s if absolute_from_s is not None else -np.inf)
    channels = {
        "imu": Channel("imu", imu_cols),
        "wheel": Channel("wheel", {"t_s": t, "speed_mps": wheel_speed}),
        "compass": Channel("compass", {"t_s": tc[heading_seen], "yaw_rad": compass_yaw[heading_seen]}),
        "rfid": Channel("rfid", {"t_s": rt, "tag_id": np.array(rid, dtype=np.int64), "range_m": np.array(rr), "true_range_m": np.array(rtrue), "arrival_s": arrival}),
        "truth": Channel(
            "truth",
            {"t_s": t, "east_m": e, "north_m": n, "v_east_mps": v * np.cos(yaw), "v_north_mps": v * np.sin(yaw), "yaw_rad": yaw},
        ),
    }
    if not compass:
        del channels["compass"]
    return Drive(f"synthetic-{seed}", channels, tags=tags)


def range_model() -> LinearCalibration:
    return LinearCalibration(sigma0_m=RANGE_SIGMA_M)


def truth_at(drive: Drive, t_s: np.ndarray) -> np.ndarray:
    tr = drive.truth
    return np.column_stack([np.interp(t_s, tr.t_s, tr.east_m), np.interp(t_s, tr.t_s, tr.north_m)])


def position_errors(drive: Drive, est) -> np.ndarray:
    return np.linalg.norm(est.position - truth_at(drive, est.t_s), axis=1)


def errors(drive: Drive, est) -> np.ndarray:
    """Position errors of the outputs within the truth's time span (late readings can outlast it)."""
    within = est.t_s <= drive.truth.t_s[-1]
    return np.linalg.norm(est.position[within] - truth_at(drive, est.t_s[within]), axis=1)


def rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e**2)))


def run(key: str, drive: Drive, initial_pose=None, model=None, spoil=None, **config):
    """Run an estimator on the drive as it sees it (``drive.without_truth()``).

    ``key``: ``graph-name/parameterisation`` (the synthetic drive's graph
    config, with ``config`` on top) or a filter's name; ``model``: the range
    model (default: the synthetic drive's; ``"drive"``: the drive's own default).
    ``spoil``: feed the measurements one by one (the online loop), each
    through ``spoil(index, measurement) -> measurement`` (values a drive
    would refuse, as a live feed may bring them).
    """
    from filters import ESTIMATORS as FILTERS
    from graphpos.graph import ESTIMATORS as GRAPHS
    from graphpos.graph.config import GraphConfig

    model = range_model() if model is None else (None if model == "drive" else model)
    name, _, parameterisation = key.partition("/")
    if parameterisation:
        est = GRAPHS[name](GraphConfig(**{**SYNTHETIC_MODEL, "parameterisation": parameterisation, **config}), range_model=model, initial_pose=initial_pose)
    else:
        est = FILTERS[name](range_model=model, initial_pose=initial_pose)
    if spoil is None:
        return est.run(drive.without_truth())
    seen = est.prepare(drive.without_truth())
    est.start(seen)
    for i, m in enumerate(seen.measurements(est.channels_used(seen), by=est.merge_by)):
        est.process(spoil(i, m))
    return est.finish()


# -- awkward but valid drives (issue 14) -----------------------------------------------------------------------
#: Every sensor channel (the truth is not a sensor).
SENSORS = ("imu", "wheel", "compass", "rfid", "rsu", "gnss")


def paused(drive: Drive, at_s: float, pause_s: float) -> Drive:
    """Every channel, the truth included, from ``at_s`` on shifted ``pause_s`` later: a recording paused
    while the vehicle stood (its motion stops and resumes with no odometry of it)."""
    channels = {}
    for name, ch in drive.channels.items():
        cols = dict(ch.columns)
        later = cols["t_s"] >= at_s
        for c in ("t_s", "arrival_s"):
            if c in cols:
                cols[c] = np.where(later, cols[c] + pause_s, cols[c])
        channels[name] = Channel(name, cols)
    return drive.replace(channels=channels)


def without_span(drive: Drive, from_s: float, to_s: float, channels: tuple[str, ...] = SENSORS) -> Drive:
    """The rows of ``channels`` taken in ``[from_s, to_s)`` lost: the vehicle drives on unobserved by them."""
    return drive.replace(channels={n: ch.select(~((ch.t_s >= from_s) & (ch.t_s < to_s))) if n in channels else ch
                                   for n, ch in drive.channels.items()})


def late_rfid(drive: Drive, delay_s: float, fraction: float, seed: int = 0) -> tuple[Drive, np.ndarray]:
    """A random ``fraction`` of the RFID readings arriving ``delay_s`` after they were taken; the drive and the late rows."""
    rfid = drive.rfid
    late = np.random.default_rng(seed).random(len(rfid)) < fraction
    return drive.replace(channels={**drive.channels, "rfid": rfid.replace(arrival_s=np.where(late, rfid.t_s + delay_s, rfid.arrival_s))}), late


def with_nan(drive: Drive, channel: str, column: str, rows) -> Drive:
    """The drive with NaN in ``rows`` of one (optional) column."""
    ch = drive.channels[channel]
    values = np.array(ch[column])
    values[np.asarray(rows, dtype=np.int64)] = np.nan
    return drive.replace(channels={**drive.channels, channel: ch.replace(**{column: values})})


def mixed_readings(drive: Drive, rss_only: np.ndarray, seed: int = 0) -> Drive:
    """The RFID readings of rows ``rss_only`` with an RSS (the simulated tunnel's law) and no range; the others a range only."""
    from graphpos.sim.rss import ENVIRONMENTS

    rfid = drive.rfid
    rss = ENVIRONMENTS["tunnel"].sample_rss(rfid.true_range_m, np.random.default_rng(seed))
    return drive.replace(channels={**drive.channels, "rfid": rfid.replace(rss=np.where(rss_only, rss, np.nan),
                                                                             range_m=np.where(rss_only, np.nan, rfid.range_m))})
