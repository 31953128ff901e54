"""Self-calibration of the graphs: range and wheel scales, range offset and delay, the sensor profile.

A ranging radio may read long or short by a common factor (the Plaza UWB
ranges read about 6.9 % long: ``reading = scale * distance``). The scale is
estimated from the drive itself, without any truth, by profile likelihood:
for a trial scale ``s`` every range factor is built with ``reading / s`` and
sigma ``sigma / s`` — its whitened residual ``(reading - s d) / sigma`` stays
in reading units, so graph errors at different ``s`` are comparable — the
whole graph is solved by Levenberg–Marquardt (warm-started from the previous
trial), and a bounded Brent search over ``s`` minimises the solved error.
The wheel scale is found the same way (:func:`estimate_wheel_scale`).

Why an outer loop and not a scale variable in the graph: the scale multiplies
every range, which no GTSAM built-in factor expresses; a Python CustomFactor
on every range of a whole-drive graph costs about 1.7 ms per call at 10k
variables (measured, GTSAM_NOTES.md), i.e. minutes per solve, whereas the
outer loop keeps all factors built-in and costs about a dozen warm solves.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import gtsam
import numpy as np
from scipy.optimize import minimize_scalar

from graphpos.graph.config import GraphConfig
from graphpos.graph.models import COMPASS_BIAS_KEY
from graphpos.profile import PLAUSIBLE_LIMITS

#: Tolerance of the scale search (dimensionless).
SCALE_TOLERANCE = 2e-4


#: Step of the range-scale search: the graph is solved at the centre and this far either side.
RANGE_SCALE_STEP = 0.01
#: Centres the range-scale search may try.
RANGE_SCALE_MAX_MOVES = 6
#: Least fall of the solved error (half a chi-square) for a searched parameter to replace the one it was
#: searched against (no range delay; the wheel scale fitted to the wheel deltas): a likelihood-ratio test at
#: 95 % (chi-square(1) 3.84, halved).
LIKELIHOOD_RATIO_MIN_GAIN = 1.92
#: Step of the wheel-scale search (:func:`estimate_wheel_scale`).
WHEEL_SCALE_STEP = 0.01
#: Centres the wheel-scale search may try.
WHEEL_SCALE_MAX_MOVES = 4
#: Farthest the wheel-scale search moves its centre at once (five steps): the ranges' robust loss makes the
#: solved error nearly linear a few percent from its minimum, and a parabola through it points far beyond.
WHEEL_SCALE_MAX_MOVE = 0.05


def estimate_range_scale(builder, initial: gtsam.Values, config: GraphConfig, what: str) -> tuple[float, gtsam.Values]:
    """Scale minimising the solved graph error, and the solution at that scale.

    The solved error is nearly a parabola in the scale: :func:`_profile_minimum`
    finds its vertex in a few solves (warm-started). Where it is not convex
    about a centre, or its vertex reaches a bound, a bounded Brent search
    over ``config.range_scale_bounds`` takes over (alone, it took 14 solves
    on a 10-minute paper drive: a third of graph-batch's CPU, issue 19).
    The scale returned is the best solved.

    Parameters
    ----------
    builder : GraphBuilder
        With its full history (range records and the other factors).
    initial : gtsam.Values
        Starting point of the first solve (the causal pass's estimate).
    """
    lo, hi = config.range_scale_bounds
    at = _Solves(lambda scale: builder.graph(scale), config, lambda scale: f"{what} (range scale {scale:.4f})", digits=9, keep=())
    found = _profile_minimum(at, 1.0, RANGE_SCALE_STEP, (lo, hi), RANGE_SCALE_MAX_MOVES, initial)
    if found is None or not lo < found[0] < hi:
        warm = [initial]

        def solved_error(x: float) -> float:
            err, warm[0] = at(x, warm[0])
            return err

        minimize_scalar(solved_error, bounds=(lo, hi), method="bounded", options={"xatol": SCALE_TOLERANCE})
    builder.diagnostics["range_scale_solves"] = len(at.solved)
    best = at.best()
    return float(best), at.solved[best][1]


def estimate_wheel_scale(builder, initial: gtsam.Values, config: GraphConfig, what: str) -> tuple[float, gtsam.Values]:
    """Wheel scale (``reading = scale * true``) minimising the solved graph error, and the solution at that scale.

    ``initial`` is a solve whose wheel factors allow for a scale error (the
    builder's drift term): the scale fitting the wheel deltas to it
    (:meth:`GraphBuilder.fit_wheel_scale`) is where the search starts.
    That fit alone weighs every keyframe alike, and where nothing but the
    wheel places the track (a U-turn beyond the last tag) the solve follows
    the wheel whatever its scale, so those keyframes pull the fit towards
    no correction: on 300-s realistic drives whose U-turns outside the
    portals see no tag it found 0.990 for a wheel reading 5.9 % short
    (0.941). The solved error, with the wheel factors built at a trial scale
    (readings and sigmas divided by it, so the errors stay comparable), weighs
    only what the ranges and fixes say: its minimum was at 0.943
    (:func:`_profile_minimum`, from the fit; a few warm solves). On Plaza1
    and MRCLAM6, whose tracks see a landmark almost everywhere, the fit and
    the minimum agree within 0.5 %. The fit stays unless the minimum's
    error is lower by a likelihood-ratio test at 95 %
    (:data:`LIKELIHOOD_RATIO_MIN_GAIN`), and where the error is not convex
    in the scale (no range or fix to weigh it): on 150-s pieces of MRCLAM6,
    whose wheels read within 2 % of true, the minimum of so little data
    took the mean RMS from 0.318 to 0.335 m (one piece 0.66 to 0.98 m).
    Sets ``builder.wheel_scale`` (and its diagnostics); the values returned are solved at it.
    """
    lo, hi = config.wheel_scale_bounds
    fitted = round(min(max(builder.fit_wheel_scale(initial), lo), hi), 9)

    def graph_at(scale: float) -> gtsam.NonlinearFactorGraph:
        builder.wheel_scale = scale
        return builder.graph()

    at = _Solves(graph_at, config, lambda scale: f"{what} (wheel scale {scale:.4f})", digits=9, keep=(fitted,))
    found = _profile_minimum(at, fitted, WHEEL_SCALE_STEP, (lo, hi), WHEEL_SCALE_MAX_MOVES, initial, WHEEL_SCALE_MAX_MOVE)
    best = at.best()
    if found is None or at.solved[fitted][0] - at.solved[best][0] < LIKELIHOOD_RATIO_MIN_GAIN:
        best = fitted
    values = at(best, initial)[1]  # held: the best solve's or the fit's
    builder.wheel_scale = best
    builder.diagnostics.update(wheel_scale=best, wheel_scale_solves=len(at.solved))
    return float(best), values


class _Solves:
    """A graph family over one parameter, solved on demand: ``(x, warm) -> (error, values)``, memoised.

    ``graph_at(x)`` builds the graph at ``x`` (rounded to ``digits``),
    solved by Levenberg-Marquardt warm-started from ``warm``; ``what(x)``
    names it in errors. With ``keep`` a tuple, only the best solve's values,
    those at ``keep`` and the latest are held (an hour-long drive's values are
    tens of MB); ``keep=None`` holds every solve's.
    """

    def __init__(self, graph_at, config: GraphConfig, what, digits: int, keep: tuple[float, ...] | None):
        self.graph_at, self.config, self.what, self.digits, self.keep = graph_at, config, what, digits, keep
        self.solved: dict[float, tuple[float, gtsam.Values | None]] = {}

    def __call__(self, x: float, warm: gtsam.Values | None) -> tuple[float, gtsam.Values]:
        from graphpos.graph.estimators import optimise

        x = round(x, self.digits)
        if self.solved.get(x, (0.0, None))[1] is None:
            graph = self.graph_at(x)
            values = optimise(graph, warm, self.config, self.what(x))
            self.solved[x] = (graph.error(values), values)
            if self.keep is not None:
                held = (self.best(), x, *self.keep)
                for y in self.solved:
                    if y not in held:
                        self.solved[y] = (self.solved[y][0], None)
        return self.solved[x]

    def best(self) -> float:
        """The parameter of the least solved error."""
        return min(self.solved, key=lambda y: self.solved[y][0])


def _profile_minimum(at, centre: float, step: float, bounds: tuple[float, float], max_moves: int,
                     warm: gtsam.Values, max_move: float | None = None) -> tuple[float, float, float] | None:
    """The minimum of a solved graph error over one parameter, by successive parabolas (a profile likelihood).

    ``at(x, warm) -> (error, values)`` solves the graph at ``x``
    (warm-started from ``warm``; memoised). The graph is solved at
    ``centre`` and ``step`` either side; the centre moves to the parabola's
    vertex (clipped to ``bounds``, and to ``max_move`` from the centre when
    given: a robust loss makes the error grow only linearly away from its
    minimum, where a parabola's vertex overshoots) until the vertex lies
    within a step of it (or ``max_moves`` centres have been tried), and the
    graph is solved at the vertex. Returns ``(vertex, curvature, centre)`` (the curvature
    of the error at the last centre), or None when the error is not convex
    about a centre.
    """
    lo, hi = bounds
    for move in range(max_moves):
        e0, v0 = at(centre, warm)
        e_lo, e_hi = at(centre - step, v0)[0], at(centre + step, v0)[0]
        curvature = (e_lo - 2 * e0 + e_hi) / step**2
        if not curvature > 0:
            return None
        vertex = centre - step * (e_hi - e_lo) / (2 * (e_lo - 2 * e0 + e_hi))
        if max_move is not None:
            vertex = min(max(vertex, centre - max_move), centre + max_move)
        vertex = float(np.clip(vertex, lo, hi))
        if abs(vertex - centre) <= step or vertex in (lo, hi) or move == max_moves - 1:
            at(vertex, v0)
            return vertex, curvature, centre
        centre, warm = vertex, v0
    return None


#: Step of the range-offset search, m: the graph is solved at the centre and this far either side.
RANGE_OFFSET_STEP_M = 0.05
#: Largest offset correction the search moves to, m.
RANGE_OFFSET_BOUND_M = 0.5
#: Times the search may move its centre before it stops.
RANGE_OFFSET_MAX_MOVES = 4


@dataclass
class RangeOffsetFit:
    """A common range offset found by :func:`estimate_range_offset`.

    ``offset_m``: subtracted from every reading (reading units);
    ``sigma_m``: its standard error from the curvature of the solved error
    (None: the error is not convex in the offset, which the drive does not
    determine, and the offset stays 0); ``values``: the solution at
    ``offset_m``; ``position_per_m``: (keyframes, 2) change of each
    keyframe's east/north position per metre of offset (None with
    ``sigma_m``), for the covariance the offset's uncertainty adds.
    """

    offset_m: float
    sigma_m: float | None
    values: gtsam.Values
    position_per_m: np.ndarray | None


def estimate_range_offset(builder, initial: gtsam.Values, config: GraphConfig, what: str) -> RangeOffsetFit:
    """Offset common to every range that minimises the solved graph error (profile likelihood), and its uncertainty.

    Why not the median residual about a solved track: a camera sees the
    landmarks ahead of it, so ranges that all read long are matched as
    well by a track moved forward; only the odometry, through the turns,
    tells the two apart, and a track solved with the readings absorbs most
    of the offset (MRCLAM6 robot 3: the readings about graph-batch's track
    have median 0.001 m; about the truth, 0.072 m). The solved error ``E``
    (half the chi-square) as a function of the offset weighs both. The
    graph is solved at a centre and :data:`RANGE_OFFSET_STEP_M` either side
    (warm-started), the centre moves to the parabola's vertex until the
    vertex lies within the step, and the graph is solved there. The
    offset's variance is ``1 / E''`` (a Gaussian's profile likelihood);
    the change of each position between the two side solves, per metre,
    lets the caller add that variance to the positions' covariance (the
    offset is estimated, not known).
    """
    h = RANGE_OFFSET_STEP_M
    # every solve's values are held: the side solves about the final centre give the positions' sensitivity
    at = _Solves(lambda offset: builder.graph(offset=offset), config, lambda offset: f"{what} (range offset {offset:+.3f} m)",
                 digits=6, keep=None)
    found = _profile_minimum(at, 0.0, h, (-RANGE_OFFSET_BOUND_M, RANGE_OFFSET_BOUND_M), RANGE_OFFSET_MAX_MOVES, initial)
    builder.diagnostics["range_offset_solves"] = len(at.solved)
    if found is None:
        return RangeOffsetFit(0.0, None, at(0.0, initial)[1], None)
    vertex, curvature, centre = found
    keyframes = range(builder.last_keyframe + 1)
    v_lo, v_hi = at(centre - h, None)[1], at(centre + h, None)[1]
    per_m = (np.array([builder.model.position(v_hi, k) for k in keyframes])
             - np.array([builder.model.position(v_lo, k) for k in keyframes])) / (2 * h)
    return RangeOffsetFit(vertex, 1.0 / math.sqrt(curvature), at(vertex, None)[1], per_m)


#: Step of the tag readings' delay search, s: the graph is solved at the centre and this far either side.
RANGE_DELAY_STEP_S = 0.3
#: Delays the search may move to, s (a reading stamped before it was taken: negative).
RANGE_DELAY_BOUNDS_S = (-0.5, 2.0)
#: Times the search may move its centre before it stops.
RANGE_DELAY_MAX_MOVES = 5


def estimate_range_delay(builder, initial: gtsam.Values, config: GraphConfig, what: str) -> tuple[float, gtsam.Values]:
    """How long after it was taken each tag reading was stamped, by profile likelihood; and the solution there
    (the undelayed solve's when no delay is kept).

    A reader that reports a round of reads as the round ends, or a logger
    that stamps a reading when it receives it, puts every reading some
    fraction of a second after the moment it measured: the vehicle was
    that much farther back. The odometry tells the two apart: with the
    readings moved back by the right delay
    (:meth:`GraphBuilder.delayed_range_records`, to the nearest keyframe)
    the solved error is least. The graph is solved at 0 and
    :data:`RANGE_DELAY_STEP_S` either side and moved to the parabola's
    vertex (:func:`_profile_minimum`). The delay is kept only when its
    error falls below the undelayed one's by :data:`LIKELIHOOD_RATIO_MIN_GAIN`
    (a drive stamped on time, or one that hardly moves, keeps 0), and only
    when the minimum lies inside :data:`RANGE_DELAY_BOUNDS_S`. A reading
    that the delay would move off its track stops at the track's end: every
    search compares the same readings. On the paper profile's straight
    drives (reads stamped 1 s late), seeds 0-2, it finds 0.63-0.88 s and
    graph-batch's RMS goes from 1.48/1.93/1.85 m to 0.45/0.93/0.62 m; on
    Plaza1 and MRCLAM6 robots 1-5 it costs 3-4 solves and moves no RMS by
    more than 2 mm. Not yet on the paper comprehensive drives (seeds 0-1):
    there the final solve's error rises with any delay and 0 is kept,
    though the readings moved back by their true 1 s would take RMS from
    1.78/1.93 m to 0.94/1.09 m (the first solve, fitted to the late
    readings, seems to leave a profile that absorbs part of the lag).
    """
    at = _Solves(lambda delay_s: builder.graph(range_records=builder.delayed_range_records(delay_s)), config,
                 lambda delay_s: f"{what} (tag readings {delay_s:+.2f} s late)", digits=6, keep=(0.0,))
    found = _profile_minimum(at, 0.0, RANGE_DELAY_STEP_S, RANGE_DELAY_BOUNDS_S, RANGE_DELAY_MAX_MOVES, initial)
    builder.diagnostics["range_delay_solves"] = len(at.solved)
    best = at.best()
    if found is None or at.solved[0.0][0] - at.solved[best][0] < LIKELIHOOD_RATIO_MIN_GAIN:
        return 0.0, at.solved[0.0][1]
    if found[0] in RANGE_DELAY_BOUNDS_S or best in RANGE_DELAY_BOUNDS_S:
        # the error falls all the way to a bound: no delay the data locate, but another error the shift absorbs
        # (realistic paper-imm seed 0 without its GNSS approach, a gyro 29 % off: -0.5 s found, RMS 0.11 -> 1.02 m)
        builder.diagnostics["range_delay_at_bound_s"] = float(best)
        return 0.0, at.solved[0.0][1]
    return float(best), at.solved[best][1]


def calibrate_range_scale(drive, config: GraphConfig | None = None, layout: str | None = None):
    """Self-calibrate a range-reporting radio on a drive, without its truth.

    Runs ``graph-batch`` with ``range_scale="estimate"`` and returns a
    :class:`~graphpos.ranging.model.LinearCalibration` with the sensor
    profile's scale and, as its sigma, the robust spread of the readings
    about the smoothed trajectory (:func:`fit_profile`). The online
    estimators then use it as their range model (calibrate once, run
    causally), e.g. ``GraphIsam2(range_model=calibrate_range_scale(drive))``.
    """
    import dataclasses

    from graphpos.graph.estimators import GraphBatch
    from graphpos.ranging.model import LinearCalibration

    config = dataclasses.replace(config or GraphConfig(), range_scale="estimate", output_covariance=False)
    result = GraphBatch(config, layout=layout, range_model=LinearCalibration()).run(drive)
    profile = result.diagnostics.get("profile") or {}
    return LinearCalibration(scale=float(profile.get("range_scale", result.diagnostics.get("range_scale", 1.0))), offset_m=0.0,
                             sigma0_m=max(float(profile.get("range_sigma0_m") or 0.0), 0.05))


#: Odometry is compared with the solved trajectory over windows of this many seconds.
CALIBRATION_WINDOW_S = 2.0
#: Turn (rad, summed |turn| over the windows) below which a turn-rate scale is not fitted.
MIN_TURN_FOR_SCALE_RAD = 6.0
#: Distance driven below which there is nothing to calibrate, m.
MIN_TRAVEL_M = 2.0
#: Limits of the fitted corrections (beyond them the fit is not trusted and clamped).
YAW_RATE_SCALE_BOUNDS = (0.7, 1.4)
GYRO_BIAS_BOUND_RADPS = math.radians(2.0)


def _windows(builder, values, since_keyframe: int = 0) -> dict[str, np.ndarray]:
    """Odometry against the solved trajectory, summed over :data:`CALIBRATION_WINDOW_S` windows.

    Per window: duration ``T``, measured turn (integrated yaw rate) and
    distance (wheel), the solved trajectory's turn and distance, the
    variance the graph's odometry factors give the measured turn
    (``turn_var``), and the keyframes at its ends (``first_k``, ``last_k``).
    Only keyframes after ``since_keyframe`` count.
    """
    model = builder.model
    records = [(k, d) for k, d in builder.odometry_records if k > since_keyframe and values.exists(model.pose_key(k - 1))]
    ks = np.array([k for k, _ in records])
    dur = np.array([d.duration_s for _, d in records])
    turn_m = np.array([d.dtheta_rad for _, d in records])
    turn_var = np.array([d.cov[2, 2] for _, d in records])
    dist_m = np.array([math.hypot(d.dx_m, d.dy_m) for _, d in records])
    yaw = np.unwrap(np.array([model.yaw(values, k) for k in range(int(ks.min()) - 1, int(ks.max()) + 1)]))
    turn_s = yaw[ks - ks.min() + 1] - yaw[ks - ks.min()]
    trans = np.array([model.body_translation(values, k) for k in ks])
    dist_s = np.hypot(trans[:, 0], trans[:, 1])
    per = max(int(round(CALIBRATION_WINDOW_S / max(np.median(dur), 1e-3))), 1)
    idx = np.arange(ks.size) // per
    # a window must be consecutive keyframes (a gap in the records starts a new one)
    idx = idx + np.concatenate(([0], np.cumsum(np.diff(ks) != 1)))
    sums = {name: np.bincount(idx, weights=a) for name, a in
            (("T", dur), ("turn_m", turn_m), ("turn_s", turn_s), ("turn_var", turn_var), ("dist_m", dist_m), ("dist_s", dist_s))}
    last_k = np.zeros(idx[-1] + 1, dtype=np.int64)
    last_k[idx] = ks  # records in time order: each window's last one stays
    first_k = np.zeros_like(last_k)
    first_k[idx[::-1]] = ks[::-1] - 1  # reversed: each window's first one stays
    sums.update(first_k=first_k, last_k=last_k)
    keep = sums["T"] > 0.5 * CALIBRATION_WINDOW_S
    return {k: v[keep] for k, v in sums.items()}


def _huber_lstsq(A: np.ndarray, y: np.ndarray, iterations: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Huber-weighted least squares (k = 1.345 robust sigmas); the solution and the residuals."""
    w = np.ones(y.size)
    x = np.zeros(A.shape[1])
    for _ in range(iterations):
        x, *_ = np.linalg.lstsq(A * w[:, None], y * w, rcond=None)
        r = y - A @ x
        s = 1.4826 * np.median(np.abs(r - np.median(r))) + 1e-12
        u = np.abs(r) / (1.345 * s)
        w = np.sqrt(np.where(u <= 1, 1.0, 1.0 / u))
    return x, y - A @ x


#: Longest horizon of the odometry noise fit, s (windows of CALIBRATION_WINDOW_S, 2x, 4x ... up to it).
NOISE_FIT_MAX_HORIZON_S = 64.0
#: Windows a horizon needs to count in the noise fit.
NOISE_FIT_MIN_WINDOWS = 8


#: Smallest redundancy share a window's turn is given (a turn the ranges see nothing of; numerical guard).
MIN_REDUNDANCY = 0.02
#: Degrees of freedom (:func:`_noise_fit`'s ``dof``) under which a drive does not determine its odometry's
#: noise: the relative standard error of a variance estimated from ``dof`` of them is ``sqrt(2 / dof)``,
#: 100 % at 2. MRCLAM6's whole drives give 4.0-9.6 and Plaza1 42; MRCLAM6's 150 s pieces 0-2.5, 25 of 27
#: under 2 (see :func:`_noise_fit`).
MIN_NOISE_FIT_DOF = 2.0


def _noise_fit(residual: np.ndarray, T: np.ndarray, motion: np.ndarray, redundancy=None) -> tuple[float, float, float]:
    """``E[e^2] = a T + c motion^2 / T`` (white and motion-proportional densities), a and c >= 0, over several horizons.

    ``residual``, ``T`` and ``motion`` are per :data:`CALIBRATION_WINDOW_S`
    window, in time order. The residuals of consecutive windows are summed
    into windows of 2, 4, 8 ... times the length, up to
    :data:`NOISE_FIT_MAX_HORIZON_S` (under the model the variances add:
    ``a sum(T) + c sum(motion^2 / T)``), and one fit is made over every
    horizon, each horizon weighing the same and each window's equation
    relative to its length. Why not the short windows alone: the solved
    trajectory follows the odometry over the seconds the ranges cannot
    resolve, so short windows show only part of the odometry's error (on
    MRCLAM6 the 2-s residuals about the solved track were a third of those
    about the truth, the 30-s ones four fifths), and an error that
    persists (commanded rather than measured turn rates) grows faster
    than a random walk: fitted to 2-s windows alone, the heading noise
    left graph-batch's ANEES at 6-23 there (2 when consistent).

    Squared residuals are heavy-tailed; each horizon's fit keeps those
    under its 95th percentile and the trimmed mean is corrected by a
    chi-square(1) factor.

    Returns ``(a, c, dof)``. ``dof``: the fit's degrees of freedom, the
    largest over the horizons of the summed ``u`` of the windows it keeps
    whose ``u`` is above :data:`MIN_REDUNDANCY` (a window at that floor
    shows too little of its error to say how much less; without
    ``redundancy`` each kept window counts one, the residuals taken for the
    errors, as graph-isam2's online learnings take them). Under
    :data:`MIN_NOISE_FIT_DOF` the drive does not determine the noise: on
    150 s pieces of MRCLAM6 (robot 4 at 15 %, robot 1 at 45 and 60 %:
    dof 0.0-0.3) the fit put the heading noise at 0.001-0.0035
    rad/s/sqrt(s) where the truth shows 0.011-0.038 over 2-64 s (the whole
    drives: dof 4.0-9.6, fitted 0.022-0.067), and graph-batch's ANEES on
    two of them was 24 and 28.

    ``redundancy``: ``(first, last) -> u``, the share of each span's error
    its residual shows (windows ``first`` to ``last``, arrays; see
    :func:`turn_redundancy`). The expected squared residual is then
    ``u (a T + c motion^2 / T)``: variance-component estimation (Helmert's,
    Förstner's) rather than a fit to the residuals as if they were the
    errors. Without it, every ``u`` is 1.
    """
    from scipy.optimize import nnls

    rows, targets = [], []
    dof = 0.0
    span = 1
    while True:
        n = residual.size // span
        if n < NOISE_FIT_MIN_WINDOWS or (span > 1 and span * CALIBRATION_WINDOW_S > NOISE_FIT_MAX_HORIZON_S):
            break
        cut = n * span
        e = residual[:cut].reshape(n, span).sum(1)
        t = T[:cut].reshape(n, span).sum(1)
        m = (motion[:cut] ** 2 / T[:cut]).reshape(n, span).sum(1)
        u = np.ones(n) if redundancy is None else redundancy(np.arange(0, cut, span), np.arange(span - 1, cut, span))
        r2 = e**2
        keep = r2 <= np.quantile(r2, 0.95)
        dof = max(dof, float(u[keep & (u > MIN_REDUNDANCY)].sum()))
        weight = 1.0 / (t[keep] * math.sqrt(keep.sum()))
        rows.append(np.column_stack([t[keep], m[keep]]) * (u[keep] * weight)[:, None])
        targets.append(r2[keep] * weight)
        span *= 2
    coef, _ = nnls(np.concatenate(rows), np.concatenate(targets))
    # a chi-square(1) variable trimmed at its 95th percentile keeps 0.73 of its mean
    return float(coef[0] / 0.73), float(coef[1] / 0.73), dof


def turn_redundancy(builder, values: gtsam.Values, w: dict[str, np.ndarray], scale: float):
    """The ``redundancy`` of :func:`_noise_fit` for the windows ``w`` of a solved graph (:func:`_windows`).

    A span's turn residual (measured less solved) shows the share
    ``u = 1 - posterior / prior`` of its error: ``prior`` the variance the
    odometry factors give the measured turn (over ``scale^2``, the residual's
    correction), ``posterior`` the solved turn's (the two end keyframes' joint
    marginal). Where the ranges hardly see the heading (a camera's narrow view
    ahead, MRCLAM6), the solved track follows the odometry and ``u`` is a few
    per cent: the residuals alone put robot 1's heading noise at a quarter of
    what its truth shows. Raises RuntimeError when GTSAM cannot factorise the graph.
    """
    from graphpos.graph.estimators import MARGINAL_CACHE_KEYS

    marginals = gtsam.Marginals(builder.graph(), values)
    key = builder.model.pose_key
    prior = np.concatenate(([0.0], np.cumsum(w["turn_var"]))) / scale**2
    asked = [0]

    def posterior(k1: int, k2: int) -> float:
        P = marginals.jointMarginalCovariance(gtsam.KeyVector([key(k1), key(k2)])).fullMatrix()
        n = P.shape[0] // 2  # yaw: Pose2 and Pose3 tangent index 2
        asked[0] += 1
        if asked[0] % MARGINAL_CACHE_KEYS == 0:
            marginals.deleteCachedShortcuts()
        return P[2, 2] + P[n + 2, n + 2] - 2.0 * P[2, n + 2]

    def redundancy(first: np.ndarray, last: np.ndarray) -> np.ndarray:
        post = np.array([posterior(int(w["first_k"][i]), int(w["last_k"][j])) for i, j in zip(first, last)])
        return np.clip(1.0 - post / (prior[last + 1] - prior[first]), MIN_REDUNDANCY, 1.0)

    return redundancy


def _turn_correction_fit(w: dict[str, np.ndarray], with_scale: bool, longest_span: bool = True) -> tuple[float, float]:
    """``measured = yaw_rate_scale * solved + gyro_bias * T`` (Huber) over the longest spans the windows allow.

    The windows ``w`` (:func:`_windows`) are summed into sliding spans of
    consecutive ones, as long as :data:`NOISE_FIT_MAX_HORIZON_S` and still
    :data:`NOISE_FIT_MIN_WINDOWS` of them end to end (the noise fit's
    horizons). Why not the 2-s windows: the solved heading follows the
    odometry through a turn and the compass or the ranges pull it back over
    the seconds after, so a short window shows only part of the turn-rate
    error and the fit is drawn towards no correction. On 300-s
    realistic-profile drives (yaw rates up to 29 % off) the 2-s windows found
    1.108 for 1.291 and 1.101 for 1.282; the spans (32 s there) find
    1.255 and 1.248, every one of 12 seeds within 3 % (``python
    benchmarks/realistic_drives.py --seeds 0-11``). Without ``with_scale``
    (too little turning) only the bias. Both are clamped to
    :data:`YAW_RATE_SCALE_BOUNDS` and :data:`GYRO_BIAS_BOUND_RADPS`.

    ``longest_span`` False: the 2-s windows' fit, about which
    :func:`fit_profile` measures the noise levels. Measured about the spans'
    correction, fitted to the very minute-long spans the noise fit reads its
    longest horizons from, they came out smaller (MRCLAM6 robot 1's heading
    noise 0.027 to 0.016 rad/sqrt(s)) and too small for another stretch of
    the drive: a profile from each MRCLAM6 drive's first half, on 150-s
    pieces of its second half, gave graph-isam2 0.242 m and median ANEES
    2.77 against 0.217 m and 2.17 before; with the noise about the windows'
    fit, 0.219 m and 1.90 (``python benchmarks/real_drives.py -e
    graph-isam2 --mrclam-only --halves 150``).
    """
    span = max(int(NOISE_FIT_MAX_HORIZON_S / CALIBRATION_WINDOW_S), 1) if longest_span else 1
    while span > 1 and w["T"].size // span < NOISE_FIT_MIN_WINDOWS:
        span //= 2

    def spans(a: np.ndarray) -> np.ndarray:
        c = np.concatenate(([0.0], np.cumsum(a)))
        return c[span:] - c[:-span]

    T, solved, measured = spans(w["T"]), spans(w["turn_s"]), spans(w["turn_m"])
    if with_scale:
        (scale, bias), _ = _huber_lstsq(np.column_stack([solved, T]), measured)
    else:
        (bias,), _ = _huber_lstsq(T[:, None], measured - solved)
        scale = 1.0
    return float(np.clip(scale, *YAW_RATE_SCALE_BOUNDS)), float(np.clip(bias, -GYRO_BIAS_BOUND_RADPS, GYRO_BIAS_BOUND_RADPS))


def _lag1_correlation(residual: np.ndarray, keys: np.ndarray) -> float:
    """Correlation of consecutive range residuals of the same sighting (landmark key), clipped to [0, 0.9].

    A tag's or beacon's errors repeat from one reading to the next (multipath,
    shadowing at a place): ``n`` readings with lag-1 correlation ``rho`` carry
    the information of about ``n (1 - rho) / (1 + rho)`` independent ones
    (first-order autoregressive errors), so their sigma is inflated by
    ``sqrt((1 + rho) / (1 - rho))``. Residuals beyond 5 robust sigmas
    (outliers) are left out.
    """
    order = np.argsort(keys, kind="stable")  # records are in time order: stable keeps each key's readings in order
    r, k = residual[order], keys[order]
    same = k[1:] == k[:-1]
    a, b = r[:-1][same], r[1:][same]
    scale = 1.4826 * float(np.median(np.abs(residual))) + 1e-12
    ok = (np.abs(a) < 5 * scale) & (np.abs(b) < 5 * scale)
    if ok.sum() < 20:
        return 0.0
    rho = float(np.corrcoef(a[ok], b[ok])[0, 1])
    return float(np.clip(rho if np.isfinite(rho) else 0.0, 0.0, 0.9))


def fit_profile(builder, values: gtsam.Values, config: GraphConfig, drive_name: str, since_keyframe: int = 0,
                redundancy: bool = False):
    """A sensor profile from a solved whole-drive graph (no truth): corrections and noise levels.

    The solved trajectory (from a solve whose odometry allows for these
    errors: ranges and fixes carry it) is compared with the raw odometry
    over :data:`CALIBRATION_WINDOW_S` windows:

    - turn: ``measured = yaw_rate_scale * solved + gyro_bias * T`` by Huber
      regression over spans of windows up to a minute long
      (:func:`_turn_correction_fit`; the scale only when the drive turns
      :data:`MIN_TURN_FOR_SCALE_RAD` in all, else 1);
    - wheel: the builder's fit of the wheel deltas
      (:meth:`GraphBuilder.fit_wheel_scale`) to the solve, whose wheel
      factors graph-batch built at the scale its search found
      (:func:`estimate_wheel_scale`): where only the wheel places the track
      the solve follows that scale (the search's scale itself, taken
      instead, put graph-batch's NEES on 40-s synthetic drives with a true
      wheel below its 95 % band: ANEES 1.74 over 25 seeds, band 1.76-2.26);
    - noise: the corrected odometry's remaining turn errors,
      ``E[e^2] = a T + c (turn)^2 / T`` (:func:`_noise_fit`): the heading
      random walk and the turn-rate scale density left (the density only
      when the drive turns :data:`MIN_TURN_FOR_SCALE_RAD`, as the scale,
      else None: fitted on straight driving it came out anywhere from 0 to
      14 /sqrt(s), and graph-isam2's learnings applied it); with ``redundancy``,
      each residual weighed by the share of the error it can show
      (:func:`turn_redundancy`: one factorisation of the solved graph). The wheel keeps its
      configured scale density: fitted the same way, it came out too small
      on simulated paper drives (mean RMS over 6 seeds 0.439 m against
      0.355 m with the default density);
    - compass: the bias the solve carried as an unknown, where it did
      (``compass_bias``, :meth:`GraphBuilder.graph`);
    - ranges: the range scale found by the profile likelihood search
      (:func:`estimate_range_scale`) or 1 (for RSS, the scale of the RSS
      model's distances); for reported ranges also the offset,
      camera bearing term, sigma and correlation factor of
      :func:`fit_range_terms`.

    The solved trajectory's own jitter adds to the turn residuals, so the noise
    levels err on the large side (a conservative covariance). The odometry
    terms use the keyframes after ``since_keyframe`` (online learning: the
    readings since the last correction, so the result corrects that one;
    its noise levels are pooled with the earlier learnings' by
    :meth:`~graphpos.profile.SensorProfile.combined`).
    """
    from graphpos.profile import SensorProfile

    w = _windows(builder, values, since_keyframe)
    if w["T"].size < 10 or (float(w["dist_s"].sum()) < MIN_TRAVEL_M and float(np.abs(w["turn_s"]).sum()) < 1.0):
        return None  # too little data, or a vehicle that has not moved: nothing to calibrate on
    T = w["T"]
    turned = float(np.abs(w["turn_s"]).sum())
    scale, bias = _turn_correction_fit(w, turned >= MIN_TURN_FOR_SCALE_RAD)
    # the noise about the windows' correction (see _turn_correction_fit), each residual's share by that correction
    window_scale, window_bias = _turn_correction_fit(w, turned >= MIN_TURN_FOR_SCALE_RAD, longest_span=False)
    shares = None
    if redundancy:
        try:
            shares = turn_redundancy(builder, values, w, window_scale)
        except RuntimeError:
            shares = None  # not factorisable: the plain fit
    heading_var, turn_var, dof = _noise_fit((w["turn_m"] - window_bias * T) / window_scale - w["turn_s"], T, w["turn_s"], shares)
    wheel_scale = 1.0
    if builder.odometry.has_speed:
        lo, hi = config.wheel_scale_bounds
        wheel_scale = float(np.clip(builder.fit_wheel_scale(values, since_keyframe), lo, hi))
    gyro_density = config.gyro_sigma_radps / math.sqrt(config.imu_rate_hz)
    fields = dict(
        gyro_bias_radps=bias,
        yaw_rate_scale=scale,
        wheel_scale=wheel_scale,
        heading_noise_radps_per_sqrt_s=max(math.sqrt(heading_var), gyro_density),
        # a drive that turned too little for a scale does not determine its density either (None: left as it was)
        turn_scale_density_per_sqrt_s=math.sqrt(turn_var) if turned >= MIN_TURN_FOR_SCALE_RAD else None,
    )
    fields.update(fit_range_terms(builder, values) or {})
    if builder.has_tag_ranges and not builder.reports_ranges:
        fields["range_scale"] = float(builder.range_scale)  # an RSS model's distances: the scale search's (no other range term)
    if builder.compass_bias_sigma_rad is not None and values.exists(COMPASS_BIAS_KEY):
        lo, hi = PLAUSIBLE_LIMITS["compass_bias_rad"]
        fields["compass_bias_rad"] = float(np.clip(builder.model.compass_bias(values), lo, hi))
    return SensorProfile(**fields, source={"drive": drive_name, "estimator": "graph-batch", "windows": int(T.size), "noise_dof": dof,
                                           "turned_rad": turned})


def implausible_calibration(exc, drive_name: str) -> str:
    """What to tell a user whose drive self-calibrated to a correction no sensor has (``exc``: an
    :class:`~graphpos.profile.ImplausibleProfileError`).

    The profile's plausibility check said only ``sensor profile: range_offset_m = -25.05 is outside the
    plausible range``, to a user who had given no profile, when a wheel logged in km/h (read as m/s) or
    ranges in cm made the ranges and the odometry disagree beyond any calibration.
    """
    return (f"self-calibration on '{drive_name}' found {exc.name} = {exc.value:.4g}, outside the plausible "
            f"[{exc.limits[0]:g}, {exc.limits[1]:g}]: the drive's ranges, odometry and compass disagree beyond any calibration, "
            f"most often a unit (wheel speed in km/h, ranges in cm, a rate in deg/s; set it in the import mapping); "
            f"`graphpos info` compares each sensor with the truth when the drive has one")


def undetermined_noise_warning(profile) -> str | None:
    """What to tell a user whose drive did not determine its odometry's noise (:data:`MIN_NOISE_FIT_DOF`), or None.

    The fit's degrees of freedom (``source["noise_dof"]``) count the turn
    errors the absolute readings (ranges, fixes, compass) could show. A
    short drive shows almost none, and the noise fitted from it is a guess
    (:func:`_noise_fit`): on 150 s pieces of MRCLAM6 5-25 times under what
    the truth shows (ANEES up to 28); on the simulator's 76 s paper-straight
    drives (dof 0) 0.005-0.007, with ANEES
    0.9-1.1 on the ideal and realistic profiles and 5.1 on the paper one
    (seed 3).
    """
    dof = profile.source.get("noise_dof")
    if dof is None or dof >= MIN_NOISE_FIT_DOF or profile.heading_noise_radps_per_sqrt_s is None:
        return None
    return (f"the drive does not determine its odometry's heading noise ({dof:.1f} of the {MIN_NOISE_FIT_DOF:g} degrees of "
            f"freedom needed: its ranges, fixes and compass show too little of the heading's errors), so the covariances "
            f"rest on a guess of {profile.heading_noise_radps_per_sqrt_s:.4f} rad/s/sqrt(s); a profile calibrated on a "
            f"longer drive of these sensors (graphpos calibrate, then --profile) settles it")


#: Readings with a bearing needed to fit the bearing term, and the spread of bearing^2 (rad^2) it needs.
MIN_BEARING_READINGS = 200
MIN_BEARING2_SPREAD_RAD2 = 0.01
#: Residuals beyond this are left out of the bearing fit (outliers, wrong landmark), m.
BEARING_FIT_MAX_RESIDUAL_M = 1.0


def fit_bearing_term(residual: np.ndarray, bearing: np.ndarray) -> tuple[float, float, float] | None:
    """Offset, bearing^2 coefficient and sigma of a camera's range residuals (no truth).

    A range measured from a landmark's image reads off by an amount that
    grows with the landmark's bearing in the image (MRCLAM's camera:
    ``reading = range_scale * d + c0 + c2 * bearing^2``, c2 -1.0 to -1.7
    m/rad^2 on Dataset 6's robots, :mod:`graphpos.io.mrclam`). The
    residuals ``reading - range_scale * d`` of the readings that carry a
    bearing (NaN: none) are fitted by ``[c0, c2]`` Huber regression, those
    beyond :data:`BEARING_FIT_MAX_RESIDUAL_M` of the median left out.
    Returns ``(c0, c2, sigma)`` in reading units, or None with too few such
    readings, or bearings too alike to tell the term from the offset.
    """
    has = np.isfinite(bearing) & np.isfinite(residual)
    if has.sum() < MIN_BEARING_READINGS:
        return None
    r, b = residual[has], bearing[has]
    ok = np.abs(r - np.median(r)) < BEARING_FIT_MAX_RESIDUAL_M
    if ok.sum() < MIN_BEARING_READINGS or float(np.std(b[ok] ** 2)) < MIN_BEARING2_SPREAD_RAD2:
        return None
    (c0, c2), left = _huber_lstsq(np.column_stack([np.ones(ok.sum()), b[ok] ** 2]), r[ok])
    return float(c0), float(c2), 1.4826 * float(np.median(np.abs(left - np.median(left))))


def fit_range_terms(builder, values: gtsam.Values) -> dict[str, float] | None:
    """The range fields of a sensor profile, from the reported ranges about a solved graph (no truth); None without them.

    Each recorded reading (less the builder's :attr:`~GraphBuilder.range_offset_m`)
    is compared with ``range_scale`` times the distance from its keyframe's
    solved position: the camera's bearing term where the readings carry
    bearings (:func:`fit_bearing_term`), else an offset (the median
    residual); a sigma (1.4826 x MAD of what is left, in metres); and the
    factor on it for errors that repeat from one reading of a landmark to
    the next (:func:`_lag1_correlation`). Offset and bearing coefficient are
    in the recorded readings' units: on readings already corrected, they
    correct them further.
    """
    records = builder.range_records
    if not records or not builder.reports_ranges:
        return None
    reading = np.array([r.reading_m for r in records])
    pos = np.array([builder.model.position(values, r.keyframe) for r in records])
    marks = np.array([builder.landmark_positions[r.landmark_key] for r in records])
    bearing = np.array([r.bearing_rad for r in records])
    res = reading - builder.range_offset_m - builder.range_scale * np.hypot(*(pos - marks).T)
    term = fit_bearing_term(res, bearing)
    c0, c2 = (term[0], term[1]) if term is not None else (float(np.median(res)), 0.0)
    left = res - c0 - c2 * np.where(np.isfinite(bearing), bearing, 0.0) ** 2
    sigma = 1.4826 * float(np.median(np.abs(left - np.median(left)))) / builder.range_scale
    rho = _lag1_correlation(left, np.array([r.landmark_key for r in records]))
    return dict(range_scale=float(builder.range_scale), range_offset_m=c0, range_bearing2_m_per_rad2=c2, range_sigma0_m=max(sigma, 0.02),
                range_sigma_slope=0.0, range_sigma_scale=float(math.sqrt((1 + rho) / (1 - rho))))
