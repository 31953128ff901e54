"""Accuracy, consistency and cost figures of one estimate against the truth.

Every figure is absolute: the estimate is compared with the truth
interpolated at the estimate's own epochs, with no alignment, no time shift
and no removal of a constant offset (what a navigation engineer means by
"the error"). Estimate epochs outside the truth's time span are not scored.

Definitions used throughout (metres):

- Euclidean error ``d_k = sqrt(e_k^2 + n_k^2)`` with ``e_k, n_k`` the east and
  north errors (estimate minus truth) at epoch ``k``; max, RMS
  ``sqrt(mean d^2)``, mean, median and 95th percentile of ``d``. The papers'
  tables report max and RMS of this quantity.
- ``2DRMS = 2 sqrt(mean(e^2 + n^2)) = 2 x RMS``. liu2016 reports "2DRMS"
  without defining it; the textbook definition is ``2 sqrt(sigma_e^2 +
  sigma_n^2)`` about the true position, which, taken about the truth rather
  than about the error mean, is twice the horizontal RMS error. We keep the
  bias in it (the honest figure for absolute positioning); for zero-mean
  errors the two definitions coincide.
- East and north error mean and (population) STD.
- NEES ``e_k^T P_k^-1 e_k`` of the 2-D position with the estimator's own
  east/north covariance ``P_k``; ANEES is its mean over the ``N`` scored
  epochs. For a consistent estimator with independent errors ``N x ANEES``
  is chi-square with ``2N`` degrees of freedom, so the two-sided 95 % band of
  ANEES is ``[chi2.ppf(0.025, 2N), chi2.ppf(0.975, 2N)] / N``. Filter errors
  are correlated in time, which widens the true spread: a value just outside
  this band is weak evidence; the fraction of epochs whose NEES is below
  ``chi2.ppf(0.95, 2)`` (expected 0.95) is reported beside it.
- Speed error ``|v_est| - |v_true|`` where the estimator gives a velocity,
  beside the raw wheel-speed error ``v_wheel - |v_true|`` (song2016 Fig. 16).
- Output rate: median of ``1 / diff(t)``; real-time factor: wall time of
  ``run`` over the drive's duration (below 1: faster than real time).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import stats

from graphpos.drive import Channel, Drive, Window
from graphpos.estimate import Estimate

#: Window name of the whole drive.
WHOLE = "whole"
#: Confidence of the NEES bands.
NEES_CONFIDENCE = 0.95


@dataclass(frozen=True)
class TruthAt:
    """Truth interpolated at some epochs (only the epochs inside its span)."""

    mask: np.ndarray  # (N,) which of the requested epochs are inside the truth span
    east_m: np.ndarray
    north_m: np.ndarray
    v_east_mps: np.ndarray
    v_north_mps: np.ndarray
    yaw_rad: np.ndarray

    @property
    def speed_mps(self) -> np.ndarray:
        return np.hypot(self.v_east_mps, self.v_north_mps)


def interpolate_truth(truth: Channel, t_s: np.ndarray) -> TruthAt:
    """Truth at ``t_s``: linear in position and velocity, on the circle for yaw.

    Yaw is unwrapped before the linear interpolation so that an interval
    crossing +-pi interpolates the short way; the result is wrapped to
    (-pi, pi].
    """
    t_s = np.asarray(t_s, dtype=np.float64)
    tt = truth.t_s
    mask = (t_s >= tt[0]) & (t_s <= tt[-1]) if len(tt) else np.zeros(t_s.shape, bool)
    t = t_s[mask]
    yaw = np.interp(t, tt, np.unwrap(truth.yaw_rad))
    return TruthAt(
        mask=mask,
        east_m=np.interp(t, tt, truth.east_m),
        north_m=np.interp(t, tt, truth.north_m),
        v_east_mps=np.interp(t, tt, truth.v_east_mps),
        v_north_mps=np.interp(t, tt, truth.v_north_mps),
        yaw_rad=wrap_angle(yaw),
    )


def wrap_angle(angle_rad: np.ndarray) -> np.ndarray:
    """Wrap to (-pi, pi]."""
    wrapped = np.mod(np.asarray(angle_rad) + np.pi, 2 * np.pi) - np.pi
    return np.where(wrapped == -np.pi, np.pi, wrapped)


# ---------------------------------------------------------------------------
# Statistics of an error sample
# ---------------------------------------------------------------------------


def position_error_stats(err_east_m: np.ndarray, err_north_m: np.ndarray) -> dict[str, float]:
    """Statistics of 2-D position errors (see the module docstring).

    Returns NaN figures (and ``n = 0``) for an empty sample.
    """
    e = np.asarray(err_east_m, dtype=np.float64)
    n = np.asarray(err_north_m, dtype=np.float64)
    if e.size == 0:
        keys = ("max_m", "rms_m", "mean_m", "median_m", "p95_m", "drms2_m",
                "east_mean_m", "east_std_m", "north_mean_m", "north_std_m")
        return {"n": 0, **{k: math.nan for k in keys}}
    d = np.hypot(e, n)
    rms = float(np.sqrt(np.mean(d**2)))
    return {
        "n": int(d.size),
        "max_m": float(d.max()),
        "rms_m": rms,
        "mean_m": float(d.mean()),
        "median_m": float(np.median(d)),
        "p95_m": float(np.percentile(d, 95)),
        "drms2_m": 2.0 * rms,
        "east_mean_m": float(e.mean()),
        "east_std_m": float(e.std()),
        "north_mean_m": float(n.mean()),
        "north_std_m": float(n.std()),
    }


def scalar_error_stats(err: np.ndarray, unit: str) -> dict[str, float]:
    """Mean, STD, RMS and max |.| of a signed scalar error (``unit`` suffixes the keys)."""
    err = np.asarray(err, dtype=np.float64)
    err = err[np.isfinite(err)]
    if err.size == 0:
        return {"n": 0, f"mean_{unit}": math.nan, f"std_{unit}": math.nan,
                f"rms_{unit}": math.nan, f"max_abs_{unit}": math.nan}
    return {
        "n": int(err.size),
        f"mean_{unit}": float(err.mean()),
        f"std_{unit}": float(err.std()),
        f"rms_{unit}": float(np.sqrt(np.mean(err**2))),
        f"max_abs_{unit}": float(np.abs(err).max()),
    }


def nees(err_en_m: np.ndarray, cov_en_m2: np.ndarray) -> np.ndarray:
    """Per-epoch NEES ``e^T P^-1 e`` of (N, 2) errors with (N, 2, 2) covariances.

    Epochs whose covariance is not positive definite give NaN.
    """
    err = np.asarray(err_en_m, dtype=np.float64)
    cov = np.asarray(cov_en_m2, dtype=np.float64)
    a, b, c = cov[:, 0, 0], 0.5 * (cov[:, 0, 1] + cov[:, 1, 0]), cov[:, 1, 1]
    det = a * c - b * b
    ok = np.isfinite(det) & (det > 0) & (a > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        # inverse of [[a, b], [b, c]] is [[c, -b], [-b, a]] / det
        q = (c * err[:, 0] ** 2 - 2 * b * err[:, 0] * err[:, 1] + a * err[:, 1] ** 2) / det
    return np.where(ok, q, np.nan)


def anees_band(n_epochs: int, dof: int = 2, confidence: float = NEES_CONFIDENCE) -> tuple[float, float]:
    """Two-sided ``confidence`` band of ANEES over ``n_epochs`` independent epochs."""
    if n_epochs <= 0:
        return (math.nan, math.nan)
    alpha = 1.0 - confidence
    k = dof * n_epochs
    return (float(stats.chi2.ppf(alpha / 2, k) / n_epochs), float(stats.chi2.ppf(1 - alpha / 2, k) / n_epochs))


def nees_stats(err_en_m: np.ndarray, cov_en_m2: np.ndarray) -> dict[str, Any]:
    """ANEES, its 95 % band, whether it lies inside, and the fraction of epochs under the 95 % bound."""
    q = nees(err_en_m, cov_en_m2)
    q = q[np.isfinite(q)]
    lo, hi = anees_band(q.size)
    if q.size == 0:
        return {"n": 0, "anees": math.nan, "band": [lo, hi], "in_band": False, "frac_below_95": math.nan}
    anees = float(q.mean())
    return {
        "n": int(q.size),
        "anees": anees,
        "band": [lo, hi],
        "in_band": bool(lo <= anees <= hi),
        "frac_below_95": float(np.mean(q <= stats.chi2.ppf(NEES_CONFIDENCE, 2))),
    }


def output_rate_hz(t_s: np.ndarray) -> float:
    """Median output rate (NaN with fewer than two distinct epochs)."""
    dt = np.diff(np.asarray(t_s, dtype=np.float64))
    dt = dt[dt > 0]
    return float(1.0 / np.median(dt)) if dt.size else math.nan


# ---------------------------------------------------------------------------
# Windows
# ---------------------------------------------------------------------------


def window_masks(t_s: np.ndarray, windows: tuple[Window, ...] | list[Window]) -> dict[str, np.ndarray]:
    """Boolean mask per window label over ``t_s``, plus :data:`WHOLE`.

    Windows sharing a label are united (a drive may enter a zone twice).
    """
    t_s = np.asarray(t_s, dtype=np.float64)
    masks: dict[str, np.ndarray] = {WHOLE: np.ones(t_s.shape, dtype=bool)}
    for w in windows:
        masks[w.label] = masks.get(w.label, np.zeros(t_s.shape, dtype=bool)) | w.contains(t_s)
    return masks


# ---------------------------------------------------------------------------
# One estimate
# ---------------------------------------------------------------------------


def wheel_speed_error(drive: Drive) -> tuple[np.ndarray, np.ndarray]:
    """Epochs and raw wheel speed minus true speed (song2016 Fig. 16), inside the truth span."""
    if not drive.has("wheel") or not drive.has("truth"):
        return np.zeros(0), np.zeros(0)
    wheel = drive.wheel
    at = interpolate_truth(drive.truth, wheel.t_s)
    return wheel.t_s[at.mask], wheel.speed_mps[at.mask] - at.speed_mps


def held_to_end(estimate: Estimate, end_s: float) -> Estimate:
    """The estimate with its last output repeated, at its median output interval, until ``end_s``.

    What a positioning system reports once its estimator falls silent (an
    RFID-only estimator past the last tag it hears): its last position.
    Scoring this is how a paper's "whole test" counts an RFID-only system
    over the stretches it does not cover (song2014 Table 4: its RFID-based
    positioning errs up to 19.01 m over the whole test, 8.57 m in the
    tunnel). An estimate with fewer than two outputs, or whose last output
    is within one interval of ``end_s``, is returned as it is.
    """
    if len(estimate) < 2:
        return estimate
    period_s = float(np.median(np.diff(estimate.t_s)))
    if not period_s > 0 or end_s - estimate.t_s[-1] < period_s:
        return estimate
    extra = estimate.t_s[-1] + period_s * np.arange(1, int(math.floor((end_s - estimate.t_s[-1]) / period_s)) + 1)
    last = np.full(extra.size, len(estimate) - 1)

    def held(column: np.ndarray | None) -> np.ndarray | None:
        return None if column is None else np.concatenate([column, column[last]])

    return Estimate(estimate.name, np.concatenate([estimate.t_s, extra]), held(estimate.east_m), held(estimate.north_m),
                    held(estimate.v_east_mps), held(estimate.v_north_mps), held(estimate.yaw_rad), held(estimate.cov_en_m2),
                    estimate.rate_hz, estimate.diagnostics, estimate.wall_time_s)


def evaluate_estimate(drive: Drive, estimate: Estimate) -> dict[str, Any]:
    """Every figure of one estimate on one drive, per window.

    Returns
    -------
    dict
        ``windows``: label -> {``position``: :func:`position_error_stats`,
        ``speed``: :func:`scalar_error_stats` (m/s) or None, ``nees``:
        :func:`nees_stats` or None}; ``wheel_speed``: the raw wheel-speed
        error per window; ``output_rate_hz``, ``n_outputs``,
        ``velocity_provided``, ``covariance_provided``, ``wall_time_s``,
        ``duration_s``, ``real_time_factor``, ``unscored_outputs`` (epochs
        outside the truth span); each window also has ``coverage``
        (:func:`coverage`: the share of its truth the figures are over).
    """
    from graphpos.errors import MissingChannelError

    if not drive.has("truth"):
        raise MissingChannelError(f"evaluate needs truth: drive '{drive.name}' has no truth channel")
    at = interpolate_truth(drive.truth, estimate.t_s)
    t = estimate.t_s[at.mask]
    err_e = estimate.east_m[at.mask] - at.east_m
    err_n = estimate.north_m[at.mask] - at.north_m
    finite = np.isfinite(err_e) & np.isfinite(err_n)
    speed_err = None
    if estimate.has_velocity:
        speed = np.hypot(estimate.v_east_mps[at.mask], estimate.v_north_mps[at.mask])
        speed_err = speed - at.speed_mps
    cov = estimate.cov_en_m2[at.mask] if estimate.cov_en_m2 is not None else None

    wheel_t, wheel_err = wheel_speed_error(drive)
    wheel_masks = window_masks(wheel_t, drive.windows) if wheel_err.size else {}

    truth_masks = window_masks(drive.truth.t_s, drive.windows)
    windows: dict[str, Any] = {}
    for label, m in window_masks(t, drive.windows).items():
        m = m & finite
        windows[label] = {
            "coverage": coverage(drive.truth.t_s[truth_masks.get(label, np.zeros(0, dtype=bool))], t[m]),
            "position": position_error_stats(err_e[m], err_n[m]),
            "speed": scalar_error_stats(speed_err[m], "mps") if speed_err is not None else None,
            "nees": nees_stats(np.column_stack([err_e[m], err_n[m]]), cov[m]) if cov is not None else None,
            "wheel_speed": scalar_error_stats(wheel_err[wheel_masks[label]], "mps") if label in wheel_masks else None,
        }
    duration = drive.duration_s
    wall = float(estimate.wall_time_s)
    return {
        "windows": windows,
        "output_rate_hz": output_rate_hz(estimate.t_s),
        "n_outputs": len(estimate),
        "non_finite_outputs": int((~finite).sum()),
        "unscored_outputs": int((~at.mask).sum()),
        "velocity_provided": estimate.has_velocity,
        "covariance_provided": estimate.cov_en_m2 is not None,
        "wall_time_s": wall,
        "duration_s": duration,
        "real_time_factor": wall / duration if duration > 0 and math.isfinite(wall) else math.nan,
    }


#: An output stands for the truth this close to it, s (or 1.5 output periods, if longer): a 1 Hz filter covers its drive.
COVERAGE_TOLERANCE_S = 1.0


def coverage(truth_t_s: np.ndarray, scored_t_s: np.ndarray) -> float:
    """Share of the truth epochs ``truth_t_s`` with a scored output within :data:`COVERAGE_TOLERANCE_S` (or 1.5
    output periods); NaN without truth epochs.

    Error figures are over the scored outputs only: an estimator that
    started late, or whose track ended when a sensor stopped (a CSV drive
    whose IMU log ended at 7 s of 30 s: 9 s of outputs, RMS 0.2 m, exit 0),
    is scored over that part, and its coverage says how much that is.
    """
    truth_t_s = np.asarray(truth_t_s, dtype=np.float64)
    if truth_t_s.size == 0:
        return math.nan
    scored = np.sort(np.asarray(scored_t_s, dtype=np.float64))
    if scored.size == 0:
        return 0.0
    period = float(np.median(np.diff(scored))) if scored.size > 1 else 0.0
    i = np.searchsorted(scored, truth_t_s)  # the outputs either side of each truth epoch
    before, after = scored[np.maximum(i - 1, 0)], scored[np.minimum(i, scored.size - 1)]
    nearest = np.minimum(np.abs(truth_t_s - before), np.abs(after - truth_t_s))
    return float(np.mean(nearest <= max(COVERAGE_TOLERANCE_S, 1.5 * period)))


def error_series(drive: Drive, estimate: Estimate) -> dict[str, np.ndarray]:
    """Per-epoch errors for plots: ``t_s``, ``error_m`` and, with velocity, ``speed_error_mps``."""
    at = interpolate_truth(drive.truth, estimate.t_s)
    out = {
        "t_s": estimate.t_s[at.mask],
        "error_m": np.hypot(estimate.east_m[at.mask] - at.east_m, estimate.north_m[at.mask] - at.north_m),
    }
    if estimate.has_velocity:
        out["speed_error_mps"] = np.hypot(estimate.v_east_mps[at.mask], estimate.v_north_mps[at.mask]) - at.speed_mps
    return out
