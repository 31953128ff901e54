"""Checks of a drive: whether it makes sense at all, and its conventions against its truth.

:data:`DRIVE_RULES` is the one table of what makes a drive unusable (level
``error``: every time stamp equal, a span of years; ``run`` and ``evaluate``
refuse it in one line before any work) and what only deserves a word (level
``warning``: no sensor rows, a long gap, every tag at one point, a
recording whose writer was stopped before it closed the file, IMU or wheel
rows at a rate no logger has (times in the wrong unit), two rows of one
sensor at one time with different values; said on
stderr and listed in ``run.json`` and ``results.json``), with the rules the
reader enforces on every file listed alongside. :func:`drive_checks`
returns the drive against each rule; ``graphpos info`` prints them as its
``checks`` section.

Real recordings carry convention errors a user must see before trusting any
estimate: a truth heading 180 degrees from the direction of travel, a gyro
with a constant bias, ranges a few per cent long, a wheel-speed scale.
:func:`truth_checks` measures each of them on a drive with a ``truth``
channel; ``graphpos info`` prints the result. Truth is only used here (and
for scoring), never by an estimator.

Every figure is a plain float (or ``None`` where it cannot be measured: too
little motion, turning or data), so the result is JSON-serialisable. Each
check has a ``verdict``: ``"ok"``, a short word or two naming what is off
(``"reversed"``, ``"scaled"``, ``"biased"`` ...), or ``"unknown"`` when the
drive does not allow the check.

Thresholds (module constants) are loose enough for a clean recording with
MEMS-grade sensors (the simulator's gyro bias has a 1-sigma of 0.05 deg/s:
the 0.2 deg/s threshold is four of them) and tight enough to catch the
errors above.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from graphpos.drive import CHANNEL_NAMES, Channel, Drive
from graphpos.errors import DriveCheckError

#: Motion below this speed has no usable direction.
MIN_MOVING_SPEED_MPS = 0.05
#: ... nor motion below this fraction of the median speed over that threshold.
MOVING_SPEED_FRACTION = 0.25
#: Fewer moving truth samples than this: the heading check says "unknown".
MIN_MOVING_SAMPLES = 10
#: A truth heading drifting from the direction of motion by more than this over the drive is not ok.
MAX_HEADING_DRIFT_DEG = 30.0
#: Bin length of the heading drift.
HEADING_DRIFT_BIN_S = 60.0
#: A residual beyond this many robust sigmas is an outlier of a line fit.
OUTLIER_SIGMAS = 5.0
#: Range and odometry scales within this of 1 are ok.
SCALE_TOLERANCE = 0.02
#: Range offsets within this are ok.
RANGE_OFFSET_TOLERANCE_M = 0.3
#: Gyro biases within this are ok.
GYRO_BIAS_TOLERANCE_DPS = 0.2
#: Gyro scales within this of 1 are ok.
GYRO_SCALE_TOLERANCE = 0.03
#: The gyro scale is fitted only when the truth yaw rate over the windows spreads this much.
MIN_TURN_SPREAD_DPS = 1.0
#: The integrated-turn ratio is given only for a net truth yaw change this large.
MIN_NET_TURN_DEG = 90.0
#: Length of the windows the gyro is compared to the truth yaw over (at least three gyro samples long).
TURN_WINDOW_S = 1.0
#: ... and to the truth's course (direction of motion), which is noisier.
COURSE_WINDOW_S = 5.0


def _wrap_rad(angle_rad: np.ndarray) -> np.ndarray:
    """Angles into [-pi, pi)."""
    return np.remainder(np.asarray(angle_rad) + np.pi, 2 * np.pi) - np.pi


def _robust_sigma(residual: np.ndarray) -> float:
    """1.4826 x the median absolute deviation from the median."""
    return float(1.4826 * np.median(np.abs(residual - np.median(residual))))


def robust_line(x: np.ndarray, y: np.ndarray, fit_slope: bool = True) -> dict[str, Any] | None:
    """Robust fit of ``y = slope * x + intercept``.

    Huber iteratively reweighted least squares (tuning constant 1.345 robust
    sigmas) from an ordinary least-squares start, then an ordinary fit of the
    points within :data:`OUTLIER_SIGMAS` robust sigmas of that line, whose
    residuals give the reported sigma and outliers.

    Parameters
    ----------
    x, y : array of float
        Finite pairs.
    fit_slope : bool
        False: the slope is fixed at 1 and only the intercept is fitted.

    Returns
    -------
    dict or None
        ``slope``, ``intercept``, ``sigma`` (1.4826 MAD of the residuals),
        ``outlier_share`` (residual beyond :data:`OUTLIER_SIGMAS` sigmas),
        ``n``; None with fewer than 3 points (or no spread of ``x`` when
        fitting the slope).
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if x.size < 3 or (fit_slope and np.ptp(x) <= 0):
        return None
    design = np.column_stack([x, np.ones_like(x)]) if fit_slope else np.ones((x.size, 1))
    target = y if fit_slope else y - x

    def solve(weights: np.ndarray) -> np.ndarray:
        w = np.sqrt(weights)
        return np.linalg.lstsq(design * w[:, None], target * w, rcond=None)[0]

    def sigma_of(residual: np.ndarray) -> float:
        # floor: noise-free data has a zero MAD
        return max(_robust_sigma(residual), 1e-9 * (1.0 + float(np.median(np.abs(target)))))

    coef = solve(np.ones_like(x))
    for _ in range(100):
        residual = target - design @ coef
        u = np.abs(residual) / (1.345 * sigma_of(residual))
        new = solve(np.where(u <= 1.0, 1.0, 1.0 / np.maximum(u, 1e-12)))
        done = np.allclose(new, coef, rtol=1e-10, atol=1e-12)
        coef = new
        if done:
            break
    residual = target - design @ coef
    inlier = np.abs(residual) <= OUTLIER_SIGMAS * sigma_of(residual)
    if np.count_nonzero(inlier) >= 3 and not (fit_slope and np.ptp(x[inlier]) <= 0):
        coef = solve(inlier.astype(np.float64))
        residual = target - design @ coef
    sigma = sigma_of(residual)
    slope, intercept = (float(coef[0]), float(coef[1])) if fit_slope else (1.0, float(coef[0]))
    return {
        "slope": slope,
        "intercept": intercept,
        "sigma": sigma,
        "outlier_share": float(np.mean(np.abs(residual) > OUTLIER_SIGMAS * sigma)),
        "n": int(x.size),
    }


# ---------------------------------------------------------------------------
# Heading
# ---------------------------------------------------------------------------


def _moving_threshold_mps(truth: Channel) -> float:
    """Speed above which the truth moves clearly (see :func:`heading_check`);
    infinite when it never exceeds :data:`MIN_MOVING_SPEED_MPS`."""
    speed_mps = np.hypot(truth.v_east_mps, truth.v_north_mps)
    fast = speed_mps > MIN_MOVING_SPEED_MPS
    if not fast.any():
        return float("inf")
    return max(MIN_MOVING_SPEED_MPS, MOVING_SPEED_FRACTION * float(np.median(speed_mps[fast])))


def _drift(t_s: np.ndarray, diff_rad: np.ndarray) -> dict[str, Any] | None:
    """Robust line through the unwrapped circular means (in degrees) of
    ``diff_rad`` over time bins (see :func:`heading_check`)."""
    span_s = float(t_s[-1] - t_s[0])
    if span_s <= 0:
        return None
    bin_s = min(HEADING_DRIFT_BIN_S, span_s / 5)
    index = np.minimum((t_s / bin_s).astype(np.int64), int(np.ceil(span_s / bin_s)) - 1)
    counts = np.bincount(index)
    full = counts >= 3
    if np.count_nonzero(full) < 3:
        return None
    unit = np.exp(1j * diff_rad)
    mean_rad = np.angle(np.bincount(index, unit.real) + 1j * np.bincount(index, unit.imag))[full]
    centre_s = (np.bincount(index, t_s) / np.maximum(counts, 1))[full]
    return robust_line(centre_s, np.degrees(np.unwrap(mean_rad)))


def heading_check(truth: Channel) -> dict[str, Any]:
    """Truth yaw against the direction of motion ``atan2(v_north, v_east)``.

    Only samples where the truth moves clearly are used: speed above
    :data:`MIN_MOVING_SPEED_MPS` and above :data:`MOVING_SPEED_FRACTION` of
    the median speed over that threshold. A vehicle that really drives
    backwards most of the time reads as ``reversed`` too.

    Besides the size of the difference, its drift is measured: the robust
    slope (:func:`robust_line`) over time of its circular means over
    consecutive bins of :data:`HEADING_DRIFT_BIN_S` (at most a fifth of the
    moving time span), unwrapped; means, because single samples near stops
    scatter too much to unwrap. A truth heading integrated from a biased
    gyro drifts away from the direction of motion at the gyro's bias.

    Parameters
    ----------
    truth : Channel
        A ``truth`` channel.

    Returns
    -------
    dict
        ``moving_samples``; ``median_abs_diff_deg`` (median of
        ``|wrap(yaw - direction)|``); ``offset_deg`` (their circular mean,
        signed: yaw minus direction); ``share_over_90deg``; ``drift_dps``
        and ``drift_deg`` (the slope, and it times the moving samples' time
        span); ``verdict``: ``ok`` (at most 20 % over 90 deg and median
        under 30 deg), ``reversed`` (at least 80 % over 90 deg and median
        over 150 deg), either only with a drift under
        :data:`MAX_HEADING_DRIFT_DEG`; ``drifting`` (a larger drift, about
        which the bins' means scatter by under 30 deg); ``inconsistent``
        otherwise; ``unknown`` with fewer than :data:`MIN_MOVING_SAMPLES`
        moving samples.
    """
    speed_mps = np.hypot(truth.v_east_mps, truth.v_north_mps)
    out: dict[str, Any] = {"moving_samples": 0, "median_abs_diff_deg": None, "offset_deg": None,
                           "share_over_90deg": None, "drift_dps": None, "drift_deg": None, "verdict": "unknown"}
    moving = speed_mps > _moving_threshold_mps(truth)
    n = int(np.count_nonzero(moving))
    out["moving_samples"] = n
    if n < MIN_MOVING_SAMPLES:
        return out
    t_s = truth.t_s[moving]
    direction_rad = np.arctan2(truth.v_north_mps[moving], truth.v_east_mps[moving])
    diff_rad = _wrap_rad(truth.yaw_rad[moving] - direction_rad)
    abs_deg = np.degrees(np.abs(diff_rad))
    median_deg = float(np.median(abs_deg))
    share = float(np.mean(abs_deg > 90.0))
    drift = _drift(t_s - t_s[0], diff_rad)
    drift_dps = 0.0 if drift is None else drift["slope"]
    drift_deg = drift_dps * float(t_s[-1] - t_s[0])
    steady = abs(drift_deg) <= MAX_HEADING_DRIFT_DEG
    if steady and share >= 0.8 and median_deg >= 150.0:
        verdict = "reversed"
    elif steady and share <= 0.2 and median_deg <= 30.0:
        verdict = "ok"
    elif not steady and drift is not None and drift["sigma"] < 30.0:
        verdict = "drifting"
    else:
        verdict = "inconsistent"
    out.update(
        median_abs_diff_deg=median_deg,
        offset_deg=float(np.degrees(np.angle(np.mean(np.exp(1j * diff_rad))))),
        share_over_90deg=share,
        drift_dps=drift_dps,
        drift_deg=drift_deg,
        verdict=verdict,
    )
    return out


# ---------------------------------------------------------------------------
# Ranges, odometry, turn
# ---------------------------------------------------------------------------


def true_ranges_m(drive: Drive) -> np.ndarray:
    """True reader-tag distance of every RFID reading, NaN where unknown (truth: for scoring and checks only).

    ``rfid.true_range_m`` where given, else the distance from the truth
    position (linearly interpolated at the reading time; NaN outside the
    truth's time span) to the tag. :func:`graphpos.ranging.true_ranges_m`
    is this with errors for a drive without readings or truth; this one
    lives here so that ``graphpos info`` need not import the ranging
    package (which brings in the simulator).
    """
    rfid = drive.rfid
    true_m = np.array(rfid.true_range_m, dtype=np.float64)
    missing = ~np.isfinite(true_m)
    if missing.any() and drive.has("truth"):
        truth = drive.truth
        t = rfid.t_s[missing]
        inside = (t >= truth.t_s[0]) & (t <= truth.t_s[-1])
        east = np.interp(t, truth.t_s, truth.east_m)
        north = np.interp(t, truth.t_s, truth.north_m)
        tags = drive.tags.positions(rfid.tag_id[missing].astype(np.int64))
        true_m[missing] = np.where(inside, np.hypot(east - tags[:, 0], north - tags[:, 1]), np.nan)
    return true_m


def range_check(drive: Drive) -> dict[str, Any] | None:
    """RFID/UWB ``range_m`` readings against the true distances.

    True distances from :func:`true_ranges_m` (``rfid.true_range_m``
    where given, else from the truth trajectory).
    Fit: ``reading = scale * true + offset`` by :func:`robust_line`.

    Returns
    -------
    dict or None
        ``readings``, ``scale``, ``offset_m``, ``sigma_m`` (robust sigma of
        the residuals), ``outlier_share`` and ``outlier_rule``, ``verdict``
        (``ok``, or ``scaled`` / ``offset`` when beyond
        :data:`SCALE_TOLERANCE` / :data:`RANGE_OFFSET_TOLERANCE_M`);
        None when the drive has no range readings.
    """
    if not drive.has("rfid") or not np.isfinite(drive.rfid.range_m).any():
        return None
    true_m = true_ranges_m(drive)
    reading_m = drive.rfid.range_m
    use = np.isfinite(reading_m) & np.isfinite(true_m)
    fit = robust_line(true_m[use], reading_m[use])
    out: dict[str, Any] = {"readings": int(np.count_nonzero(use)), "scale": None, "offset_m": None, "sigma_m": None,
                           "outlier_share": None, "outlier_rule": f"|residual| > {OUTLIER_SIGMAS:g} robust sigma",
                           "verdict": "unknown"}
    if fit is None:
        return out
    off = []
    if abs(fit["slope"] - 1.0) > SCALE_TOLERANCE:
        off.append("scaled")
    if abs(fit["intercept"]) > RANGE_OFFSET_TOLERANCE_M:
        off.append("offset")
    out.update(scale=fit["slope"], offset_m=fit["intercept"], sigma_m=fit["sigma"],
               outlier_share=fit["outlier_share"], verdict=", ".join(off) or "ok")
    return out


def _overlap_s(a: np.ndarray, b: np.ndarray) -> tuple[float, float] | None:
    start, end = max(a[0], b[0]), min(a[-1], b[-1])
    return (float(start), float(end)) if end > start else None


def _with_ends(t_s: np.ndarray, start_s: float, end_s: float) -> np.ndarray:
    """``start_s``, the times strictly inside, ``end_s``."""
    inside = t_s[(t_s > start_s) & (t_s < end_s)]
    return np.r_[start_s, inside, end_s]


def odometry_check(drive: Drive) -> dict[str, Any] | None:
    """Wheel distance over truth path length, over the time both cover.

    Wheel distance: the trapezoid integral of ``|speed_mps|``; truth path:
    the summed lengths of the truth's steps (linearly interpolated at the
    ends of the span). Position noise in a recorded truth lengthens its path
    a little, so a scale a little under 1 may be the truth's.

    Returns
    -------
    dict or None
        ``span_s``, ``wheel_distance_m``, ``truth_path_m``, ``scale``
        (None for a truth path under 1 m), ``verdict`` (``ok`` or
        ``scaled`` beyond :data:`SCALE_TOLERANCE`); None without wheel
        speeds.
    """
    if not drive.has("wheel") or not drive.has("truth"):
        return None
    wheel, truth = drive.wheel, drive.truth
    span = _overlap_s(wheel.t_s, truth.t_s)
    out: dict[str, Any] = {"span_s": 0.0, "wheel_distance_m": None, "truth_path_m": None, "scale": None,
                           "verdict": "unknown"}
    if span is None:
        return out
    t = _with_ends(wheel.t_s, *span)
    speed = np.interp(t, wheel.t_s, np.abs(wheel.speed_mps))
    wheel_m = float(np.sum(np.diff(t) * (speed[1:] + speed[:-1]) / 2))
    t = _with_ends(truth.t_s, *span)
    east, north = np.interp(t, truth.t_s, truth.east_m), np.interp(t, truth.t_s, truth.north_m)
    path_m = float(np.sum(np.hypot(np.diff(east), np.diff(north))))
    out.update(span_s=span[1] - span[0], wheel_distance_m=wheel_m, truth_path_m=path_m)
    if path_m >= 1.0:
        scale = wheel_m / path_m
        out.update(scale=scale, verdict="scaled" if abs(scale - 1.0) > SCALE_TOLERANCE else "ok")
    return out


def _rate_fit(reference_dps: np.ndarray, gyro_dps: np.ndarray) -> dict[str, Any] | None:
    """:func:`robust_line` of gyro against reference rates; the slope is
    fixed at 1 when the reference spreads less than :data:`MIN_TURN_SPREAD_DPS`."""
    spread = reference_dps.size > 0 and float(np.std(reference_dps)) >= MIN_TURN_SPREAD_DPS
    fit = robust_line(reference_dps, gyro_dps, fit_slope=spread)
    if fit is not None and not spread:
        fit["slope"] = None
    return fit


def _rate_words(fit: dict[str, Any], what: str = "") -> list[str]:
    off = []
    if fit["slope"] is not None and fit["slope"] < 0:
        off.append("sign flipped" + what)
    elif fit["slope"] is not None and abs(fit["slope"] - 1.0) > GYRO_SCALE_TOLERANCE:
        off.append("scaled" + what)
    if abs(fit["intercept"]) > GYRO_BIAS_TOLERANCE_DPS:
        off.append("biased" + what)
    return off


def turn_check(drive: Drive) -> dict[str, Any] | None:
    """The gyro (``imu.yaw_rate_radps``) against the truth yaw and course.

    The truth yaw is unwrapped (a constant offset, such as a reversed
    heading, does not change its rate). Over the time both cover:

    - the integrated yaw rate over the truth's net yaw change (given only
      when that change exceeds :data:`MIN_NET_TURN_DEG`);
    - a robust fit (:func:`robust_line`) of ``yaw_rate = scale *
      truth_yaw_rate + bias`` over consecutive windows of
      ``max(TURN_WINDOW_S, 3 gyro intervals)``: the gyro's mean rate (its
      trapezoid integral over the window, over the window's length) against
      the truth's (its yaw, interpolated at the window ends, differenced).
      When the truth rate spreads less than :data:`MIN_TURN_SPREAD_DPS`
      (a straight drive) the scale cannot be told and is fixed at 1;
    - the same fit against the rate of the truth's course (direction of
      motion, from its velocity at the window ends; windows where it moves
      at both ends, as :func:`heading_check` counts moving) over longer
      windows of ``max(COURSE_WINDOW_S, 3 gyro intervals)`` (the course is
      noisier than the yaw). It does not use the truth yaw, so it still
      sees a gyro bias when the truth yaw was integrated from the same
      gyro (then the yaw fit cannot).

    Returns
    -------
    dict or None
        ``span_s``, ``gyro_yaw_change_deg``, ``truth_yaw_change_deg``,
        ``turn_ratio``, ``window_s``, ``windows``, ``scale`` (None when not
        fitted), ``bias_dps``, ``sigma_dps`` (robust sigma of the window
        residuals); ``course_window_s``, ``course_windows``,
        ``course_scale``, ``course_bias_dps``, ``course_sigma_dps`` (the
        course fit); ``verdict`` (``ok``, or ``biased`` / ``scaled`` /
        ``sign flipped`` from the yaw fit; where that finds nothing and the
        truth yaw does not follow the motion (:func:`heading_check` neither
        ``ok`` nor ``reversed``), the same words with ``" vs course"`` from
        the course fit, which is too noisy to judge by otherwise: a slow
        robot turning on the spot has a poorly defined course);
        None without gyro readings.
    """
    if not drive.has("imu") or not drive.has("truth"):
        return None
    imu, truth = drive.imu, drive.truth
    ok = np.isfinite(imu.yaw_rate_radps)
    if np.count_nonzero(ok) < 2:
        return None
    t_imu, rate_radps = imu.t_s[ok], imu.yaw_rate_radps[ok]
    out: dict[str, Any] = {"span_s": 0.0, "gyro_yaw_change_deg": None, "truth_yaw_change_deg": None,
                           "turn_ratio": None, "window_s": None, "windows": 0, "scale": None, "bias_dps": None,
                           "sigma_dps": None, "course_window_s": None, "course_windows": 0, "course_scale": None,
                           "course_bias_dps": None, "course_sigma_dps": None, "verdict": "unknown"}
    span = _overlap_s(t_imu, truth.t_s)
    if span is None or np.unique(t_imu).size < 2:
        return out
    # cumulative integral of the gyro at its own times
    turned_rad = np.r_[0.0, np.cumsum(np.diff(t_imu) * (rate_radps[1:] + rate_radps[:-1]) / 2)]
    yaw_rad = np.unwrap(truth.yaw_rad)
    gyro_change = float(np.diff(np.interp(span, t_imu, turned_rad))[0])
    truth_change = float(np.diff(np.interp(span, truth.t_s, yaw_rad))[0])
    out.update(span_s=span[1] - span[0], gyro_yaw_change_deg=float(np.degrees(gyro_change)),
               truth_yaw_change_deg=float(np.degrees(truth_change)))
    if abs(np.degrees(truth_change)) >= MIN_NET_TURN_DEG:
        out["turn_ratio"] = gyro_change / truth_change
    dt_s = float(np.median(np.diff(np.unique(t_imu))))

    def windows(length_s: float) -> np.ndarray:
        return span[0] + length_s * np.arange(int(np.floor((span[1] - span[0]) / length_s)) + 1)

    def gyro_dps(edges: np.ndarray) -> np.ndarray:
        return np.degrees(np.diff(np.interp(edges, t_imu, turned_rad)) / np.diff(edges))

    # against the truth yaw
    window_s = max(TURN_WINDOW_S, 3.0 * dt_s)
    edges = windows(window_s)
    out.update(window_s=window_s, windows=int(max(edges.size - 1, 0)))
    fit = None
    if edges.size >= 4:
        fit = _rate_fit(np.degrees(np.diff(np.interp(edges, truth.t_s, yaw_rad)) / window_s), gyro_dps(edges))
    if fit is not None:
        out.update(scale=fit["slope"], bias_dps=fit["intercept"], sigma_dps=fit["sigma"])
    # against the truth course
    course_window_s = max(COURSE_WINDOW_S, 3.0 * dt_s)
    edges = windows(course_window_s)
    out["course_window_s"] = course_window_s
    course = None
    if edges.size >= 4:
        v_east = np.interp(edges, truth.t_s, truth.v_east_mps)
        v_north = np.interp(edges, truth.t_s, truth.v_north_mps)
        moving = np.hypot(v_east, v_north) > _moving_threshold_mps(truth)
        both = moving[1:] & moving[:-1]
        out["course_windows"] = int(np.count_nonzero(both))
        if np.count_nonzero(both) >= 3:
            course_dps = np.degrees(_wrap_rad(np.diff(np.arctan2(v_north, v_east))) / course_window_s)
            course = _rate_fit(course_dps[both], gyro_dps(edges)[both])
    if course is not None:
        out.update(course_scale=course["slope"], course_bias_dps=course["intercept"], course_sigma_dps=course["sigma"])
    if fit is None and course is None:
        return out
    off = _rate_words(fit) if fit is not None else []
    if not off and course is not None and heading_check(truth)["verdict"] not in ("ok", "reversed"):
        # the truth yaw is no reference: judge by the course (noisy for a slow robot, so only then)
        off = _rate_words(course, " vs course")
    out["verdict"] = ", ".join(off) or "ok"
    return out


def truth_checks(drive: Drive) -> dict[str, Any]:
    """Every check of a drive against its truth.

    Parameters
    ----------
    drive : Drive

    Returns
    -------
    dict
        ``heading`` (:func:`heading_check`) and, where the drive has the
        channel, ``ranges`` (:func:`range_check`), ``odometry``
        (:func:`odometry_check`), ``turn`` (:func:`turn_check`). Empty
        without a ``truth`` channel. JSON-serialisable (plain floats, ints,
        strings and None).
    """
    if not drive.has("truth"):
        return {}
    checks: dict[str, Any] = {"heading": heading_check(drive.truth)}
    for name, check in (("ranges", range_check), ("odometry", odometry_check), ("turn", turn_check)):
        result = check(drive)
        if result is not None:
            checks[name] = result
    return checks


def _fmt(value: float | None, spec: str, unit: str = "") -> str:
    return "-" if value is None else f"{format(value, spec)}{unit}"


def describe_check(name: str, check: dict[str, Any]) -> str:
    """One line of figures of one check of :func:`truth_checks` (without its verdict).

    Parameters
    ----------
    name : {"heading", "ranges", "odometry", "turn"}
        The check's key in :func:`truth_checks`' result.
    check : dict
        Its value.
    """
    if name == "heading":
        if check["median_abs_diff_deg"] is None:
            return f"{check['moving_samples']} moving truth samples, too few to tell"
        return (f"truth yaw vs direction of motion: median |difference| {check['median_abs_diff_deg']:.1f} deg, "
                f"{100 * check['share_over_90deg']:.1f} % of {check['moving_samples']} moving samples over 90 deg off, "
                f"drift {check['drift_dps']:+.3f} deg/s ({check['drift_deg']:+.0f} deg over the drive)")
    if name == "ranges":
        if check["scale"] is None:
            return f"{check['readings']} readings with a true range, too few to fit"
        return (f"reading = {check['scale']:.4f} x true {check['offset_m']:+.3f} m, robust sigma "
                f"{check['sigma_m']:.3f} m, outliers {100 * check['outlier_share']:.1f} % "
                f"({check['outlier_rule']}) of {check['readings']}")
    if name == "odometry":
        return (f"wheel distance / truth path {_fmt(check['scale'], '.4f')} "
                f"({_fmt(check['wheel_distance_m'], '.1f')} / {_fmt(check['truth_path_m'], '.1f')} m "
                f"over {check['span_s']:.1f} s)")
    if name == "turn":
        def fit(prefix: str, windows: int, window_s: float | None) -> str:
            if check[prefix + "bias_dps"] is None:
                return f"{windows} windows, too few to fit"
            scale = check[prefix + "scale"]
            return (f"bias {check[prefix + 'bias_dps']:+.3f} deg/s, "
                    f"scale {'- (too little turning)' if scale is None else format(scale, '.4f')}, "
                    f"robust sigma {check[prefix + 'sigma_dps']:.3f} deg/s ({windows} windows of {window_s:.1f} s)")

        return (f"gyro = scale x truth yaw rate + bias: {fit('', check['windows'], check['window_s'])}; "
                f"vs course rate: {fit('course_', check['course_windows'], check['course_window_s'])}; "
                f"integrated / truth yaw change {_fmt(check['turn_ratio'], '.4f')} "
                f"({_fmt(check['gyro_yaw_change_deg'], '+.1f')} / {_fmt(check['truth_yaw_change_deg'], '+.1f')} deg)")
    return ""


# ---------------------------------------------------------------------------
# Drive checks: which awkward drives are refused, which are warned about
# ---------------------------------------------------------------------------

#: A drive spanning longer than this holds channels on different clocks
#: (seconds since the start next to Unix seconds); the simulator's longest
#: drive is a day.
MAX_DRIVE_SPAN_S = 7 * 86400.0
#: A stretch this long without a row of any sensor is warned about.
SENSOR_GAP_WARNING_S = 30.0
#: Channels the estimators read (all but the truth).
SENSOR_CHANNELS: tuple[str, ...] = tuple(name for name in CHANNEL_NAMES if name != "truth")


def _frozen_time(drive: Drive) -> str | None:
    rows = sum(len(ch) for ch in drive.channels.values())
    if rows and drive.duration_s == 0:
        which = "the only row is" if rows == 1 else f"all {rows} rows are"
        return f"{which} at t_s = {drive.start_s:g} s: no time passes"
    return None


def _time_span(drive: Drive) -> str | None:
    if drive.duration_s <= MAX_DRIVE_SPAN_S:
        return None
    spans = ", ".join(f"{name} {ch.t_s[0]:.6g} .. {ch.t_s[-1]:.6g} s" for name, ch in drive.channels.items() if len(ch))
    return f"the drive spans {drive.duration_s:.6g} s, over {MAX_DRIVE_SPAN_S:g} s ({spans}): channels on different clocks?"


def _channel_frozen(drive: Drive) -> str | None:
    for name, ch in drive.channels.items():
        if len(ch) >= 2 and ch.t_s[0] == ch.t_s[-1]:
            return f"all {len(ch)} rows of channel '{name}' are at t_s = {ch.t_s[0]:g} s"
    return None


def _no_sensor_rows(drive: Drive) -> str | None:
    if any(drive.has(name) for name in SENSOR_CHANNELS):
        return None
    return f"no sensor channel ({', '.join(SENSOR_CHANNELS)}) has rows: no estimator can run on this drive"


def _sensor_gap(drive: Drive) -> str | None:
    present = [drive.channels[name].t_s for name in SENSOR_CHANNELS if drive.has(name)]
    t_s = np.sort(np.concatenate(present)) if present else np.zeros(0)
    if t_s.size < 2:
        return None
    gap = int(np.argmax(np.diff(t_s)))
    gap_s = float(t_s[gap + 1] - t_s[gap])
    if gap_s <= SENSOR_GAP_WARNING_S:
        return None
    return f"no sensor row for {gap_s:.1f} s ({t_s[gap]:.3f} .. {t_s[gap + 1]:.3f} s)"


#: How far an odometry channel's rows may start after, or end before, the other sensors' rows, s. Past it the
#: estimators' tracks start late or end early (an odometry silence longer than
#: :data:`graphpos.ignition.MAX_ODOMETRY_GAP_S`, 2 s, ends a track), and the drive says so.
ODOMETRY_SPAN_WARNING_S = 5.0


def _odometry_span(drive: Drive) -> str | None:
    """An IMU or wheel log that starts late or ends early against the drive's other sensors (a CSV drive whose IMU
    log ended at 7 s of 30 s: every track ended at 9 s, exit 0, no word)."""
    present = {name: drive.channels[name].t_s for name in SENSOR_CHANNELS if drive.has(name)}
    first_s = min((float(t[0]) for t in present.values()), default=None)
    last_s = max((float(t[-1]) for t in present.values()), default=None)
    said = []
    for name in ("imu", "wheel"):
        if name not in present:
            continue
        t = present[name]
        if t[0] - first_s > ODOMETRY_SPAN_WARNING_S:
            said.append(f"'{name}' starts at {t[0]:.3f} s, {t[0] - first_s:.1f} s after the first sensor row")
        if last_s - t[-1] > ODOMETRY_SPAN_WARNING_S:
            said.append(f"'{name}' ends at {t[-1]:.3f} s, {last_s - t[-1]:.1f} s before the last sensor row ({last_s:.3f} s)")
    if not said:
        return None
    return f"{'; '.join(said)}: the estimators' tracks need the odometry and begin or end with it (a log cut short?)"


def _tags_at_one_point(drive: Drive) -> str | None:
    tags = drive.tags
    if len(tags) < 2 or np.ptp(tags.east_m) > 0 or np.ptp(tags.north_m) > 0:
        return None
    return (f"all {len(tags)} tags are at one point (east {tags.east_m[0]:g} m, north {tags.north_m[0]:g} m): "
            "ranges to them cannot fix a position")


def _window_outside(drive: Drive) -> str | None:
    if not any(len(ch) for ch in drive.channels.values()):
        return None
    for w in drive.windows:
        if w.end_s < drive.start_s or w.start_s > drive.end_s:
            return (f"window '{w.label}' [{w.start_s:g}, {w.end_s:g}] s lies outside the drive "
                    f"({drive.start_s:g} .. {drive.end_s:g} s)")
    return None


def _unclosed_recording(drive: Drive) -> str | None:
    if drive.params.get("unclosed_recording") is not True:
        return None
    rows = any(len(ch) for ch in drive.channels.values())
    ending = f"ending at t = {drive.end_s:.3f} s" if rows else "which holds no rows"
    return f"the recording was not closed (its writer was stopped) and was read up to its last complete chunk, {ending}"


#: Slowest and fastest plausible row rates of the odometry sensors (IMU, wheel), Hz. Real loggers run at
#: 5 Hz (Plaza's odometry) to 100 Hz (MRCLAM, the simulator), IMUs at up to a few kHz; a rate outside is
#: times read in the wrong unit (milliseconds taken as seconds: 100 Hz becomes 0.1 Hz; seconds as
#: milliseconds: 100 kHz).
MIN_ODOMETRY_RATE_HZ = 1.0
MAX_ODOMETRY_RATE_HZ = 10_000.0
#: Channels that hold one reading per instant (rfid and rsu may hold several: one per tag or RSU).
ONE_READING_CHANNELS: tuple[str, ...] = ("imu", "wheel", "compass", "gnss", "truth")


def row_rate_hz(t_s: np.ndarray) -> float | None:
    """1 / the median interval between the distinct times of a channel, Hz; None with fewer than three distinct times.

    The median, so that a gap or a burst does not move it; distinct times, so that rows repeated at one time
    (:func:`repeated_rows`) do not.
    """
    times = np.unique(t_s)
    if times.size < 3:
        return None
    return 1.0 / float(np.median(np.diff(times)))


def _odometry_rate(drive: Drive) -> str | None:
    said = []
    for channel in ("imu", "wheel"):
        rate_hz = row_rate_hz(drive.channels[channel].t_s) if drive.has(channel) else None
        if rate_hz is not None and not MIN_ODOMETRY_RATE_HZ <= rate_hz <= MAX_ODOMETRY_RATE_HZ:
            said.append(f"{channel} at {rate_hz:.3g} rows/s (one every {1 / rate_hz:.3g} s)")
    if not said:
        return None
    return (f"{' and '.join(said)}, outside the {MIN_ODOMETRY_RATE_HZ:g} .. {MAX_ODOMETRY_RATE_HZ:g} rows/s of any "
            "IMU or wheel logger: times in the wrong unit? (an import mapping's units.time, e.g. \"ms\")")


def repeated_rows(channel: Channel) -> tuple[np.ndarray, np.ndarray]:
    """The rows of a channel that repeat the time of an earlier row: exactly, and with other values.

    Parameters
    ----------
    channel : Channel

    Returns
    -------
    exact : array of bool
        Rows equal to an earlier row in every column (NaN equal to NaN): a
        logger that wrote the row twice.
    conflicting : array of bool
        Rows of a channel of :data:`ONE_READING_CHANNELS` at the time of an
        earlier row, not equal to any earlier row: two readings of one sensor
        at one instant. Always False for rfid and rsu, which read several
        tags or RSUs at once.
    """
    n = len(channel)
    exact = np.zeros(n, dtype=bool)
    if n < 2:
        return exact, exact.copy()
    table = np.column_stack(list(channel.columns.values()))
    _, first = np.unique(np.where(np.isnan(table), np.inf, table), axis=0, return_index=True)  # columns hold no inf
    exact[:] = True
    exact[first] = False
    if channel.kind not in ONE_READING_CHANNELS:
        return exact, np.zeros(n, dtype=bool)
    same_time = np.r_[False, channel.t_s[1:] == channel.t_s[:-1]]  # t_s never decreases
    return exact, same_time & ~exact


def _conflicting_rows(drive: Drive) -> str | None:
    said = []
    for name in ONE_READING_CHANNELS:
        if not drive.has(name):
            continue
        conflicting = repeated_rows(drive.channels[name])[1]
        if conflicting.any():
            row = int(np.argmax(conflicting))
            said.append(f"{name}: {int(np.count_nonzero(conflicting))} of {len(drive.channels[name])} rows "
                        f"(first: row {row}, t_s = {drive.channels[name].t_s[row]:.6g} s)")
    if not said:
        return None
    return ("rows at the time of an earlier row with other values, two readings of one sensor at one instant "
            "(a logger writing each row twice, or two sensors on one channel?), both used: " + "; ".join(said))


#: Odometry readings a graph turns into noise densities: (channel, column, the graph setting of its rate).
ODOMETRY_READINGS: tuple[tuple[str, str, str], ...] = (("wheel", "speed_mps", "wheel_rate_hz"), ("imu", "yaw_rate_radps", "imu_rate_hz"))
#: A channel whose readings are new at under this share of its row rate is said to repeat them.
HELD_READINGS_SHARE = 0.5


def new_reading_rate_hz(t_s: np.ndarray, values: np.ndarray) -> tuple[float, float] | None:
    """A channel's row rate and its rate of new readings, Hz; None with too few rows.

    The row rate is 1 / the median interval between rows (what a graph
    estimator takes the sample rate to be). A reading repeated over
    several rows (a logger that holds the last commanded speed, MRCLAM's
    odometry) is new once per run of identical values: the rate of new
    readings is the row rate over the median run length (the median, so
    that a standstill's one long run of zeros does not count).
    """
    if len(t_s) < 3:
        return None
    dt = float(np.median(np.diff(t_s)))
    if not dt > 0:
        return None
    changes = np.flatnonzero(values[1:] != values[:-1])
    runs = np.diff(np.concatenate(([-1], changes, [len(values) - 1])))
    return 1.0 / dt, 1.0 / (dt * float(np.median(runs)))


def held_readings(drive: Drive) -> list[tuple[str, str, str, float, float]]:
    """The odometry channels of ``drive`` that repeat their readings: ``(channel, column, rate setting, rows/s, new readings/s)``.

    A channel repeats them when its new readings come at under
    :data:`HELD_READINGS_SHARE` of its row rate (:func:`new_reading_rate_hz`)
    and at no less than :data:`MIN_ODOMETRY_RATE_HZ`: a channel whose value
    never changes (a wheel speed of 0 throughout a standstill), or barely
    ever, holds one reading, not a logger's repeats, and a rate of new
    readings near 0 would make the graphs take its rows for almost no
    information at all.
    """
    held = []
    for channel, column, setting in ODOMETRY_READINGS:
        if not drive.has(channel) or column not in drive.channels[channel].columns:
            continue
        values = drive.channels[channel].columns[column]
        if not (values != values[0]).any():
            continue  # one value throughout: nothing is repeated
        rates = new_reading_rate_hz(drive.channels[channel].t_s, values)
        if rates is not None and MIN_ODOMETRY_RATE_HZ <= rates[1] < HELD_READINGS_SHARE * rates[0]:
            held.append((channel, column, setting, *rates))
    return held


def _held_readings(drive: Drive) -> str | None:
    said = [f"{channel}.{column} has {rows_hz:.1f} rows/s but {new_hz:.1f} new readings/s "
            f"(--set {setting}={new_hz:.3g} makes the online graphs count those)"
            for channel, column, setting, rows_hz, new_hz in held_readings(drive)]
    if not said:
        return None
    return ("readings repeat over several rows: graph-batch counts each reading once, but the online graphs take each "
            "row's error as independent, so their odometry covariance is too small: " + "; ".join(said))


@dataclass(frozen=True)
class DriveRule:
    """One rule a drive is checked against (:data:`DRIVE_RULES`).

    Parameters
    ----------
    name : str
        Short key, as ``graphpos info`` and the reports show it.
    level : {"error", "warning"}
        ``error``: ``run`` and ``evaluate`` refuse the drive (one line,
        status 2) before any work; ``warning``: they say it on stderr when
        done and list it in ``run.json`` / ``results.json``.
    rule : str
        What a drive must do, in words.
    test : callable or None
        What is wrong with a drive (None when it keeps the rule); None for
        a rule enforced while the file is read (the file is refused, with
        the file, channel or field, row and value: :mod:`graphpos.drive`,
        :mod:`graphpos.io.json_rules`).
    """

    name: str
    level: str
    rule: str
    test: Callable[[Drive], str | None] | None


#: Every rule of a drive, errors first: the one table of what is refused
#: and what is warned about.
DRIVE_RULES: tuple[DriveRule, ...] = (
    DriveRule("values", "error", "every channel field and metadata field holds a value of its JSON type (numbers, "
              "never strings or booleans), finite where required, in its plausible range, whole for ids, a known "
              "name where names are fixed", None),
    DriveRule("time-order", "error", "t_s never decreases within a channel and arrival_s is never before t_s", None),
    DriveRule("ids", "error", "tag and RSU ids are unique and every reading names a tag or RSU of the map", None),
    DriveRule("frozen-time", "error", "time passes: the rows of a drive are not all at one t_s", _frozen_time),
    DriveRule("time-span", "error", f"the drive spans at most {MAX_DRIVE_SPAN_S:g} s", _time_span),
    DriveRule("sensor-rows", "warning", "some sensor channel has rows", _no_sensor_rows),
    DriveRule("channel-span", "warning", "the rows of a channel are not all at one t_s", _channel_frozen),
    DriveRule("sensor-gap", "warning", f"no stretch over {SENSOR_GAP_WARNING_S:g} s without a sensor row", _sensor_gap),
    DriveRule("odometry-span", "warning", f"IMU and wheel rows start and end within {ODOMETRY_SPAN_WARNING_S:g} s of "
              "the other sensors' rows", _odometry_span),
    DriveRule("tag-spread", "warning", "tags are not all at one point", _tags_at_one_point),
    DriveRule("window-span", "warning", "every window overlaps the drive's time span", _window_outside),
    DriveRule("held-readings", "warning", "the wheel speed and the yaw rate are new readings at least "
              f"{HELD_READINGS_SHARE:g} times as often as rows come", _held_readings),
    DriveRule("odometry-rate", "warning", f"IMU and wheel rows come at {MIN_ODOMETRY_RATE_HZ:g} .. "
              f"{MAX_ODOMETRY_RATE_HZ:g} per second (median interval)", _odometry_rate),
    DriveRule("conflicting-rows", "warning", f"{', '.join(ONE_READING_CHANNELS)} (one reading per instant) never "
              "hold two rows at one time with different values", _conflicting_rows),
    DriveRule("closed-file", "warning", "a recording was closed by its writer, not stopped while it wrote "
              "(graphpos.io.mcap_recorder)", _unclosed_recording),
)


def drive_checks(drive: Drive) -> list[dict[str, Any]]:
    """The drive against every rule of :data:`DRIVE_RULES`.

    Returns
    -------
    list of dict
        One per rule, in table order: ``name``, ``level``, ``rule``,
        ``checked`` (``on reading`` for the rules the reader enforces: the
        drive keeps them, or it would not have been read; else ``on the
        drive``), ``verdict`` (``ok``, or the level of a broken rule) and
        ``message`` (what is wrong, None when ok). JSON-serialisable.
    """
    results = []
    for rule in DRIVE_RULES:
        message = rule.test(drive) if rule.test is not None else None
        results.append({"name": rule.name, "level": rule.level, "rule": rule.rule,
                        "checked": "on reading" if rule.test is None else "on the drive",
                        "verdict": "ok" if message is None else rule.level, "message": message})
    return results


def check_message(result: dict[str, Any], source: str) -> str:
    """One line of a broken rule (a result of :func:`drive_checks`), naming the file."""
    return f"{source}: {result['message']} (drive check '{result['name']}')"


def require_usable(checks: list[dict[str, Any]], source: str) -> list[str]:
    """Refuse a drive that breaks a rule of level ``error``; say what it warns of.

    Parameters
    ----------
    checks : list of dict
        The drive's :func:`drive_checks`.
    source : str
        The file it was read from, named in every line.

    Returns
    -------
    list of str
        One line per broken rule of level ``warning`` (:func:`check_message`).

    Raises
    ------
    DriveCheckError
        The first broken rule of level ``error``.
    """
    broken = [c for c in checks if c["verdict"] != "ok"]
    for check in broken:
        if check["verdict"] == "error":
            raise DriveCheckError(check_message(check, source))
    return [check_message(c, source) for c in broken]
