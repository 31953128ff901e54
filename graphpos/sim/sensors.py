"""Sensor models: each turns the truth trajectory into one channel's columns.

Every model draws from its own random stream (:func:`stream`), so a change
to one sensor's parameters leaves the others' samples unchanged. Times are
``k / rate_hz`` from the drive's start, up to its duration.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.signal import lfilter
from scipy.spatial import cKDTree

from graphpos.drive import RsuMap, TagMap
from graphpos.sim.route import Route
from graphpos.sim.rss import RssEnvironment
from graphpos.sim.trajectory import Trajectory

#: Random-stream numbers (never reorder: drives must stay reproducible; new
#: components append a new number). ``profile`` holds the per-drive error
#: terms of a sensor profile (:func:`profile_errors`), ``rfid_range`` the
#: noise and outliers of reported RFID ranges, ``gnss_approach`` the DGPS fixes
#: on a paper scenario's approach, ``profile_terms`` the per-drive terms added
#: for the ``paper`` profile (:func:`road_test_errors`), ``rfid_road`` the
#: per-tag and per-reading road-test terms of the RSS radio
#: (:func:`rfid_road_test`).
_STREAMS = {"imu": 1, "wheel": 2, "compass": 3, "rfid": 4, "gnss": 5, "rsu": 6, "latency": 7, "faults": 8,
            "profile": 9, "rfid_range": 10, "gnss_approach": 11, "profile_terms": 12, "rfid_road": 13}


def stream(seed: int, name: str) -> np.random.Generator:
    """The random generator of one component of a seeded drive."""
    return np.random.default_rng([seed, _STREAMS[name]])


def sample_times(duration_s: float, rate_hz: float) -> np.ndarray:
    """``k / rate_hz`` for every k with ``k / rate_hz <= duration_s``."""
    n = int(np.floor(duration_s * rate_hz + 1e-9)) + 1
    return np.arange(n) / rate_hz


def gauss_markov(n: int, dt_s: float, sigma: float, tau_s: float, rng: np.random.Generator) -> np.ndarray:
    """First-order Gauss-Markov process started from its stationary law.

    ``x[k] = phi x[k-1] + w[k]``, ``phi = exp(-dt/tau)``, ``w ~ N(0, sigma^2 (1 - phi^2))``,
    so ``x`` has standard deviation ``sigma`` at every step.
    """
    phi = np.exp(-dt_s / tau_s)
    x0 = rng.standard_normal() * sigma
    w = rng.standard_normal(n) * sigma * np.sqrt(1.0 - phi**2)
    out, _ = lfilter([1.0], [1.0, -phi], w, zi=[phi * x0])
    return out


def profile_errors(params: dict[str, Any], rng: np.random.Generator) -> dict[str, float]:
    """The per-drive error terms of a sensor profile, drawn once per drive.

    Four unit variates are drawn in a fixed order whatever the bounds (so
    changing one bound changes only its own term) and scaled to the bounds
    of :mod:`graphpos.sim.params`; with the ideal profile's zero bounds every
    term is 0 (the range scale 1).

    Parameters
    ----------
    params : dict
        The drive's parameters (``imu``, ``wheel`` and, where present,
        ``rfid``).
    rng : numpy Generator
        The ``profile`` stream.

    Returns
    -------
    dict
        ``gyro_turn_on_bias_dps`` (uniform in +-``imu.gyro_turn_on_bias_max_dps``),
        ``yaw_rate_scale_error`` (uniform in +-``imu.yaw_rate_scale_error_max``),
        ``wheel_profile_scale_error`` (uniform in +-``wheel.scale_error_max``,
        or, with ``wheel.scale_error_min`` > 0, of size uniform in
        [``scale_error_min``, ``scale_error_max``] and the variate's sign),
        ``range_scale`` (uniform in [``rfid.range_scale_min``, ``rfid.range_scale_max``]).
    """
    u_bias, u_yaw, u_wheel, u_range = rng.uniform(-1.0, 1.0, 4)
    imu_p, wheel_p = params["imu"], params["wheel"]
    out = {
        "gyro_turn_on_bias_dps": float(u_bias * imu_p["gyro_turn_on_bias_max_dps"]) + 0.0,
        "yaw_rate_scale_error": float(u_yaw * imu_p["yaw_rate_scale_error_max"]) + 0.0,
        "wheel_profile_scale_error": _banded(u_wheel, wheel_p.get("scale_error_min", 0.0), wheel_p["scale_error_max"]),
        "range_scale": 1.0,
    }
    if "rfid" in params:
        lo, hi = params["rfid"]["range_scale_min"], params["rfid"]["range_scale_max"]
        out["range_scale"] = float(lo + 0.5 * (u_range + 1.0) * (hi - lo)) if hi > lo else float(lo)
    return out


def _banded(u: float, lo: float, hi: float) -> float:
    """A unit variate u in [-1, 1] as a term of size in [lo, hi] and u's sign
    (``u * hi`` exactly when lo is 0)."""
    if lo == 0.0:
        return float(u * hi) + 0.0
    return float(np.sign(u) * (lo + abs(u) * (hi - lo))) + 0.0


def road_test_errors(params: dict[str, Any], rng: np.random.Generator) -> dict[str, float]:
    """The per-drive terms the ``paper`` profile adds, drawn once per drive.

    Four unit variates, uniform in [-1, 1], are drawn in a fixed order from
    the ``profile_terms`` stream whatever the bounds (so ``ideal`` and
    ``realistic`` drives, whose terms are all 0, keep every sample).

    Returns
    -------
    dict
        ``compass_bias_deg`` (size uniform in [``compass.bias_min_deg``,
        ``compass.bias_max_deg``], random sign), ``accel_turn_on_bias_x_mps2``
        and ``accel_turn_on_bias_y_mps2`` (each uniform in
        +-``imu.accel_turn_on_bias_max_mps2``), ``reader_gain_db`` (uniform
        in [``rfid.reader_gain_min_db``, ``rfid.reader_gain_max_db``]; 0
        without RFID).
    """
    u_compass, u_ax, u_ay, u_gain = rng.uniform(-1.0, 1.0, 4)
    c, a = params["compass"], params["imu"]["accel_turn_on_bias_max_mps2"]
    out = {
        "compass_bias_deg": _banded(u_compass, c["bias_min_deg"], c["bias_max_deg"]),
        "accel_turn_on_bias_x_mps2": float(u_ax * a) + 0.0,
        "accel_turn_on_bias_y_mps2": float(u_ay * a) + 0.0,
        "reader_gain_db": 0.0,
    }
    if "rfid" in params:
        lo, hi = params["rfid"]["reader_gain_min_db"], params["rfid"]["reader_gain_max_db"]
        out["reader_gain_db"] = float(lo + 0.5 * (u_gain + 1.0) * (hi - lo)) + 0.0
    return out


def imu(traj: Trajectory, duration_s: float, p: dict[str, Any], rng: np.random.Generator,
        turn_on_bias_dps: float = 0.0, yaw_rate_scale_error: float = 0.0,
        accel_turn_on_bias_mps2: tuple[float, float] = (0.0, 0.0)) -> dict[str, np.ndarray]:
    """Two accelerometers (body x, y) and a yaw gyro: truth + bias + white noise.

    The gyro reads ``(1 + yaw_rate_scale_error) * truth + gauss_markov_bias +
    turn_on_bias + noise``; the last two arguments are the sensor profile's
    per-drive terms (:func:`profile_errors`; 0 leaves the samples those of
    the ideal profile bit for bit). Each accelerometer adds its constant
    turn-on bias of ``accel_turn_on_bias_mps2`` (x, y; the ``paper``
    profile's terms, :func:`road_test_errors`).
    """
    t = sample_times(duration_s, p["rate_hz"])
    st = traj.state(t)
    dt = 1.0 / p["rate_hz"]
    n = t.size
    cols = {"t_s": t}
    for axis, turn_on in zip(("x", "y"), accel_turn_on_bias_mps2):
        bias = gauss_markov(n, dt, p["accel_bias_sigma_mps2"], p["accel_bias_tau_s"], rng)
        if turn_on != 0.0:
            bias = bias + turn_on
        cols[f"accel_{axis}_mps2"] = st[f"accel_{axis}_mps2"] + bias + rng.standard_normal(n) * p["accel_sigma_mps2"]
    bias = gauss_markov(n, dt, np.deg2rad(p["gyro_bias_sigma_dps"]), p["gyro_bias_tau_s"], rng)
    rate = st["yaw_rate_radps"] if yaw_rate_scale_error == 0.0 else st["yaw_rate_radps"] * (1.0 + yaw_rate_scale_error)
    if turn_on_bias_dps != 0.0:
        bias = bias + np.deg2rad(turn_on_bias_dps)
    cols["yaw_rate_radps"] = rate + bias + rng.standard_normal(n) * np.deg2rad(p["gyro_sigma_dps"])
    return cols


def wheel(traj: Trajectory, duration_s: float, p: dict[str, Any], rng: np.random.Generator,
          profile_scale_error: float = 0.0) -> tuple[dict[str, np.ndarray], float]:
    """Wheel-encoder speed: truth times (1 + scale error) + white noise.

    The scale error is the Gaussian draw (``scale_error_sigma``, from this
    sensor's stream) combined with the sensor profile's per-drive term
    ``profile_scale_error`` (:func:`profile_errors`):
    ``1 + scale = (1 + gaussian) (1 + profile_scale_error)``.

    Returns the columns and the total scale error.
    """
    t = sample_times(duration_s, p["rate_hz"])
    gaussian = float(rng.standard_normal() * p["scale_error_sigma"])
    # gaussian + u + gaussian u is exactly the Gaussian draw when u is 0 (ideal profile)
    scale = gaussian + profile_scale_error + gaussian * profile_scale_error
    speed = traj.state(t)["speed_mps"] * (1.0 + scale) + rng.standard_normal(t.size) * p["sigma_mps"]
    return {"t_s": t, "speed_mps": speed}, scale


def lagged(yaw_rad: np.ndarray, dt_s: float, tau_s: float) -> np.ndarray:
    """A heading seen through a first-order lag of time constant ``tau_s``
    (the damping of a vehicle compass), started settled on the first sample.
    The heading is unwrapped first, so the lag never crosses +-pi the long way."""
    y = np.unwrap(yaw_rad)
    a = 1.0 - np.exp(-dt_s / tau_s)
    out, _ = lfilter([a], [1.0, a - 1.0], y, zi=[(1.0 - a) * y[0]])
    return out


def compass(traj: Trajectory, route: Route, duration_s: float, p: dict[str, Any], rng: np.random.Generator,
            bias_deg: float = 0.0) -> dict[str, np.ndarray]:
    """Heading (yaw from east, wrapped to [-pi, pi)) with white noise,
    local disturbances fixed along the road (Gaussian bumps, none in
    turnarounds) and a constant per-drive bias ``bias_deg`` (the ``paper``
    profile's term, :func:`road_test_errors`; 0 leaves the samples as they were).
    With ``lag_s`` > 0 the heading is the truth through a first-order lag
    (:func:`lagged`; a damped compass reads late in turns)."""
    t = sample_times(duration_s, p["rate_hz"])
    st = traj.state(t)
    n_bumps = rng.poisson(p["disturbances_per_km"] * route.length_m / 1000.0)
    centres = rng.uniform(0.0, route.length_m, n_bumps)
    amps = np.deg2rad(rng.standard_normal(n_bumps) * p["disturbance_sigma_deg"])
    width = max(p["disturbance_width_m"], 1e-6)
    disturbance = np.zeros(t.size)
    for c, a in zip(centres, amps):
        disturbance += a * np.exp(-0.5 * ((st["route_s"] - c) / width) ** 2)
    disturbance[st["turnaround"]] = 0.0
    true_yaw = st["yaw_rad"]
    if p.get("lag_s", 0.0) > 0.0:
        true_yaw = lagged(true_yaw, 1.0 / p["rate_hz"], p["lag_s"])
    yaw = true_yaw + disturbance + rng.standard_normal(t.size) * np.deg2rad(p["sigma_deg"])
    if bias_deg != 0.0:
        yaw = yaw + np.deg2rad(bias_deg)
    return {"t_s": t, "yaw_rad": (yaw + np.pi) % (2 * np.pi) - np.pi}


def rfid(traj: Trajectory, tags: TagMap, env: RssEnvironment, duration_s: float, p: dict[str, Any],
         rng: np.random.Generator) -> dict[str, np.ndarray]:
    """One row per heard tag per read: RSS (0-255) from the RSS law, true range.

    Detection probability is ``1 - read_failure_probability`` within the
    environment's reliable range and falls linearly to zero at its maximum
    range. A reader of shorter range (``p["reader_range_m"]``) does not hear
    the farther tags: their rows are dropped after every draw, so the rows
    left are those of the full range, bit for bit. The radio reports RSS
    only, so ``range_m`` is NaN (a ranging radio adds it: :func:`rfid_ranges`).

    A read stamped ``t`` was taken ``p["stamp_delay_s"]`` earlier (a reader
    that reports each inventory round when it ends: the RSS and
    ``true_range_m`` are those of the earlier position); stamps before the
    delay has passed give no read.
    """
    delay_s = p["stamp_delay_s"]
    t = sample_times(duration_s, p["rate_hz"])
    t = t[t >= delay_s]
    empty = {"t_s": np.zeros(0), "tag_id": np.zeros(0), "rss": np.zeros(0), "true_range_m": np.zeros(0)}
    if len(tags) == 0:
        return empty
    offsets_db = env.draw_tag_offsets_db(len(tags), rng)
    st = traj.state(t - delay_s)
    reader = np.column_stack([st["east_m"], st["north_m"]])
    tree = cKDTree(np.column_stack([tags.east_m, tags.north_m]))
    hits = tree.query_ball_point(reader, r=env.max_range_m)
    counts = np.array([len(h) for h in hits])
    if counts.sum() == 0:
        return empty
    read = np.repeat(np.arange(t.size), counts)
    tag_idx = np.concatenate([np.sort(np.asarray(h, dtype=np.int64)) for h in hits if h])
    dist = np.hypot(reader[read, 0] - tags.east_m[tag_idx], reader[read, 1] - tags.north_m[tag_idx])
    fade = np.clip((env.max_range_m - dist) / (env.max_range_m - env.reliable_range_m), 0.0, 1.0)
    heard = rng.random(dist.size) < (1.0 - p["read_failure_probability"]) * fade
    read, tag_idx, dist = read[heard], tag_idx[heard], dist[heard]
    rss = env.sample_rss(dist, rng, offsets_db[tag_idx])
    wild = rng.random(dist.size) < p["outlier_probability"]
    rss[wild] = np.clip(np.round(rss[wild] + env.units_per_db * rng.standard_normal(int(wild.sum())) * p["outlier_sigma_db"]), 0, 255)
    near = dist <= p["reader_range_m"]
    return {"t_s": t[read][near], "tag_id": tags.tag_id[tag_idx][near].astype(np.float64), "rss": rss[near], "true_range_m": dist[near]}


def rfid_road_test(cols: dict[str, np.ndarray], tags: TagMap, env: RssEnvironment, p: dict[str, Any],
                   reader_gain_db: float, rng: np.random.Generator) -> tuple[dict[str, np.ndarray], int]:
    """The road-test terms of an RSS radio, applied to :func:`rfid`'s rows.

    The calibration (song2016 §6.1: a reader on a stand, tags averaged over
    5 minutes) and the RSS law describe a set-up the moving vehicle does not
    reproduce. On the road:

    * the reader's gain differs from the calibration's by ``reader_gain_db``
      (per drive: the antenna behind the car body, its height and cable);
    * each tag carries a constant mounting offset, 1-sigma ``tag_offset_db``
      (orientation to the reader, the wall behind it);
    * each reading fades more, 1-sigma ``extra_fading_db`` (vehicle
      motion, the car body and other traffic);
    * whole scans are lost with ``scan_dropout_probability`` per read epoch
      (the reader's link to the computer).

    Draws come from the ``rfid_road`` stream in a fixed order whatever the
    parameters; with every term 0 the rows are returned unchanged.

    Returns
    -------
    cols, dropped : dict, int
        The rows left, and how many read epochs were dropped.
    """
    offsets = rng.standard_normal(len(tags)) * p["tag_offset_db"]
    epochs, inverse = np.unique(cols["t_s"], return_inverse=True)
    lost = rng.random(epochs.size) < p["scan_dropout_probability"]
    fading = rng.standard_normal(cols["t_s"].size) * p["extra_fading_db"]
    if reader_gain_db == 0.0 and p["tag_offset_db"] == 0.0 and p["extra_fading_db"] == 0.0 and not lost.any():
        return cols, 0
    index = {int(t): i for i, t in enumerate(tags.tag_id)}
    tag_idx = np.array([index[int(t)] for t in cols["tag_id"]], dtype=np.int64)
    db = reader_gain_db + offsets[tag_idx] + fading
    rss = np.clip(np.round(cols["rss"] + env.units_per_db * db), 0.0, 255.0)
    keep = ~lost[inverse]
    out = {k: v[keep] for k, v in cols.items()}
    out["rss"] = rss[keep]
    return out, int(lost.sum())


def rfid_ranges(true_range_m: np.ndarray, p: dict[str, Any], range_scale: float,
                rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Ranges reported by a ranging radio (``rfid.reports_range``) for RFID rows.

    The sensor profile's choice for ranges that read long: rather than
    distort the RSS (whose distance an RSS model would turn into a range
    with several metres of its own error, burying a 5-8 % scale), the radio
    reports a range beside its RSS, as Plaza's UWB radio does, and that range
    reads long::

        range_m = range_scale * true_range_m + N(0, range_sigma_m) [+ excess]

    so an estimator that calibrates a range scale (a
    :class:`~graphpos.ranging.model.LinearCalibration` fitted to the drive,
    or a scale state) can recover ``range_scale``. With probability
    ``range_outlier_probability`` a reading gains a positive multipath-like
    excess uniform in [``range_outlier_min_m``, ``range_outlier_max_m``] (a
    reflected path taken for the direct one). The RSS column is left as the
    RSS law of the true distance gives it (its samples are those of an
    RSS-only drive). Draws come from the ``rfid_range`` stream, three values
    per row whatever the parameters. Ranges are clipped at 0.

    Parameters
    ----------
    true_range_m : array
        True reader-tag distance of each RFID row.
    p : dict
        The ``rfid`` parameters.
    range_scale : float
        The drive's drawn scale (:func:`profile_errors`).
    rng : numpy Generator
        The ``rfid_range`` stream.

    Returns
    -------
    range_m, outlier : arrays
        The reported ranges and which rows are outliers.
    """
    n = true_range_m.size
    noise = rng.standard_normal(n) * p["range_sigma_m"]
    outlier = rng.random(n) < p["range_outlier_probability"]
    excess = rng.uniform(p["range_outlier_min_m"], p["range_outlier_max_m"], n)
    range_m = range_scale * true_range_m + noise + np.where(outlier, excess, 0.0)
    return np.maximum(range_m, 0.0), outlier


def gnss_approach(traj: Trajectory, route: Route, duration_s: float, p: dict[str, Any],
                  rng: np.random.Generator) -> dict[str, np.ndarray]:
    """DGPS-grade fixes on the approach road before the first tunnel entrance.

    The paper scenarios start every filter from DGPS before the tunnel
    (song2016 §6): fixes at ``k / rate_hz`` from the drive's start for at
    most ``duration_s`` seconds (and the drive's length), only while the
    vehicle is on the road outside the tunnel before it first enters it
    (the route's zones: no fix from the first sample in the ``tunnel`` zone
    on, none in a turnaround). Error: white Gaussian, ``sigma_m`` per axis,
    reported as ``sigma_m``. Empty columns when ``enabled`` is false.
    """
    cols = {k: np.zeros(0) for k in ("t_s", "east_m", "north_m", "sigma_m")}
    if not p["enabled"]:
        return cols
    t = sample_times(min(duration_s, p["duration_s"]), p["rate_hz"])
    st = traj.state(t)
    outside = (np.array(route.zones)[st["zone"]] != "tunnel") & ~st["turnaround"]
    keep = np.cumprod(outside).astype(bool)  # up to the first sample inside (or turning)
    noise = rng.standard_normal((t.size, 2)) * p["sigma_m"]
    return {
        "t_s": t[keep],
        "east_m": st["east_m"][keep] + noise[keep, 0],
        "north_m": st["north_m"][keep] + noise[keep, 1],
        "sigma_m": np.full(int(keep.sum()), p["sigma_m"]),
    }


def gnss(traj: Trajectory, route: Route, duration_s: float, p: dict[str, Any], rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Position fixes in the zones that have a GNSS model (none elsewhere).

    Per zone: white noise (Gaussian, or Student t with ``tail_dof`` degrees of
    freedom scaled to ``sigma_m``), a Gauss-Markov wander (``wander_m``,
    ``wander_tau_s``) and a constant bias ``bias_m`` to the left of the
    road's forward direction (multipath off buildings on the right). The
    reported ``sigma_m`` is the zone's white-noise sigma, as a receiver's
    own figure would be: it does not know its multipath bias.
    """
    t = sample_times(duration_s, p["rate_hz"])
    st = traj.state(t)
    zone_names = np.array(route.zones)[st["zone"]]
    _, _, road_heading, _ = route.centre(st["route_s"])
    east, north, sigma = np.full(t.size, np.nan), np.full(t.size, np.nan), np.full(t.size, np.nan)
    dt = 1.0 / p["rate_hz"]
    for name, z in sorted(p["zones"].items()):
        m = zone_names == name
        # Draw for every epoch so a zone's errors do not depend on the others'.
        if z["tail_dof"] > 0:
            dof = z["tail_dof"]
            white = rng.standard_t(dof, (t.size, 2)) * z["sigma_m"] / np.sqrt(dof / (dof - 2.0))
        else:
            white = rng.standard_normal((t.size, 2)) * z["sigma_m"]
        wander = np.column_stack([gauss_markov(t.size, dt, z["wander_m"], z["wander_tau_s"], rng) for _ in range(2)])
        left = np.column_stack([-np.sin(road_heading), np.cos(road_heading)]) * z["bias_m"]
        err = white + wander + left
        east[m] = st["east_m"][m] + err[m, 0]
        north[m] = st["north_m"][m] + err[m, 1]
        sigma[m] = z["sigma_m"]
    keep = np.isfinite(east)
    return {"t_s": t[keep], "east_m": east[keep], "north_m": north[keep], "sigma_m": sigma[keep]}


def rsu(traj: Trajectory, route: Route, rsus: RsuMap, duration_s: float, p: dict[str, Any],
        rng: np.random.Generator) -> dict[str, np.ndarray]:
    """RSU readings inside the tunnel: each epoch, from the nearest RSU within
    ``range_m``, one row with the RSU subsystem's position fix and the range
    to that RSU, both with 1-sigma ``sigma_m`` (liu2016 §2.1.1)."""
    t = sample_times(duration_s, p["rate_hz"])
    cols = {k: np.zeros(0) for k in ("t_s", "rsu_id", "east_m", "north_m", "range_m", "sigma_m")}
    if len(rsus) == 0:
        return cols
    st = traj.state(t)
    pos = np.column_stack([st["east_m"], st["north_m"]])
    d = np.hypot(pos[:, :1] - rsus.east_m[None, :], pos[:, 1:] - rsus.north_m[None, :])
    nearest = np.argmin(d, axis=1)
    dist = d[np.arange(t.size), nearest]
    inside = (np.array(route.zones)[st["zone"]] == "tunnel") & ~st["turnaround"] & (dist <= p["range_m"])
    noise = rng.standard_normal((t.size, 3)) * p["sigma_m"]
    return {
        "t_s": t[inside],
        "rsu_id": rsus.rsu_id[nearest[inside]].astype(np.float64),
        "east_m": pos[inside, 0] + noise[inside, 0],
        "north_m": pos[inside, 1] + noise[inside, 1],
        "range_m": np.abs(dist[inside] + noise[inside, 2]),
        "sigma_m": np.full(int(inside.sum()), p["sigma_m"]),
    }


def arrival_times(t_s: np.ndarray, latency_s: float | tuple[float, float] | None, rng: np.random.Generator,
                  per_epoch: bool) -> np.ndarray:
    """``t_s + delay``: a fixed delay, or uniform in (lo, hi) per reading (per
    read epoch when ``per_epoch``: a reader delivers one read at once)."""
    if latency_s is None:
        return t_s.copy()
    if isinstance(latency_s, tuple):
        lo, hi = latency_s
        if per_epoch:
            epochs, inverse = np.unique(t_s, return_inverse=True)
            return t_s + rng.uniform(lo, hi, epochs.size)[inverse]
        return t_s + rng.uniform(lo, hi, t_s.size)
    return t_s + float(latency_s)
