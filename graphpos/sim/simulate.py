"""Build a simulated drive: trajectory, infrastructure, sensors and windows."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from graphpos.drive import Channel, Drive, RsuMap, Window
from graphpos.errors import ConfigError
from graphpos.sim import sensors
from graphpos.sim.faults import apply_faults, check_faults
from graphpos.sim.infrastructure import no_tags, place_rsus, place_tags
from graphpos.sim.params import MAX_DURATION_S, resolve_params, sensor_set
from graphpos.sim.rss import ENVIRONMENTS
from graphpos.sim.scenarios import SCENARIOS, trajectory
from graphpos.sim.trajectory import Trajectory


def _check_latency(latency: Any) -> float | tuple[float, float] | None:
    if latency is None:
        return None
    if isinstance(latency, (tuple, list)):
        if len(latency) != 2:
            raise ConfigError(f"rfid latency range must be (lo, hi), got {latency!r}")
        lo, hi = (_check_latency(v) for v in latency)
        if lo > hi:
            raise ConfigError(f"rfid latency range has lo {lo} > hi {hi}")
        return (lo, hi)
    if isinstance(latency, bool) or not isinstance(latency, (int, float)) or not math.isfinite(latency) or latency < 0:
        raise ConfigError(f"rfid latency must be a non-negative number of seconds, got {latency!r}")
    return float(latency)


def _runs(t: np.ndarray, mask: np.ndarray, label: str) -> list[Window]:
    """One window per run of consecutive True samples."""
    if not mask.any():
        return []
    edges = np.diff(mask.astype(np.int8))
    starts = np.flatnonzero(edges == 1) + 1
    ends = np.flatnonzero(edges == -1)
    if mask[0]:
        starts = np.concatenate([[0], starts])
    if mask[-1]:
        ends = np.concatenate([ends, [mask.size - 1]])
    return [Window(label, float(t[a]), float(t[b])) for a, b in zip(starts, ends)]


def _windows(traj: Trajectory, t: np.ndarray, st: dict[str, np.ndarray]) -> list[Window]:
    """``in_tunnel``, ``zone:<name>``, ``turnaround`` and, on routes with a
    curve, ``straight`` / ``curve`` (the road's shape where the vehicle is,
    turnarounds excluded)."""
    route = traj.route
    zones = np.array(route.zones)[st["zone"]]
    on_route = ~st["turnaround"]
    out = _runs(t, (zones == "tunnel") & on_route, "in_tunnel")
    for name in route.zones:
        out += _runs(t, zones == name, f"zone:{name}")
    out += _runs(t, st["turnaround"], "turnaround")
    if route.spans(curved=True):
        _, _, _, k = route.centre(st["route_s"])
        out += _runs(t, on_route & (k == 0), "straight")
        out += _runs(t, on_route & (k != 0), "curve")
    return out


def simulate(
    scenario: str,
    pattern: str | None = None,
    seed: int = 0,
    duration_s: float | None = None,
    overrides: dict[str, Any] | None = None,
    rfid_latency_s: float | tuple[float, float] | None = None,
    faults: dict[str, Any] | None = None,
    profile: str | None = None,
) -> Drive:
    """Simulate one drive of a scenario.

    Parameters
    ----------
    scenario : str
        A key of :data:`graphpos.sim.SCENARIOS`.
    pattern : str, optional
        Motion pattern (default: the scenario's default pattern).
    seed : int
        Random seed (>= 0); the same arguments give the same drive.
    duration_s : float, optional
        Drive length. Default: one pass of the route. Longer drives go out
        and back (turning around on the approach roads) until it is reached.
    overrides : dict, optional
        Nested parameter overrides (the keys of a ``--config`` TOML file).
    rfid_latency_s : float or (lo, hi), optional
        Delay of RFID and RSU readings: ``arrival_s = t_s + delay``, fixed or
        uniform in (lo, hi) (per read for RFID, per reading for RSUs).
    faults : dict, optional
        Fault kind -> parameters (or a list of them for several episodes);
        see :mod:`graphpos.sim.faults`. Each episode adds a ``fault:<kind>``
        window; the effective parameters are recorded in ``params["faults"]``.
    profile : str, optional
        Sensor profile (:data:`graphpos.sim.params.PROFILES`): ``"ideal"``
        (the default: the sensor models without the profile error terms) or
        ``"realistic"`` (adds a gyro turn-on bias, yaw-rate and wheel-speed
        scale errors, RFID ranges that read long and gross range outliers,
        drawn per drive). Wins over a ``profile`` key in ``overrides``. The
        profile is recorded in ``params["profile"]``, the drawn terms in
        ``params["realised"]`` (``gyro_turn_on_bias_dps``,
        ``yaw_rate_scale_error``, ``wheel_profile_scale_error``,
        ``wheel_scale_error`` (the total: the wheel reads ``1 +`` it times the
        truth), ``range_scale``, ``range_outliers`` (RFID ranges given an
        outlier excess, counted before faults), and the ``paper`` profile's
        ``compass_bias_deg``, ``accel_turn_on_bias_x_mps2``,
        ``accel_turn_on_bias_y_mps2``, ``reader_gain_db`` and
        ``rfid_scans_dropped``). ``"paper"`` adds the error sources of the
        papers' road tests (see :data:`graphpos.sim.params.PROFILES`).

    Notes
    -----
    The paper-* scenarios carry a short DGPS ``gnss`` channel on the approach
    before the tunnel (parameters ``gnss_approach``; see
    :func:`graphpos.sim.sensors.gnss_approach`), scenarios with a GNSS model
    (``gnss`` parameters) their own.

    Raises
    ------
    ConfigError
        Unknown scenario, pattern or parameter; invalid value.
    """
    if scenario not in SCENARIOS:
        raise ConfigError(f"unknown scenario '{scenario}' (known: {', '.join(SCENARIOS)})")
    info = SCENARIOS[scenario]
    pattern = info.default_pattern if pattern is None else pattern
    if pattern not in info.patterns:
        raise ConfigError(f"scenario '{scenario}' has no motion pattern '{pattern}' (choose from: {', '.join(info.patterns)})")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ConfigError(f"seed must be a non-negative whole number, got {seed!r}")
    seed = int(seed)
    latency = _check_latency(rfid_latency_s)
    if overrides and "faults" in overrides:
        raise ConfigError("'faults' is not a parameter: pass it as simulate(faults=...) (the CLI takes [faults] from --config)")
    params = resolve_params(scenario, overrides, profile)

    traj = trajectory(scenario, pattern, params)
    route = traj.route
    if duration_s is None:
        duration_s = round(traj.first_pass_time_s, 6)
    if isinstance(duration_s, bool) or not isinstance(duration_s, (int, float)) or not math.isfinite(duration_s) or duration_s <= 0:
        raise ConfigError(f"duration must be a positive number of seconds, got {duration_s!r}")
    if duration_s > MAX_DURATION_S:
        raise ConfigError(f"duration {duration_s:g} s is longer than the {MAX_DURATION_S:g} s a drive may last")
    duration_s = float(duration_s)
    check_faults(faults, duration_s)

    t_truth = sensors.sample_times(duration_s, params["truth"]["rate_hz"])
    st = traj.state(t_truth)
    truth = {"t_s": t_truth, **{k: st[k] for k in (
        "east_m", "north_m", "v_east_mps", "v_north_mps", "yaw_rad", "yaw_rate_radps", "accel_x_mps2", "accel_y_mps2")}}
    errors = sensors.profile_errors(params, sensors.stream(seed, "profile"))
    errors.update(sensors.road_test_errors(params, sensors.stream(seed, "profile_terms")))
    cols: dict[str, dict[str, np.ndarray]] = {
        "imu": sensors.imu(traj, duration_s, params["imu"], sensors.stream(seed, "imu"),
                           turn_on_bias_dps=errors["gyro_turn_on_bias_dps"], yaw_rate_scale_error=errors["yaw_rate_scale_error"],
                           accel_turn_on_bias_mps2=(errors["accel_turn_on_bias_x_mps2"], errors["accel_turn_on_bias_y_mps2"])),
        "compass": sensors.compass(traj, route, duration_s, params["compass"], sensors.stream(seed, "compass"),
                                   bias_deg=errors["compass_bias_deg"]),
    }
    cols["wheel"], wheel_scale = sensors.wheel(traj, duration_s, params["wheel"], sensors.stream(seed, "wheel"),
                                               profile_scale_error=errors["wheel_profile_scale_error"])
    latency_rng = sensors.stream(seed, "latency")
    env = ENVIRONMENTS[params["rss_environment"]]

    tags = place_tags(route, params["tags"]) if "tags" in params else no_tags()
    range_outliers = scans_dropped = 0
    if "rfid" in params and len(tags):
        cols["rfid"] = sensors.rfid(traj, tags, env, duration_s, params["rfid"], sensors.stream(seed, "rfid"))
        cols["rfid"], scans_dropped = sensors.rfid_road_test(cols["rfid"], tags, env, params["rfid"], errors["reader_gain_db"],
                                                             sensors.stream(seed, "rfid_road"))
        if params["rfid"]["reports_range"]:
            cols["rfid"]["range_m"], outlier = sensors.rfid_ranges(
                cols["rfid"]["true_range_m"], params["rfid"], errors["range_scale"], sensors.stream(seed, "rfid_range"))
            range_outliers = int(outlier.sum())
        cols["rfid"]["arrival_s"] = sensors.arrival_times(cols["rfid"]["t_s"], latency, latency_rng, per_epoch=True)
    rsus = place_rsus(route, params["rsu"]) if "rsu" in params else RsuMap.empty()
    if len(rsus):
        cols["rsu"] = sensors.rsu(traj, route, rsus, duration_s, params["rsu"], sensors.stream(seed, "rsu"))
        cols["rsu"]["arrival_s"] = sensors.arrival_times(cols["rsu"]["t_s"], latency, latency_rng, per_epoch=False)
    if "gnss" in params:
        cols["gnss"] = sensors.gnss(traj, route, duration_s, params["gnss"], sensors.stream(seed, "gnss"))
    elif "gnss_approach" in params and params["gnss_approach"]["enabled"]:
        cols["gnss"] = sensors.gnss_approach(traj, route, duration_s, params["gnss_approach"], sensors.stream(seed, "gnss_approach"))
    cols, fault_windows, fault_record = apply_faults(cols, faults, float(t_truth[-1]), seed, tags, env.units_per_db)
    carried = sensor_set(params["sensors"])
    channels = {"truth": Channel("truth", truth), **{name: Channel(name, c) for name, c in cols.items() if name in carried}}

    record = {
        "scenario": scenario,
        "pattern": pattern,
        "seed": seed,
        "duration_s": duration_s,
        "rfid_latency_s": list(latency) if isinstance(latency, tuple) else latency,
        "faults": fault_record,
        **params,
        "realised": {
            "wheel_scale_error": wheel_scale,
            **errors,
            "range_outliers": range_outliers,
            "rfid_scans_dropped": scans_dropped,
            "route_length_m": route.length_m,
            "pass_duration_s": traj.first_pass_time_s,
            "lap_duration_s": traj.lap_time_s,
        },
    }
    return Drive(
        name=f"{scenario}-{pattern}-seed{seed}",
        channels=channels,
        tags=tags,
        rsus=rsus,
        windows=tuple(sorted(_windows(traj, t_truth, st) + fault_windows, key=lambda w: (w.start_s, w.label))),
        params=record,
    )
