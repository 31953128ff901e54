"""Small hand-built drives and error helpers for the song2016 filter tests (the simulator has its own tests).

``make_drive`` integrates song2016 eq. 16 itself at the IMU rate from chosen
body accelerations and yaw rate, so a noiseless drive is exactly what the
filters' model predicts (zero-error test); noisy drives add white sensor
noise of the paper's magnitudes and range noise growing with distance.
Like the papers' test drives, each starts with a few seconds of DGPS fixes
(``gnss``, 0.3 m), which the filters start from (:mod:`graphpos.ignition`).
"""

from pathlib import Path

import numpy as np

from filters.models import vehicle
from graphpos.drive import Channel, Drive, TagMap, Window


def tunnel_tags(length_m=150.0, spacing_m=6.0, half_width_m=3.0):
    xs = np.arange(0.0, length_m + 1e-9, spacing_m)
    east = np.concatenate([xs, xs])
    north = np.concatenate([np.full(xs.size, half_width_m), np.full(xs.size, -half_width_m)])
    side = np.concatenate([np.ones(xs.size), -np.ones(xs.size)])
    ids = np.arange(east.size)
    # optimised layout (song2016 §5.1): two tags per wall 6 m apart, groups every 30 m
    opt = ids[(np.round(east) % 30.0 == 0) | (np.round(east - 6.0) % 30.0 == 0)]
    group = (east // 30).astype(int)
    return TagMap(ids, east, north, side, group, layouts={"optimized": opt})


def make_drive(duration_s=40.0, seed=0, noise=True, turn=True, range_sigma0_m=0.3, range_slope=0.05, late_s=0.0, dgps_s=2.0):
    rng = np.random.default_rng(seed)
    dt = 0.01
    n = int(round(duration_s / dt)) + 1
    t = np.arange(n) * dt
    ax = 0.3 * np.sin(0.2 * t)
    wz = np.where(turn & (t > 0.5 * duration_s), 0.05 * np.sin(0.3 * t), 0.0)
    x = np.zeros((n, 5))
    x[0] = [-5.0, 0.0, 2.0, 0.0, 0.0]
    speed = np.zeros(n)
    speed[0] = 2.0
    ay = np.zeros(n)
    for k in range(1, n):
        ay[k - 1] = wz[k - 1] * speed[k - 1]
        x[k], _ = vehicle.improved_motion(x[k - 1], np.array([ax[k - 1], ay[k - 1], wz[k - 1]]), dt, False)
        speed[k] = x[k, 2] * np.cos(x[k, 4]) + x[k, 3] * np.sin(x[k, 4])
    truth = Channel("truth", {"t_s": t, "east_m": x[:, 0], "north_m": x[:, 1], "v_east_mps": x[:, 2],
                              "v_north_mps": x[:, 3], "yaw_rad": x[:, 4]})
    s = 1.0 if noise else 0.0
    imu = Channel("imu", {"t_s": t, "accel_x_mps2": ax + s * rng.normal(0, 0.1, n),
                          "accel_y_mps2": ay + s * rng.normal(0, 0.1, n),
                          "yaw_rate_radps": wz + s * rng.normal(0, np.deg2rad(0.2), n)})
    wheel = Channel("wheel", {"t_s": t, "speed_mps": speed + s * rng.normal(0, 0.1, n)})
    ic = np.arange(0, n, 10)
    compass = Channel("compass", {"t_s": t[ic], "yaw_rad": np.angle(np.exp(1j * (x[ic, 4] + s * rng.normal(0, np.deg2rad(2), ic.size))))})
    tags = tunnel_tags()
    rows = {"t_s": [], "tag_id": [], "range_m": [], "true_range_m": [], "arrival_s": []}
    for k in range(0, n, 100):
        d = np.hypot(tags.east_m - x[k, 0], tags.north_m - x[k, 1])
        seen = np.flatnonzero(d < 9.0)
        r = d[seen] + s * rng.normal(0, range_sigma0_m + range_slope * d[seen])
        for i, tid in enumerate(seen):
            rows["t_s"].append(t[k])
            rows["tag_id"].append(tid)
            rows["range_m"].append(max(r[i], 0.0))
            rows["true_range_m"].append(d[seen[i]])
            rows["arrival_s"].append(t[k] + late_s)
    rfid = Channel("rfid", rows)
    channels = {"imu": imu, "wheel": wheel, "compass": compass, "rfid": rfid, "truth": truth}
    if dgps_s > 0:
        ig = np.flatnonzero(t <= dgps_s)[::10]
        channels["gnss"] = Channel("gnss", {"t_s": t[ig], "east_m": x[ig, 0] + s * rng.normal(0, 0.3, ig.size),
                                            "north_m": x[ig, 1] + s * rng.normal(0, 0.3, ig.size), "sigma_m": np.full(ig.size, 0.3)})
    return Drive(f"test-{seed}", channels,
                 tags=tags, windows=(Window("in_tunnel", 3.0, duration_s),), params={"seed": seed})


def position_errors(drive, estimate, window=None):
    """Euclidean position error of each output epoch (optionally inside a window label)."""
    tr = drive.truth
    t = estimate.t_s
    m = (t >= tr.t_s[0]) & (t <= tr.t_s[-1])
    if window is not None:
        m &= np.any([(t >= w.start_s) & (t <= w.end_s) for w in drive.window(window)], axis=0)
    return np.hypot(estimate.east_m[m] - np.interp(t[m], tr.t_s, tr.east_m),
                    estimate.north_m[m] - np.interp(t[m], tr.t_s, tr.north_m))


def rms(errors):
    return float(np.sqrt(np.mean(np.square(errors))))


def mean_nees(drive, estimate):
    tr = drive.truth
    t = estimate.t_s
    d = np.column_stack([estimate.east_m - np.interp(t, tr.t_s, tr.east_m), estimate.north_m - np.interp(t, tr.t_s, tr.north_m)])
    return float(np.mean(np.einsum("ni,nij,nj->n", d, np.linalg.inv(estimate.cov_en_m2), d)))


#: The CMU Plaza dataset (gyro-only IMU, no compass, UWB ranges), read in place.
PLAZA1 = Path(__file__).resolve().parents[2] / "../shared/data/plaza/Plaza1.mat"
