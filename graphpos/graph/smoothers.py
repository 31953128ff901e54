"""GTSAM back ends behind one small interface: iSAM2, fixed-lag, and plain Values.

Every GTSAM failure (an under-constrained or ill-conditioned system, a key
error) is re-raised as :class:`graphpos.errors.EstimationError` naming the
keyframe and time, so a user sees one clear line, not a C++ message.
"""

from __future__ import annotations

import math

import gtsam
import numpy as np

from graphpos.errors import EstimationError


#: iSAM2 wildfire threshold (tangent-space units).
WILDFIRE_THRESHOLD = 0.01
#: iSAM2 relinearisation period (updates).
RELINEARIZE_SKIP = 10
#: The fixed-lag smoother marginalises old keyframes once per this period (s).
MARGINALISE_EVERY_S = 1.0
#: The windowed iSAM2 marginalises once per this share of its window.
WINDOW_MARGINALISE_SHARE = 0.1


def isam2_params(model_name: str, find_unused_factor_slots: bool = False) -> gtsam.ISAM2Params:
    """iSAM2 with partial relinearisation checks and per-variable-type thresholds.

    Landmarks (tags, RSUs) are held by tight priors and never need
    relinearising; pose thresholds are a few centimetres / milliradians.
    """
    params = gtsam.ISAM2Params()
    # QR, not GTSAM's default Cholesky: Cholesky squares the condition number. A
    # drive with an IMU and ranges but no wheel speed nor compass starts with a
    # free heading whose only information is its prior (1/pi^2), under a chain
    # of gyro factors 1e8 times stiffer: Cholesky called that "indeterminate" at
    # the first update, QR solves it. Same estimates elsewhere, 5 % more CPU
    # (Plaza1, MRCLAM6 robots 1 and 4, long-tunnel, paper-imm).
    params.setFactorization("QR")
    thresholds = gtsam.ISAM2ThresholdMap()
    if model_name == "planar":
        thresholds.insert(("x", np.array([0.02, 0.02, 0.005])))
        thresholds.insert(("l", np.array([1.0, 1.0])))
        thresholds.insert(("r", np.array([1.0, 1.0])))
    else:
        thresholds.insert(("x", np.array([0.02, 0.02, 0.01, 0.05, 0.05, 0.05])))
        thresholds.insert(("v", np.array([0.05, 0.05, 0.05])))
        thresholds.insert(("b", np.array([0.02, 0.02, 0.02, 2e-3, 2e-3, 2e-3])))
        thresholds.insert(("l", np.array([1.0, 1.0, 1.0])))
        thresholds.insert(("r", np.array([1.0, 1.0, 1.0])))
    params.setRelinearizeThreshold(thresholds)
    # Back-substitution stops where an update changes a variable by less than
    # this (m, rad, m/s); the newest keyframe, the causal output, is always
    # updated. GTSAM's 0.001 sends each tag scan's correction far back.
    params.setOptimizationParams(gtsam.ISAM2GaussNewtonParams(WILDFIRE_THRESHOLD))
    # Relinearise every 10th update (GTSAM's default): each tag scan moves
    # the recent trajectory by more than the thresholds, and checking every
    # update cost 2.5x the time for the same accuracy on a long-tunnel drive.
    params.relinearizeSkip = RELINEARIZE_SKIP
    params.enablePartialRelinearizationCheck = True
    params.findUnusedFactorSlots = find_unused_factor_slots
    return params


def relinearise(isam: gtsam.ISAM2, iterations: int) -> None:
    """``iterations`` empty iSAM2 updates that relinearise every variable (Gauss-Newton steps).

    Run when a track is anchored (its first information arrives), where
    the held, dead-reckoned track may sit far from the solution.
    """
    if iterations:
        force = gtsam.ISAM2UpdateParams()
        force.force_relinearize = True
        for _ in range(iterations):
            isam.update(gtsam.NonlinearFactorGraph(), gtsam.Values(), force)


def gtsam_error(exc: Exception, what: str) -> EstimationError:
    """A one-line EstimationError from a GTSAM exception."""
    text = " ".join(str(exc).split())
    if "Indeterminate linear system" in text or "IndeterminantLinearSystem" in text:
        text = "under-constrained or ill-conditioned system (" + text[:160] + ")"
    return EstimationError(f"{what}: GTSAM failed: {text[:300]}")


class FixedLagSmoother:
    """GTSAM's IncrementalFixedLagSmoother (iSAM2 inside, bounded window).

    Keyframes leave the window in batches, once per ``marginalise_every_s``
    (default :data:`MARGINALISE_EVERY_S`), not one per update: the timestamps handed to
    GTSAM are floored to that period. Each marginalisation makes iSAM2
    reorder the window with the old keys first; done at every 10 Hz update,
    that triggered a full re-elimination of the window in up to 85-95 % of
    the updates (``ISAM2Result.getBatchReorderTriggered``), a rate that rose
    over the first minutes of a drive, and cost 6x the time of batched
    marginalisation. Batched, the causal estimates equal graph-isam2's (the
    frequent full re-eliminations had relinearised differently). Flooring only delays
    marginalisation: a key stays in the window for at least ``lag_s`` and at
    most ``lag_s + marginalise_every_s``.
    """

    def __init__(self, model_name: str, lag_s: float, marginalise_every_s: float = MARGINALISE_EVERY_S):
        self.lag_s = lag_s
        self.marginalise_every_s = marginalise_every_s
        self.smoother = gtsam.IncrementalFixedLagSmoother(lag_s, isam2_params(model_name, find_unused_factor_slots=True))
        self._latest_s = -math.inf

    def stamp(self, t_s: float) -> float:
        """The timestamp GTSAM is given for a key of time ``t_s`` (floored to ``marginalise_every_s``)."""
        return math.floor(t_s / self.marginalise_every_s) * self.marginalise_every_s

    def cutoff_s(self, timestamps: dict[int, float]) -> float:
        """An update with these new timestamps marginalises every key whose :meth:`stamp` is before this."""
        return max([self._latest_s, *(self.stamp(t) for t in timestamps.values())]) - self.lag_s

    def update(self, factors: gtsam.NonlinearFactorGraph, values: gtsam.Values, timestamps: dict[int, float], extra_iterations: int = 0) -> None:
        stamps = {key: self.stamp(t_s) for key, t_s in timestamps.items()}
        self.smoother.update(factors, values, stamps)
        self._latest_s = max([self._latest_s, *stamps.values()])
        # the smoother's own update takes no ISAM2UpdateParams; its iSAM2 (a
        # reference, not a copy) does: the same forced relinearisations as
        # graph-isam2's, so both run the same sequence of iSAM2 updates (empty
        # smoother updates instead shifted the relinearisation period by 7
        # updates and left the anchored start up to 9 cm from graph-isam2's)
        relinearise(self.smoother.getISAM2(), extra_iterations)

    def source(self):
        return self.smoother

    def marginal(self, key: int) -> np.ndarray:
        return self.smoother.marginalCovariance(key)

    def estimate(self) -> gtsam.Values:
        return self.smoother.calculateEstimate()

    def holds(self, key: int) -> bool:
        """Whether a variable is in the window (not yet marginalised)."""
        return self.smoother.getISAM2().valueExists(key)


class WindowedIsam2Smoother(FixedLagSmoother):
    """iSAM2 over the last ``window_s`` of keyframes: graph-isam2's smoother and graph-batch's seeding pass.

    Full-history iSAM2's per-update cost grows with the length of the
    drive, whatever the update re-eliminates: in GTSAM 4.3.0 (and
    4.3.2.dev) each update's re-eliminated top of the Bayes tree is built as
    a temporary BayesTree whose orphans (the rest of the tree) hang below
    it, and its non-recursive destructor walks every descendant. On a plain
    Pose2 chain (one key and two factors per update, 4 variables
    re-eliminated) the time of 2000 updates grows from 0.18 s to 0.96 s
    between 2000 and 10 000 keys; ``perf`` puts 61 % of the time in
    ``~BayesTree``. On a 60-minute drive graph-isam2 cost 8.5 times as much
    in its last sixth as in its first, and graph-batch's seeding iSAM2 held
    most of its 1.5 GB.

    So this is a fixed-lag smoother whose window is far longer than a causal
    output needs (``GraphConfig.isam2_window_s``): keyframes older than that
    are marginalised in batches, once per :data:`WINDOW_MARGINALISE_SHARE`
    of the window (:class:`FixedLagSmoother`), and the Bayes tree, its
    per-update cost and its memory stay bounded. Each marginalisation
    re-eliminates the window: once a second, as graph-fixed-lag does, a
    120 s window cost 55 % more CPU than full iSAM2 on a 10-minute drive;
    once per 12 s, about the same (6.3 s against 6.6 s). Until the first
    marginalisation it is a plain iSAM2 (GTSAM constrains the ordering only
    when some variable is to be marginalised), so on a drive shorter than
    the window it gives full iSAM2's estimates. Unlike graph-fixed-lag's
    smoother, :meth:`estimate` back-substitutes fully (``calculateEstimate``
    stops at the wildfire threshold, which leaves the smoothed past up to
    about 1 cm stale). The whole drive's variables come from the estimators'
    factor history (:meth:`~graphpos.graph.builder.GraphBuilder.history_values`).
    """

    def __init__(self, model_name: str, window_s: float):
        super().__init__(model_name, window_s, marginalise_every_s=WINDOW_MARGINALISE_SHARE * window_s)
        self._stamps: dict[int, float] = {}  # every key in the window, and the stamp GTSAM has for it
        # the same keys grouped by stamp: stamps are floored to the marginalisation period, so the keys that leave
        # are a few whole groups, found without scanning the window's thousands of keys at every update
        self._by_stamp: dict[float, set[int]] = {}
        self._left = gtsam.Values()  # every key marginalised, as estimated just before it left

    def update(self, factors: gtsam.NonlinearFactorGraph, values: gtsam.Values, timestamps: dict[int, float], extra_iterations: int = 0) -> None:
        cutoff_s = self.cutoff_s(timestamps)
        leaving: set[int] = set()
        for stamp in [stamp for stamp in self._by_stamp if stamp < cutoff_s]:
            leaving |= self._by_stamp.pop(stamp)
        if leaving:
            kept = self.isam.calculateBestEstimate()
            for key in [key for key in kept.keys() if key not in leaving]:
                kept.erase(key)
            self._left.insert(kept)
            for key in leaving:
                del self._stamps[key]
        for key, t_s in timestamps.items():
            stamp = self.stamp(t_s)
            old = self._stamps.get(key)
            if old != stamp:
                if old is not None:
                    self._by_stamp[old].discard(key)
                self._stamps[key] = stamp
                self._by_stamp.setdefault(stamp, set()).add(key)
        super().update(factors, values, timestamps, extra_iterations)

    @property
    def isam(self) -> gtsam.ISAM2:
        """The iSAM2 inside (a reference): its factors, and updates that remove factors."""
        return self.smoother.getISAM2()

    def estimate(self) -> gtsam.Values:
        """Every variable held so far: the window's (fully back-substituted), and each marginalised one as it
        was estimated just before it left, 1-1.1 windows after its time: a smoothed value, for the whole
        drive's solves (learning, ``final``, graph-batch) to start from. Variables marginalised in the very
        update that added them (a start-up backlog longer than the window) are not kept."""
        values = self.isam.calculateBestEstimate()
        values.insert(self._left)
        return values


class ValuesSource:
    """Reads a plain ``gtsam.Values`` with the smoothers' ``calculateEstimate*`` names."""

    def __init__(self, values: gtsam.Values):
        self.values = values

    def calculateEstimatePose2(self, key: int) -> gtsam.Pose2:
        return self.values.atPose2(key)

    def calculateEstimatePose3(self, key: int) -> gtsam.Pose3:
        return self.values.atPose3(key)

    def calculateEstimateVector(self, key: int) -> np.ndarray:
        return self.values.atVector(key)

    def calculateEstimateConstantBias(self, key: int) -> gtsam.imuBias.ConstantBias:
        return self.values.atConstantBias(key)
