"""song2014 §3.3: RFID-only preliminary positioning with an LMS-federated filter.

The paper's equations (2)-(13) were images and are lost from the extraction;
this is their reconstruction in the standard forms ``../shared/papers/README.md``
prescribes. At each RFID scan ``k`` (1 Hz):

Readings arrive as scans (one ``t_s``, distances and sigmas from the
estimator's RangeModel, :class:`filters.base.FilterEstimator`).

1. **Local LMS filters** (eq. 2-6, ``i = 1..N``), one transversal filter of
   ``m`` taps per detected tag: input ``v_i(k) = [r_i(k), r_i(k-1), ...,
   r_i(k-m+1)]`` (the tag's ranges from the RangeModel; missing taps of a
   newly heard tag are filled with its first range), output
   ``r_hat_i = w_i^T v_i``. ``w_i(0) = [1, 0, ..., 0]`` (eq. 8: the filter
   starts as a pass-through).
2. **Least squares** (eq. 13): the position minimising
   ``sum_i u_gi (r_hat_i - |X - t_i|)^2 / sigma_i^2`` (Gauss-Newton from the
   last fix), where ``u_gi`` are the information distribution coefficients.
3. **Global LMS filter** (eq. 7, ``i = 0``) on the LS positions:
   ``X_RFID(k) = sum_j w0_j X_LS(k-j)`` with ``m0`` taps, shared by east and
   north. ``w0(0)`` are the weights of a straight-line fit evaluated at the
   newest sample (the paper does not print them; these pass constant-velocity
   motion without lag, which a vehicle needs, and average the noise). Until
   ``m0`` fixes are in, the line-fit weights of those available are used.
4. **Feedback** (§3.3, eq. 9-12): ranges recomputed from the fix,
   ``r_gi = |X_RFID - t_i|``, are the desired signals of the local filters:
   ``e_i = r_gi - r_hat_i``, normalised-LMS update
   ``w_i += mu e_i v_i / (eps + v_i^T v_i)``. The coefficients become
   ``u_gi ∝ sigma_i^2 / (sigma_i^2 + e_i^2)`` normalised to sum to one (eq. 12),
   so a tag whose range disagrees with the fix gets a small weight. The
   global filter's desired signal is the LS position re-solved with the
   updated local filters and coefficients (``e_0 = X_LS' - X_RFID``, NLMS,
   weights kept summing to one so a standing vehicle is not biased).

Deviations, and why: the coefficients are also refined within the scan
(the LS is solved; while the ranges fail a chi-square consistency test the
tag whose removal restores it best is isolated; residuals then give the
coefficients and the LS is solved again), so a failing tag is isolated at
once rather than one scan later — what §3.3 claims for the structure ("any
false information from tags can be effectively isolated"). A scan with fewer than ``min_tags`` tags gives
no fix (§5.2: "the reader can't detect enough tags").
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from filters.core import ekf
from filters.base import FilterEstimator
from graphpos.drive import Drive
from graphpos.errors import ConfigError
from graphpos.estimate import OutputRow
from graphpos.estimator import require_valid_numbers


@dataclass
class LmsFederatedConfig:
    """Tunables of the LMS-federated filter (song2014 §3.3).

    Defaults (the paper gives none) were chosen on ``paper-imm`` seeds 0-9:
    five global taps average the noise of 1 Hz fixes best at 2 m/s; a slow
    local step keeps the per-tag filters from chasing the fixes' own error.

    Attributes
    ----------
    local_taps : int
        ``m_i``, taps of each per-tag LMS filter.
    local_step : float
        Normalised-LMS step of the local filters (0 < step < 2).
    global_taps : int
        ``m_0``, taps of the global filter (1: no smoothing).
    global_step : float
        Normalised-LMS step of the global filter.
    min_tags : int
        Fewest tags in a scan for a fix.
    tag_memory_s : float
        A tag unheard for longer restarts its local filter.
    track_memory_s : float
        A gap between fixes longer than this restarts the global filter.
    gauss_newton_iterations : int
        Iterations of the LS solve.
    coefficient_feedback : bool
        Recompute the information distribution coefficients from the
        feedback and isolate inconsistent tags (False: equal coefficients, a
        plain weighted LS; for comparison).
    consistency_probability : float
        Chi-square probability of the scan's range-consistency test.
    max_isolated_tags : int
        Most tags isolated in one scan.
    """

    local_taps: int = 3
    local_step: float = 0.02
    global_taps: int = 5
    global_step: float = 0.05
    min_tags: int = 3
    tag_memory_s: float = 3.0
    track_memory_s: float = 3.0
    gauss_newton_iterations: int = 6
    coefficient_feedback: bool = True
    consistency_probability: float = 0.999
    max_isolated_tags: int = 2

    def __post_init__(self) -> None:
        require_valid_numbers(self, skip=("global_step",))
        if not 0.0 < self.consistency_probability <= 1.0:
            raise ConfigError(f"consistency_probability must lie in (0, 1], got {self.consistency_probability}")
        if self.local_taps < 1 or self.global_taps < 1:
            raise ConfigError("LMS filters need at least one tap")
        if not (0 < self.local_step < 2 and 0 <= self.global_step < 2):
            raise ConfigError("normalised-LMS steps must lie in (0, 2)")
        if self.min_tags < 3:
            raise ConfigError("a 2-D fix from ranges needs min_tags >= 3")


def line_fit_weights(taps: int) -> np.ndarray:
    """Weights of a least-squares line through ``taps`` equally spaced samples,
    evaluated at the newest (index 0 is the newest sample)."""
    if taps == 1:
        return np.ones(1)
    age = np.arange(taps, dtype=np.float64)
    centred = age - age.mean()
    return 1.0 / taps + (0.0 - age.mean()) * centred / np.sum(centred**2)


# Largest Gauss-Newton step (m): keeps a near-collinear scan from throwing
# the solution far away.
_MAX_STEP_M = 5.0
# Ridge added to the LS information matrix (keeps it invertible when every tag is in one direction).
_RIDGE_M2 = 1e-9


@dataclass
class _TagFilter:
    weights: np.ndarray
    history: deque
    last_t_s: float
    coefficient: float = 1.0


@dataclass
class Fix:
    """One preliminary position (song2014 ``X_RFID``)."""

    t_s: float
    east_m: float
    north_m: float
    cov_en_m2: np.ndarray
    tags_used: int


@dataclass
class LmsFederatedPositioner:
    """The LMS-federated filter as an online object, reusable by the fusion
    filters (which take its fixes as their ``x_RFID, y_RFID`` observation).

    Feed it one RFID scan at a time (:meth:`scan`). Local filters are keyed
    by tag position (a tag is where it is surveyed).
    """

    config: LmsFederatedConfig
    _tags: dict[tuple[float, float], _TagFilter] = field(default_factory=dict)
    _track: deque = field(default_factory=deque)
    _last_fix_t_s: float = -np.inf
    _last_fix: np.ndarray | None = None
    _global_w: np.ndarray | None = None
    scans_without_fix: int = 0

    def __post_init__(self) -> None:
        self._global_w = line_fit_weights(self.config.global_taps)
        self._track = deque(maxlen=self.config.global_taps)

    def scan(self, t_s: float, tags_en_m: np.ndarray, ranges_m: np.ndarray, sigmas_m: np.ndarray) -> Fix | None:
        """Process one scan (the usable readings of the tags heard at ``t_s``);
        returns its fix, or None with fewer than ``min_tags`` tags."""
        if len(ranges_m) < self.config.min_tags:
            self.scans_without_fix += 1
            return None
        return self._process_scan(t_s, np.asarray(tags_en_m, dtype=np.float64), np.asarray(ranges_m, dtype=np.float64),
                                  np.maximum(np.asarray(sigmas_m, dtype=np.float64), 1e-3))

    # -- one scan -------------------------------------------------------------
    def _process_scan(self, t_s: float, tags: np.ndarray, ranges: np.ndarray, sigmas: np.ndarray) -> Fix:
        cfg = self.config
        keys = [(float(e), float(n)) for e, n in tags]

        # 1. local LMS filters (eq. 2-6)
        filters = [self._local_filter(k, r, t_s) for k, r in zip(keys, ranges)]
        inputs = np.array([np.asarray(f.history) for f in filters])
        smoothed = np.einsum("ij,ij->i", inputs, np.array([f.weights for f in filters]))
        coeff = np.array([f.coefficient for f in filters])

        # 2. least squares weighted by the coefficients, tags failing the
        #    consistency test isolated
        n = len(ranges)
        x_ls, coeff, info = self._robust_solve(tags, smoothed, sigmas, coeff, self._initial_guess(tags, t_s))

        # 3. global LMS filter (eq. 7)
        if not self._track or t_s - self._last_fix_t_s > cfg.track_memory_s:
            self._track.clear()
        self._track.appendleft(x_ls)
        track = np.array(self._track)
        # until m0 fixes are in, a line fit through those there are
        w_global = self._global_w if len(track) == cfg.global_taps else line_fit_weights(len(track))
        x_rfid = w_global @ track

        # 4. feedback: recomputed ranges update the local filters (eq. 9-11),
        #    the coefficients (eq. 12) and the global filter
        ranges_g = np.hypot(*(x_rfid - tags).T)
        err = ranges_g - smoothed
        for f, v, e in zip(filters, inputs, err):
            f.weights = f.weights + cfg.local_step * e * v / (1e-9 + v @ v)
        new_coeff = self._coefficients(tags, ranges_g - err, sigmas, x_rfid)
        new_coeff /= new_coeff.sum()
        for f, c in zip(filters, new_coeff):
            f.coefficient = float(c) * n
        if cfg.global_step > 0 and len(self._track) == cfg.global_taps:
            resmoothed = np.einsum("ij,ij->i", inputs, np.array([f.weights for f in filters]))
            x_ls2, _ = self._solve(tags, resmoothed, n * new_coeff / sigmas**2, x_rfid)
            e0 = x_ls2 - x_rfid
            grad = track @ e0  # sum over east/north of e0 * input
            w = self._global_w + cfg.global_step * grad / (1e-9 + np.sum(track * track))
            self._global_w = w + (1.0 - w.sum()) / w.size  # keep sum(w) = 1

        self._last_fix_t_s = t_s
        self._last_fix = x_rfid
        cov = np.linalg.inv(info) * float(np.sum(w_global**2))
        return Fix(t_s, float(x_rfid[0]), float(x_rfid[1]), cov, int(np.count_nonzero(coeff > 1e-3 / n)))

    def _local_filter(self, tag: tuple[float, float], range_m: float, t_s: float) -> _TagFilter:
        cfg = self.config
        f = self._tags.get(tag)
        if f is None or t_s - f.last_t_s > cfg.tag_memory_s:
            w = np.zeros(cfg.local_taps)
            w[0] = 1.0
            f = _TagFilter(w, deque([range_m] * cfg.local_taps, maxlen=cfg.local_taps), t_s)
            self._tags[tag] = f
        else:
            f.history.appendleft(range_m)
            f.last_t_s = t_s
        return f

    def _initial_guess(self, tags: np.ndarray, t_s: float) -> np.ndarray:
        """The last fix moved on by the track's last displacement, else the
        tags' centroid."""
        if self._last_fix is None or t_s - self._last_fix_t_s > self.config.track_memory_s:
            return tags.mean(axis=0) + 1e-3
        if len(self._track) >= 2:
            return self._last_fix + (self._track[0] - self._track[1])
        return self._last_fix.copy()

    def _robust_solve(
        self, tags: np.ndarray, ranges: np.ndarray, sigmas: np.ndarray, coeff: np.ndarray, guess: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Weighted LS, then isolation of inconsistent tags and the coefficient
        feedback (§3.3).

        While the normalised residuals fail a chi-square test (probability
        ``consistency_probability``, ``n - 2`` degrees of freedom), the tag
        whose removal best restores consistency is isolated (coefficient 0),
        keeping at least four (three tags fix a point but cannot check it). The coefficients of the rest are then
        recomputed from their residuals and the LS solved again.
        """
        cfg = self.config
        n = len(ranges)
        coeff = coeff / coeff.sum()
        x, _ = self._solve(tags, ranges, n * coeff / sigmas**2, guess)
        active = np.ones(n, dtype=bool)

        def misfit(x_: np.ndarray, keep: np.ndarray) -> float:
            r = (ranges - np.hypot(*(x_ - tags).T)) / sigmas
            return float(np.sum(r[keep] ** 2))

        if cfg.coefficient_feedback:
            for _ in range(cfg.max_isolated_tags):
                dof = int(active.sum()) - 2
                if dof < 3 or misfit(x, active) <= ekf.chi2_threshold(cfg.consistency_probability, dof):
                    break
                best = None
                for j in np.flatnonzero(active):
                    keep = active.copy()
                    keep[j] = False
                    xj, _ = self._solve(tags[keep], ranges[keep], (n * coeff / sigmas**2)[keep], x)
                    cost = misfit(xj, keep)
                    if best is None or cost < best[0]:
                        best = (cost, j, xj)
                active[best[1]] = False
                x = best[2]
        coeff = np.where(active, self._coefficients(tags, ranges, sigmas, x) * coeff, 0.0)
        coeff /= coeff.sum()
        x, info = self._solve(tags, ranges, n * coeff / sigmas**2, x)
        return x, coeff, info

    def _coefficients(self, tags: np.ndarray, ranges: np.ndarray, sigmas: np.ndarray, x: np.ndarray) -> np.ndarray:
        if not self.config.coefficient_feedback:
            return np.ones(len(ranges))
        resid = ranges - np.hypot(*(x - tags).T)
        return sigmas**2 / (sigmas**2 + resid**2)

    def _solve(self, tags: np.ndarray, ranges: np.ndarray, weights: np.ndarray, x0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Weighted Gauss-Newton least squares on ranges; returns the position
        and the information matrix ``J^T W J`` at it."""
        x = np.asarray(x0, dtype=np.float64).copy()
        info = np.eye(2) * _RIDGE_M2
        w = weights[:, None]
        for _ in range(self.config.gauss_newton_iterations):
            d = x - tags
            r = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-6)
            J = d / r[:, None]
            Jw = J * w
            info = Jw.T.dot(J)
            info.flat[::3] += _RIDGE_M2
            # the 2x2 normal equations solved in closed form
            (a, b), (c, e) = info.tolist()
            g0, g1 = Jw.T.dot(ranges - r).tolist()
            det = a * e - b * c
            step = np.array([(e * g0 - b * g1) / det, (a * g1 - c * g0) / det])
            norm = math.hypot(step[0], step[1])
            if norm > _MAX_STEP_M:  # a poorly conditioned scan: move cautiously
                step *= _MAX_STEP_M / norm
            x += step
            if step.dot(step) < 1e-8:
                break
        return x, info


class LmsFederated(FilterEstimator):
    """song2014 §3.3 LMS-federated RFID positioning (one fix per scan, no velocity)."""

    name = "lms-federated"
    summary = "song2014 RFID-only LMS-federated filter: per-tag LMS, weighted LS, global LMS, feedback (per scan)"
    required_channels = ("rfid",)
    output_on_scan = True
    needs_start = False

    @classmethod
    def default_config(cls) -> LmsFederatedConfig:
        return LmsFederatedConfig()

    def _init_filter(self, drive: Drive, start) -> None:
        self._positioner = LmsFederatedPositioner(self.config)

    def _on_scan(self, t_s: float, tags: np.ndarray, ranges: np.ndarray, sigmas: np.ndarray) -> None:
        fix = self._positioner.scan(t_s, tags, ranges, sigmas)
        if fix is None:
            self.diagnostics["scans_without_fix"] = self._positioner.scans_without_fix
            return
        self.diagnostics["ranges_used"] += fix.tags_used
        self._emit_scan_output(OutputRow(fix.t_s, fix.east_m, fix.north_m, cov_en_m2=fix.cov_en_m2))


ESTIMATORS = {LmsFederated.name: LmsFederated}
