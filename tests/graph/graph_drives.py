"""Small synthetic drives for the graph tests (independent of graphpos.sim)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from graphpos.drive import Channel, Drive, TagMap
from graphpos.ranging.model import LinearCalibration

PLAZA = Path(__file__).resolve().parents[2] / "../shared/data/plaza/Plaza1.mat"

RANGE_SIGMA_M = 0.3
#: The synthetic drive's wheel has no scale error and its range errors are
#: independent (no per-tag shadowing): graph configs that say so.
SYNTHETIC_MODEL = {"wheel_scale_density_per_sqrt_s": 1e-3, "range_sigma_scale": 1.0}


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
) -> Drive:
    """A vehicle at ``speed_mps`` (turning at ``turn_radps`` after 1/3 of the drive) past wall tags.

    Tags sit on both walls (north = +/-3 m) every ``tag_spacing_m`` along the
    east axis, and also along the curve's walls; ``tag_gap`` (east interval)
    leaves a stretch without tags. ``stop`` = (start_s, end_s) holds the
    vehicle still. IMU/wheel at 100 Hz, compass 10 Hz, RFID 1 Hz.
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
    w = np.where(t > duration_s / 3, turn_radps, 0.0)
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
    for i in idx:
        if tag_gap is not None and tag_gap[0] <= e[i] <= tag_gap[1]:
            continue
        for sd in (+1, -1):
            te.append(e[i] - sd * 3.0 * np.sin(yaw[i]))
            tn.append(n[i] + sd * 3.0 * np.cos(yaw[i]))
            side.append(sd)
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
    arrival = rt.copy()
    if rfid_latency_s is not None:
        arrival = rt + np.random.default_rng([seed, 1]).uniform(*rfid_latency_s, rt.size)  # own stream: same sensor noise
        order = np.argsort(rt, kind="stable")
        rt, arrival = rt[order], arrival[order]
    channels = {
        "imu": Channel("imu", imu_cols),
        "wheel": Channel("wheel", {"t_s": t, "speed_mps": noisy(v, 0.1)}),
        "compass": Channel("compass", {"t_s": tc, "yaw_rad": noisy(yaw[::10], np.radians(2.0))}),
        "rfid": Channel("rfid", {"t_s": rt, "tag_id": np.array(rid), "range_m": np.array(rr), "true_range_m": np.array(rtrue), "arrival_s": arrival}),
        "truth": Channel(
            "truth",
            {"t_s": t, "east_m": e, "north_m": n, "v_east_mps": v * np.cos(yaw), "v_north_mps": v * np.sin(yaw), "yaw_rad": yaw},
        ),
    }
    return Drive(f"synthetic-{seed}", channels, tags=tags)


def range_model() -> LinearCalibration:
    return LinearCalibration(sigma0_m=RANGE_SIGMA_M)


def truth_at(drive: Drive, t_s: np.ndarray) -> np.ndarray:
    tr = drive.truth
    return np.column_stack([np.interp(t_s, tr.t_s, tr.east_m), np.interp(t_s, tr.t_s, tr.north_m)])


def position_errors(drive: Drive, est) -> np.ndarray:
    return np.linalg.norm(est.position - truth_at(drive, est.t_s), axis=1)
