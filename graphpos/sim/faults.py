"""Fault injection: what real hardware does to a drive, as seeded, composable options.

``simulate(..., faults={kind: spec, ...})`` applies faults to the sensor
channels after they are generated (the truth is never touched). A spec is a
dict of the kind's parameters (missing ones take the defaults below) or a
list of such dicts for several episodes. Each fault draws from its own
random stream (seed, kind, episode), so adding one fault leaves the others'
effects unchanged, and each labels its time span as a window
``fault:<kind>`` (the whole drive for faults without an episode), so reports
can measure the error during the fault and the recovery after it.

Episodic faults take ``start_s`` (default: 30 % into the drive) and
``duration_s``; the sample-level faults (dropped, duplicated, late) act on
the whole drive unless given ``start_s``/``duration_s`` too. A fault that
would act on nothing is refused (ConfigError): an episode starting outside
the drive or of no length, no RFID tags for ``dead_tags``, or no reading of
the fault's channels in its span (a GNSS fault where the drive has no fix,
which the default 30 % puts in the tunnel of every built-in scenario): its
``fault:`` window would label a clean span, and reports would score it.

Kinds
-----
dead_tags : fraction
    That fraction of the tags never answers (a dead battery, a broken tag).
rfid_blackout : start_s, duration_s
    No RFID tag and no RSU is heard (reader or RSU network down).
nlos_burst : start_s, duration_s, probability, bias_db, sigma_db, rsu_bias_m
    Non-line-of-sight/multipath: each reading in the burst, with the given
    probability, loses ``-bias_db`` dB (plus N(0, sigma_db)) of RSS, i.e.
    reads too far; RSU ranges and fixes gain a positive bias of about
    ``rsu_bias_m``.
wheel_slip : start_s, duration_s, slip
    The wheel speed reads ``(1 + slip)`` times the truth (spin; negative: lock).
compass_disturbance : start_s, duration_s, offset_deg
    The compass is deflected by ``offset_deg`` (steel structures).
gnss_jump : start_s, duration_s, jump_m
    GNSS fixes jump by ``jump_m`` in a random direction (a wrong fix).
gnss_multipath : start_s, duration_s, sigma_m, bias_m
    GNSS fixes gain extra white noise and a bias of ``bias_m`` in a random
    direction; the reported sigma does not change.
clock_offset : channel, offset_s
    One channel's timestamps (and arrival times) are off by a constant.
dropped_samples : channels, fraction
    Rows of the channels are lost at random (``channels`` a list, or "all").
duplicated_samples : channels, fraction
    Rows of the channels are delivered twice.
late_readings : fraction, min_s, max_s
    A fraction of RFID and RSU readings arrive late by U(min_s, max_s).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from graphpos.drive import TagMap, Window
from graphpos.errors import ConfigError

_EPISODE = {"start_s": None, "duration_s": None}

#: Every fault kind with its parameters' defaults (None: see the module doc).
FAULTS: dict[str, dict[str, Any]] = {
    "dead_tags": {"fraction": 0.1},
    "rfid_blackout": {**_EPISODE, "duration_s": 60.0},
    "nlos_burst": {**_EPISODE, "duration_s": 10.0, "probability": 0.5, "bias_db": -15.0, "sigma_db": 5.0, "rsu_bias_m": 10.0},
    "wheel_slip": {**_EPISODE, "duration_s": 3.0, "slip": 0.3},
    "compass_disturbance": {**_EPISODE, "duration_s": 10.0, "offset_deg": 20.0},
    "gnss_jump": {**_EPISODE, "duration_s": 10.0, "jump_m": 20.0},
    "gnss_multipath": {**_EPISODE, "duration_s": 30.0, "sigma_m": 8.0, "bias_m": 5.0},
    "clock_offset": {"channel": "rfid", "offset_s": 0.2},
    "dropped_samples": {**_EPISODE, "channels": "all", "fraction": 0.05},
    "duplicated_samples": {**_EPISODE, "channels": "all", "fraction": 0.02},
    "late_readings": {**_EPISODE, "fraction": 0.2, "min_s": 0.5, "max_s": 2.0},
}

#: Sensor channels (the truth is never faulted).
SENSOR_CHANNELS = ("imu", "wheel", "compass", "rfid", "rsu", "gnss")

_KIND_INDEX = {kind: i for i, kind in enumerate(FAULTS)}


def _check(kind: str, spec: dict[str, Any], duration_s: float) -> dict[str, Any]:
    defaults = FAULTS[kind]
    if not isinstance(spec, dict):
        raise ConfigError(f"fault '{kind}' needs a table of parameters, got {spec!r}")
    unknown = set(spec) - set(defaults)
    if unknown:
        raise ConfigError(f"fault '{kind}' has no parameter {sorted(unknown)[0]!r} (valid: {', '.join(defaults)})")
    p = {**defaults, **spec}
    for key, value in p.items():
        if key == "channel":
            if value not in SENSOR_CHANNELS:
                raise ConfigError(f"fault '{kind}': channel must be one of {', '.join(SENSOR_CHANNELS)}, got {value!r}")
            continue
        if key == "channels":
            chans = list(SENSOR_CHANNELS) if value == "all" else value
            if isinstance(chans, str):
                chans = chans.split("+")
            if not isinstance(chans, list) or not chans or any(c not in SENSOR_CHANNELS for c in chans):
                raise ConfigError(f"fault '{kind}': channels must be 'all' or a list of {', '.join(SENSOR_CHANNELS)}, got {value!r}")
            p[key] = chans
            continue
        if value is None:
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ConfigError(f"fault '{kind}': {key} must be a finite number, got {value!r}")
        p[key] = float(value)
        if key in ("fraction", "probability") and not 0.0 <= value <= 1.0:
            raise ConfigError(f"fault '{kind}': {key} must be in [0, 1], got {value}")
        if key in ("duration_s", "min_s", "max_s", "sigma_db", "sigma_m", "jump_m") and value < 0:
            raise ConfigError(f"fault '{kind}': {key} must not be negative, got {value}")
    if "min_s" in p and p["min_s"] > p["max_s"]:
        raise ConfigError(f"fault '{kind}': min_s {p['min_s']} > max_s {p['max_s']}")
    if "start_s" in p:
        episodic = kind not in ("dropped_samples", "duplicated_samples", "late_readings")
        if p["start_s"] is None and (episodic or p["duration_s"] is not None):
            p["start_s"] = 0.3 * duration_s
        if p["start_s"] is None:
            p["start_s"], p["duration_s"] = 0.0, duration_s
        elif p["duration_s"] is None:
            p["duration_s"] = duration_s - p["start_s"]
        # an episode outside the drive, or of no length, would label a window where nothing happened
        if not 0.0 <= p["start_s"] < duration_s:
            raise ConfigError(f"fault '{kind}': start_s must be within the drive (0 to {duration_s:g} s), got {p['start_s']:g}")
        if p["duration_s"] <= 0:
            raise ConfigError(f"fault '{kind}': duration_s must be positive, got {p['duration_s']:g}")
    return p


def check_faults(faults: dict[str, Any] | None, duration_s: float) -> list[tuple[str, int, dict[str, Any]]]:
    """``(kind, episode, params)`` for every episode, defaults filled in.

    Raises
    ------
    ConfigError
        Unknown kind or parameter, or a bad value.
    """
    out = []
    if faults is None:
        return out
    if not isinstance(faults, dict):
        raise ConfigError(f"faults must be a table of fault kinds, got {faults!r}")
    for kind, spec in faults.items():
        if kind not in FAULTS:
            raise ConfigError(f"unknown fault '{kind}' (known: {', '.join(FAULTS)})")
        for episode, one in enumerate(spec if isinstance(spec, list) else [spec]):
            out.append((kind, episode, _check(kind, one, duration_s)))
    return out


def _span(p: dict[str, Any], duration_s: float) -> tuple[float, float]:
    if "start_s" not in p:
        return 0.0, duration_s
    return p["start_s"], p["start_s"] + p["duration_s"]


def _in(t: np.ndarray, span: tuple[float, float]) -> np.ndarray:
    return (t >= span[0]) & (t <= span[1])


def _rows(cols: dict[str, np.ndarray], index: np.ndarray) -> dict[str, np.ndarray]:
    return {k: v[index] for k, v in cols.items()}


def apply_faults(
    columns: dict[str, dict[str, np.ndarray]],
    faults: dict[str, Any] | None,
    duration_s: float,
    seed: int,
    tags: TagMap,
    units_per_db: float,
) -> tuple[dict[str, dict[str, np.ndarray]], list[Window], dict[str, Any]]:
    """Apply faults to the sensor channels' columns.

    Parameters
    ----------
    columns : dict
        Channel name -> column name -> array (the sensor channels).
    faults : dict or None
        Fault kind -> spec (see the module doc).
    duration_s, seed : the drive's
    tags : TagMap
        For ``dead_tags``.
    units_per_db : float
        RSS units per dB of the drive's RSS law (for ``nlos_burst``).

    Returns
    -------
    columns, windows, record
        Faulted columns, one ``fault:<kind>`` window per episode, and a
        JSON-serialisable record of the effective fault parameters and what
        was drawn (dead tag ids ...).
    """
    episodes = check_faults(faults, duration_s)
    cols = {name: dict(c) for name, c in columns.items()}
    windows: list[Window] = []
    record: dict[str, list[dict[str, Any]]] = {}
    for kind, episode, p in episodes:
        rng = np.random.default_rng([seed, 8, _KIND_INDEX[kind], episode])
        span = _span(p, duration_s)
        _require_target(kind, p, span, cols, tags)
        drawn = _APPLY[kind](cols, p, span, rng, tags=tags, units_per_db=units_per_db)
        windows.append(Window(f"fault:{kind}", max(span[0], 0.0), max(min(span[1], duration_s), max(span[0], 0.0))))
        record.setdefault(kind, []).append({**p, **(drawn or {})})
    for name, c in cols.items():
        order = np.argsort(c["t_s"], kind="stable")
        if np.any(order != np.arange(order.size)):
            cols[name] = _rows(c, order)
    return cols, windows, record


def _targets(kind: str, p: dict[str, Any]) -> tuple[str, ...]:
    """The sensor channels a fault acts on."""
    if kind == "clock_offset":
        return (p["channel"],)
    if kind in ("dropped_samples", "duplicated_samples"):
        return tuple(p["channels"])
    return _CHANNELS[kind]


def _require_target(kind: str, p: dict[str, Any], span: tuple[float, float], cols, tags: TagMap) -> None:
    """A ConfigError when the fault would act on nothing (no tags, or no reading of its channels in its span):
    its ``fault:`` window would otherwise label a span where the drive is clean, and be scored as a fault."""
    if kind == "dead_tags" and len(tags) == 0:
        raise ConfigError("fault 'dead_tags' has nothing to act on: the drive has no RFID tags")
    channels = _targets(kind, p)
    if any(name in cols and _in(cols[name]["t_s"], span).any() for name in channels):
        return
    what = " or ".join(channels)
    where = [f"{name} at " + ", ".join(f"{a:.1f}-{b:.1f}" for a, b in _stretches(cols[name]["t_s"])) + " s"
             for name in channels if name in cols and cols[name]["t_s"].size]
    if not where:
        raise ConfigError(f"fault '{kind}' has nothing to act on: the drive has no {what} readings")
    raise ConfigError(f"fault '{kind}' at {span[0]:.1f}-{span[1]:.1f} s has nothing to act on: the drive has no {what} "
                      f"reading then (it has {'; '.join(where)}: give start_s and duration_s there)")


def _stretches(t: np.ndarray, gap_s: float = 2.0, most: int = 4) -> list[tuple[float, float]]:
    """The spans of readings at most ``gap_s`` apart (the first ``most``)."""
    breaks = np.flatnonzero(np.diff(t) > gap_s)
    starts, ends = np.concatenate([[0], breaks + 1]), np.concatenate([breaks, [t.size - 1]])
    return [(float(t[a]), float(t[b])) for a, b in zip(starts[:most], ends[:most])]


def _dead_tags(cols, p, span, rng, tags, **_):
    n = int(round(p["fraction"] * len(tags)))
    dead = np.sort(rng.choice(tags.tag_id, size=n, replace=False)) if n else np.zeros(0, dtype=np.int64)
    if "rfid" in cols:
        keep = ~np.isin(cols["rfid"]["tag_id"].astype(np.int64), dead)
        cols["rfid"] = _rows(cols["rfid"], keep)
    return {"dead_tag_ids": [int(i) for i in dead]}


def _blackout(cols, p, span, rng, **_):
    for name in ("rfid", "rsu"):
        if name in cols:
            cols[name] = _rows(cols[name], ~_in(cols[name]["t_s"], span))


def _nlos(cols, p, span, rng, units_per_db, **_):
    if "rfid" in cols:
        c = cols["rfid"]
        hit = _in(c["t_s"], span) & (rng.random(c["t_s"].size) < p["probability"])
        loss_db = p["bias_db"] + rng.standard_normal(int(hit.sum())) * p["sigma_db"]
        rss = c["rss"].copy()
        rss[hit] = np.clip(np.round(rss[hit] + units_per_db * loss_db), 0.0, 255.0)
        c["rss"] = rss
    if "rsu" in cols:
        c = cols["rsu"]
        hit = _in(c["t_s"], span) & (rng.random(c["t_s"].size) < p["probability"])
        extra = np.abs(p["rsu_bias_m"] + rng.standard_normal(int(hit.sum())) * 0.3 * p["rsu_bias_m"])
        direction = rng.uniform(0, 2 * np.pi, int(hit.sum()))
        for key, value in (("range_m", extra), ("east_m", extra * np.cos(direction)), ("north_m", extra * np.sin(direction))):
            arr = c[key].copy()
            arr[hit] += value
            c[key] = arr


def _map_in_span(cols, name, column, span, fn):
    if name in cols:
        c = cols[name]
        m = _in(c["t_s"], span)
        arr = c[column].copy()
        arr[m] = fn(arr[m])
        c[column] = arr


def _wheel_slip(cols, p, span, rng, **_):
    _map_in_span(cols, "wheel", "speed_mps", span, lambda v: v * (1.0 + p["slip"]))


def _compass(cols, p, span, rng, **_):
    off = np.deg2rad(p["offset_deg"])
    _map_in_span(cols, "compass", "yaw_rad", span, lambda y: (y + off + np.pi) % (2 * np.pi) - np.pi)


def _gnss_jump(cols, p, span, rng, **_):
    direction = rng.uniform(0, 2 * np.pi)
    _map_in_span(cols, "gnss", "east_m", span, lambda e: e + p["jump_m"] * np.cos(direction))
    _map_in_span(cols, "gnss", "north_m", span, lambda n: n + p["jump_m"] * np.sin(direction))
    return {"direction_rad": float(direction)}


def _gnss_multipath(cols, p, span, rng, **_):
    direction = rng.uniform(0, 2 * np.pi)
    for key, trig in (("east_m", np.cos), ("north_m", np.sin)):
        _map_in_span(cols, "gnss", key, span,
                       lambda v, trig=trig: v + p["bias_m"] * trig(direction) + rng.standard_normal(v.size) * p["sigma_m"])
    return {"direction_rad": float(direction)}


def _clock_offset(cols, p, span, rng, **_):
    name = p["channel"]
    if name in cols:
        c = cols[name]
        c["t_s"] = c["t_s"] + p["offset_s"]
        if "arrival_s" in c:
            c["arrival_s"] = c["arrival_s"] + p["offset_s"]


def _dropped(cols, p, span, rng, **_):
    for name in p["channels"]:
        if name in cols:
            c = cols[name]
            drop = _in(c["t_s"], span) & (rng.random(c["t_s"].size) < p["fraction"])
            cols[name] = _rows(c, ~drop)


def _duplicated(cols, p, span, rng, **_):
    for name in p["channels"]:
        if name in cols:
            c = cols[name]
            twice = _in(c["t_s"], span) & (rng.random(c["t_s"].size) < p["fraction"])
            cols[name] = _rows(c, np.repeat(np.arange(c["t_s"].size), 1 + twice.astype(np.int64)))


def _late(cols, p, span, rng, **_):
    for name in ("rfid", "rsu"):
        if name in cols:
            c = cols[name]
            late = _in(c["t_s"], span) & (rng.random(c["t_s"].size) < p["fraction"])
            arrival = c["arrival_s"].copy()
            arrival[late] = np.maximum(arrival[late], c["t_s"][late] + rng.uniform(p["min_s"], p["max_s"], int(late.sum())))
            c["arrival_s"] = arrival


#: The sensor channels each fault kind acts on (clock_offset's and the sample faults' are their parameters').
_CHANNELS: dict[str, tuple[str, ...]] = {
    "dead_tags": ("rfid",),
    "rfid_blackout": ("rfid", "rsu"),
    "nlos_burst": ("rfid", "rsu"),
    "wheel_slip": ("wheel",),
    "compass_disturbance": ("compass",),
    "gnss_jump": ("gnss",),
    "gnss_multipath": ("gnss",),
    "late_readings": ("rfid", "rsu"),
}

_APPLY = {
    "dead_tags": _dead_tags,
    "rfid_blackout": _blackout,
    "nlos_burst": _nlos,
    "wheel_slip": _wheel_slip,
    "compass_disturbance": _compass,
    "gnss_jump": _gnss_jump,
    "gnss_multipath": _gnss_multipath,
    "clock_offset": _clock_offset,
    "dropped_samples": _dropped,
    "duplicated_samples": _duplicated,
    "late_readings": _late,
}
