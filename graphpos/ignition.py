"""Start-up ("ignition"): the first state of every estimator, from the sensors or the user, never the truth.

Filters and factor graphs share this one piece (issue 13). An estimator
feeds it every measurement until it returns a :class:`StartState`; until
then the estimator has not started and outputs nothing. The sources, in
order:

(a) a start pose the user gives (:class:`StartPose`: ``--initial-pose`` on
    the command line, or ``params["initial_pose"]`` stored in the drive):
    ready at the first wheel speed, which gives the start speed (a start
    at rest when the wheel read, say, 2 m/s cost fusion-ekf 0.25 -> 0.36 m
    RMS on a 30 s drive), or at the first measurement on a drive without a
    wheel (the speed unknown);
(b) position fixes (``gnss`` rows, ``rsu`` rows that carry a position);
(c) ranges to tags or RSUs at known positions.

(b) and (c) are solved together, with the compass where the drive has one,
by robust least squares over the last :attr:`IgnitionConfig.window_s`
seconds. The unknowns are the pose now (east, north, yaw) and, where the
readings determine it, the ranges' common scale (a nuisance with a prior at
1: uncalibrated ranging is often several per cent long,
:attr:`IgnitionConfig.range_scale_sigma`); every earlier reading is placed relative to it by dead reckoning (wheel speed and yaw
rate, held between samples), whose error is allowed to grow with the
distance driven since the reading. Without a compass the heading comes from
the direction of travel, so it waits until the vehicle has moved
:attr:`IgnitionConfig.min_travel_m`. Several starts (around the latest
reading's landmark, at several headings) are solved; the start is accepted
when the best solution is well determined (position and yaw sigmas under
the configured limits) and no distinct rival fits almost as well. Ranges to
tags on one wall along a straight road fit the vehicle and its mirror image
across the wall equally well; a rival behind a wall (outside the band
between the left-wall and right-wall tags, :func:`between_walls`) is
dropped explicitly, and any ambiguity that remains makes ignition wait.
Readings that cannot determine the start whatever their values (fewer
constraints than unknowns; ranges to one landmark only, with no compass or
fix for the heading: the track can turn about it) are not solved at all, so
waiting costs nothing on a drive that never starts.

The papers start every filter from DGPS before the tunnel (song2016 §6):
the simulated paper scenarios carry a short DGPS-grade ``gnss`` channel on
the approach, which is source (b).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import least_squares
from scipy.stats import chi2

from graphpos.errors import ConfigError, is_finite_number


@dataclass(frozen=True)
class StartPose:
    """A start pose given by the user, with its 1-sigmas.

    Parameters
    ----------
    east_m, north_m : float
        Position in the drive's local frame.
    yaw_rad : float
        Yaw from east, counter-clockwise.
    position_sigma_m, yaw_sigma_rad : float
        1-sigmas (default 1 m and 5 degrees).
    """

    east_m: float
    north_m: float
    yaw_rad: float
    position_sigma_m: float = 1.0
    yaw_sigma_rad: float = math.radians(5.0)

    def __post_init__(self) -> None:
        values = self.to_dict()
        if not all(is_finite_number(v) for v in values.values()):
            raise ConfigError("initial pose needs finite numbers, got " + ", ".join(f"{k} = {v!r}" for k, v in values.items()))
        if abs(self.east_m) > 1e7 or abs(self.north_m) > 1e7:
            raise ConfigError(f"initial pose ({self.east_m:g}, {self.north_m:g}) m is not a plausible local position")
        if not (self.position_sigma_m > 0 and self.yaw_sigma_rad > 0):
            raise ConfigError("initial pose sigmas must be positive")

    @classmethod
    def parse(cls, text: str) -> "StartPose":
        """``E,N,YAW_DEG[,SIGMA_M[,SIGMA_YAW_DEG]]`` (metres and degrees) as typed on the command line."""
        try:
            values = [float(v) for v in text.split(",")]
        except ValueError:
            values = []
        if len(values) not in (3, 4, 5) or not all(math.isfinite(v) for v in values):
            raise ConfigError(f"initial pose must be E,N,YAW_DEG[,SIGMA_M[,SIGMA_YAW_DEG]], finite numbers, got '{text}'")
        e, n, yaw_deg = values[:3]
        sigma_m = values[3] if len(values) > 3 else 1.0
        sigma_yaw_deg = values[4] if len(values) > 4 else 5.0
        return cls(e, n, math.radians(yaw_deg), sigma_m, math.radians(sigma_yaw_deg))

    @classmethod
    def from_params(cls, params: dict[str, Any]) -> "StartPose | None":
        """The pose stored in a drive's ``params["initial_pose"]`` (keys as the fields), or None."""
        stored = params.get("initial_pose")
        if stored is None:
            return None
        if not isinstance(stored, dict) or not {"east_m", "north_m", "yaw_rad"} <= set(stored):
            raise ConfigError("the drive's params.initial_pose needs east_m, north_m and yaw_rad")
        known = {f: stored[f] for f in ("east_m", "north_m", "yaw_rad", "position_sigma_m", "yaw_sigma_rad") if f in stored}
        return cls(**known)

    def to_dict(self) -> dict[str, float]:
        return {"east_m": self.east_m, "north_m": self.north_m, "yaw_rad": self.yaw_rad,
                "position_sigma_m": self.position_sigma_m, "yaw_sigma_rad": self.yaw_sigma_rad}


@dataclass(frozen=True)
class StartState:
    """What ignition gives an estimator: its state at ``t_s`` and the 1-sigmas.

    ``source`` is ``user``, ``fix`` (GNSS/RSU fixes, with the compass or the
    fix track for heading) or ``ranges``. ``range_scale``: the ranges'
    common scale solved with the start when significant, else 1 (the
    filters divide their ranges by it from their start on,
    :mod:`filters.base`; the graphs calibrate the ranges themselves).
    """

    t_s: float
    east_m: float
    north_m: float
    yaw_rad: float
    speed_mps: float
    position_sigma_m: float
    yaw_sigma_rad: float
    speed_sigma_mps: float
    source: str
    range_scale: float = 1.0

    @property
    def v_east_mps(self) -> float:
        return self.speed_mps * math.cos(self.yaw_rad)

    @property
    def v_north_mps(self) -> float:
        return self.speed_mps * math.sin(self.yaw_rad)

    def describe(self) -> dict[str, Any]:
        """JSON-serialisable summary for diagnostics."""
        return {"source": self.source, "t_s": self.t_s, "east_m": self.east_m, "north_m": self.north_m,
                "yaw_rad": self.yaw_rad, "position_sigma_m": self.position_sigma_m, "yaw_sigma_rad": self.yaw_sigma_rad,
                "range_scale": self.range_scale}


@dataclass
class IgnitionConfig:
    """Tunables of start-up (shared by every estimator).

    Attributes
    ----------
    window_s : float
        Absolute readings used together, s (the last ones).
    min_travel_m : float
        Without a compass, distance driven within the window before the
        heading is taken from the direction of travel.
    max_position_sigma_m, max_yaw_sigma_rad : float
        The solution's 1-sigmas must be under these to start.
    dr_error_per_m : float
        Dead-reckoning error per metre driven between a reading and now
        (wheel scale and heading errors of uncalibrated sensors: 5 %).
    dr_turn_error : float
        Heading error per radian turned between a reading and now (a
        turn-rate scale error: MRCLAM's odometry turn rates are several per
        cent off; 10 %), which moves the reading's place by that angle times
        its distance from now.
    compass_sigma_rad : float
        Compass 1-sigma used here (loose: a start must survive a disturbed compass).
    ambiguity_m, ambiguity_yaw_rad : float
        Two solutions farther apart than either are distinct.
    chi2_margin : float
        The best solution's chi-square must beat every distinct rival's by this.
    solve_every_s : float
        Minimum time between two attempts.
    speed_sigma_mps : float
        1-sigma of the start speed taken from the wheel.
    range_scale_sigma : float
        1-sigma of the prior (1) on the ranges' unknown common scale, solved
        with the pose within 3 sigmas of 1 and kept when significant
        (:data:`RANGE_SCALE_SIGNIFICANCE`; 0: taken as exact). Ranging
        without a calibration is often several per cent long (Plaza1's UWB
        ranges 7 %, the ``realistic`` profile 5-8 %); read as exact, 60 m
        ranges place the start metres off with a sigma that hides it
        (Plaza1: 4.1 m off, sigma 0.77 m).
    """

    window_s: float = 60.0
    min_travel_m: float = 1.0
    max_position_sigma_m: float = 1.5
    max_yaw_sigma_rad: float = math.radians(10.0)
    dr_error_per_m: float = 0.05
    dr_turn_error: float = 0.1
    compass_sigma_rad: float = math.radians(5.0)
    ambiguity_m: float = 2.0
    ambiguity_yaw_rad: float = math.radians(30.0)
    chi2_margin: float = 9.0
    solve_every_s: float = 1.0
    speed_sigma_mps: float = 0.3
    range_scale_sigma: float = 0.1


#: Speed 1-sigma when the drive has no wheel speed, m/s.
UNKNOWN_SPEED_SIGMA_MPS = 5.0
#: Longest odometry silence (wheel speed, yaw rate) an estimator holds its last sample over, s; a longer one ends
#: its track, which starts again from a fresh ignition (filters, and the graphs' default ``max_odometry_gap_s``).
#: MRCLAM's odometry pauses for up to 1.03 s.
MAX_ODOMETRY_GAP_S = 2.0
#: What an estimator's diagnostics say (``not_started``) when it never started.
NOT_STARTED = "no start state: give --initial-pose, or a drive with fixes or ranges while moving"
#: Without dead reckoning, readings this close to the latest one are solved together, s, if they agree
#: (else the latest epoch's alone: :data:`_MIXED_PLACES`).
NO_DR_WINDOW_S = 1.0
#: Readings this close in time belong to one epoch (one scan), s.
SAME_EPOCH_S = 0.05
#: What :meth:`Ignition._solve` gives when readings of several epochs, which no dead reckoning relates, disagree.
_MIXED_PLACES = object()
#: Number of trial headings and trial positions per heading of the multi-start solve.
_HEADING_STARTS = 8
_POSITION_STARTS = 6
#: Ignition's start has the ranges' common scale solved for when it is off 1 by more than this many of its sigmas.
RANGE_SCALE_SIGNIFICANCE = 2.0
#: Residual (in sigmas) where ignition's soft-L1 loss turns from quadratic to linear.
_ROBUST_SCALE = 2.0
#: Two local minima of the multi-start closer than these are one (m, rad).
_SAME_MINIMUM_M, _SAME_MINIMUM_RAD = 1e-3, 1e-4


def _soft_l1(F: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """scipy's soft-L1 loss at residuals F: the cost per candidate, and F and the scale of its Jacobian rows for Gauss-Newton.

    The same loss, cost and scaling as ``least_squares(loss="soft_l1",
    f_scale=_ROBUST_SCALE)`` (scipy's ``scale_for_robust_loss_function``).
    """
    z = (F / _ROBUST_SCALE) ** 2
    cost = _ROBUST_SCALE**2 * np.sum(np.sqrt(1.0 + z) - 1.0, axis=-1)
    rho1 = (1.0 + z) ** -0.5
    J_scale = np.sqrt(np.maximum(rho1 - (1.0 + z) ** -1.5 * z, np.finfo(float).eps))
    return cost, F * rho1 / J_scale, J_scale


def _distinct_minima(residuals, starts: np.ndarray, has_yaw: bool, iterations: int = 60) -> list[tuple[np.ndarray, float]]:
    """The distinct local minima of ignition's robust cost reached from ``starts`` and their costs, best first.

    A Levenberg-Marquardt descent of every start at once (numpy-batched:
    one least-squares call per start spent most of a real drive's CPU in
    scipy's per-call overhead while ignition waited: 48 starts, once a
    second, for minutes on MRCLAM), to a loose tolerance. Starts that reach
    the same minimum are merged; the caller refines each distinct one with
    ``least_squares``, whose result it uses.

    Parameters
    ----------
    residuals : callable
        ``X (S, p) -> (F (S, N), J (S, N, p))``, whitened.
    starts : ndarray, shape (S, p)
        East, north, then yaw when ``has_yaw``, then any other unknowns.
    """
    X = np.array(starts, dtype=float)
    F, J = residuals(X)
    cost, Fs, scale = _soft_l1(F)
    damping = np.full(len(X), 1e-3)
    moving = np.ones(len(X), dtype=bool)
    for _ in range(iterations):
        if not moving.any():
            break
        Js = J[moving] * scale[moving][..., None]
        H = np.einsum("snp,snq->spq", Js, Js)
        g = np.einsum("snp,sn->sp", Js, Fs[moving])
        diag = np.einsum("spp->sp", H)
        A = H + (damping[moving][:, None] * (diag + 1e-9))[..., None] * np.eye(X.shape[1])
        try:
            step = -np.linalg.solve(A, g[..., None])[..., 0]
        except np.linalg.LinAlgError:
            break
        idx = np.flatnonzero(moving)
        X_new = X[idx] + step
        F_new, J_new = residuals(X_new)
        cost_new, Fs_new, scale_new = _soft_l1(F_new)
        better = np.isfinite(cost_new) & (cost_new < cost[idx])
        take = idx[better]
        X[take], F[take], J[take], cost[take], Fs[take], scale[take] = X_new[better], F_new[better], J_new[better], cost_new[better], Fs_new[better], scale_new[better]
        damping[take] = np.maximum(damping[take] / 10.0, 1e-9)
        damping[idx[~better]] *= 10.0
        small = np.max(np.abs(step), axis=1) < 1e-6 * (1.0 + np.max(np.abs(X[idx]), axis=1))
        moving[idx[(better & small) | (damping[idx] > 1e8)]] = False
    minima: list[tuple[np.ndarray, float]] = []
    for i in np.argsort(cost):
        if not np.all(np.isfinite(X[i])):
            continue
        if not any(np.hypot(*(X[i, :2] - m[:2])) < _SAME_MINIMUM_M and (not has_yaw or abs(math.remainder(X[i, 2] - m[2], 2 * math.pi)) < _SAME_MINIMUM_RAD)
                   for m, _ in minima):
            minima.append((X[i], float(cost[i])))
    return minima


def between_walls(position_en_m: np.ndarray, tags_en_m: np.ndarray, wall_side: np.ndarray) -> bool:
    """False when a position lies behind a wall: a mirror image of the track across it.

    Each wall is the line through its two tags nearest the position (the
    wall's local direction, whatever the other wall's tags do: pairs,
    staggered, groups); the road is on the side of it where the other
    wall's nearest tag is. A position on the far side by more than a quarter
    of that tag's distance from the line (a quarter of the width) is behind
    the wall. A wall with one tag is the line through it square to the
    other wall's nearest tag. The lines run on past the walls' ends, so a
    position on the approach road before the first tags is on the road.
    A map without tags on both walls says nothing (True).
    """
    p = np.asarray(position_en_m, dtype=float)
    tags = np.asarray(tags_en_m, dtype=float).reshape(-1, 2)
    left, right = tags[wall_side > 0], tags[wall_side < 0]
    if not (left.size and right.size):
        return True
    for wall, other in ((left, right), (right, left)):
        a = wall[np.argsort(np.hypot(*(wall - p).T))[:2]]
        road = other[np.argmin(np.hypot(*(other - p).T))]
        along = a[1] - a[0] if len(a) == 2 else np.zeros(2)
        if not np.hypot(*along) > 1e-9:
            across = road - a[0]
            along = np.array([-across[1], across[0]])
        normal = np.array([-along[1], along[0]]) / max(float(np.hypot(*along)), 1e-12)
        road_side = float(np.dot(road - a[0], normal))
        if float(np.dot(p - a[0], normal)) * math.copysign(1.0, road_side) < -0.25 * abs(road_side):
            return False
    return True


def rival_gap(best: tuple[float, float, float, float], others, config: IgnitionConfig) -> float | None:
    """How much worse than ``best`` a distinct solution fits, if one fits almost as well (else None): the start is ambiguous.

    Solutions are ``(east_m, north_m, yaw_rad, cost)``, ``cost`` half the
    chi-square. Distinct: farther than ``config.ambiguity_m`` or turned by
    more than ``config.ambiguity_yaw_rad``; almost as well: within
    ``config.chi2_margin / 2`` of the best cost. Shared by ignition and the
    graph's own start (:meth:`graphpos.graph.builder.GraphBuilder._start_from_graph`).
    """
    e, n, yaw, cost = best
    for oe, on, oyaw, ocost in others:
        distinct = math.hypot(oe - e, on - n) > config.ambiguity_m or abs(math.remainder(oyaw - yaw, 2 * math.pi)) > config.ambiguity_yaw_rad
        if distinct and ocost - cost < config.chi2_margin / 2:
            return float(ocost - cost)
    return None


def _can_determine(ranges: np.ndarray, fixes: np.ndarray, heading_from_compass: bool, free_heading: bool) -> bool:
    """False when the readings cannot determine the start whatever their values (no solve needed).

    The solve's information matrix is singular, and ignition would wait
    after a costly multi-start solve, when (1) there are fewer scalar
    constraints than unknowns (a range gives one, a fix two, the compass one
    however many readings: they all bear on the same yaw), or (2) every
    reading is a range to one landmark and nothing gives the heading:
    turning the whole track about that landmark changes no range.
    """
    unknowns = 2 if free_heading else 3
    if len(ranges) + 2 * len(fixes) + (1 if heading_from_compass else 0) < unknowns:
        return False
    one_landmark = len(ranges) and np.ptp(ranges[:, 1]) == 0 and np.ptp(ranges[:, 2]) == 0
    return not (one_landmark and not len(fixes) and not heading_from_compass)


class Ignition:
    """Collects measurements until it can give a :class:`StartState` (see the module docstring).

    Parameters
    ----------
    tags_en_m, wall_side : arrays
        The tag map (positions and wall sides) for :func:`between_walls`.
    user : StartPose or None
        A given start pose (source (a)).
    has_wheel : bool
        Whether wheel speeds will come. Without them there is no dead
        reckoning: the start speed is unknown, only the readings of the last
        :data:`NO_DR_WINDOW_S` are solved together (those of the latest
        epoch alone when they disagree: taken at places nothing relates),
        and the heading comes from the compass or is left unknown (yaw 0
        with a sigma of pi).
        With them, dead reckoning starts at the first wheel speed: readings
        taken before it are not used (they could not be placed: the
        vehicle's motion until then is unknown, not a standstill).
    config : IgnitionConfig
    """

    def __init__(self, tags_en_m: np.ndarray | None = None, wall_side: np.ndarray | None = None, user: StartPose | None = None,
                 has_wheel: bool = True, config: IgnitionConfig | None = None):
        self.config = config or IgnitionConfig()
        self.user = user
        self.has_wheel = has_wheel
        self._tags = np.zeros((0, 2)) if tags_en_m is None else np.asarray(tags_en_m, dtype=float).reshape(-1, 2)
        self._walls = np.zeros(0) if wall_side is None else np.asarray(wall_side)
        self.state: StartState | None = None
        self.attempts = 0
        #: Why the last solve gave no start (None: none refused yet); see :meth:`not_started`.
        self.refused: str | None = None
        # dead reckoning in the start frame: time, east, north, yaw, distance driven, angle turned
        self._t: float | None = None
        self._pose = np.zeros(5)  # x, y, theta, path length, |turn|
        self._speed = 0.0
        self._yaw_rate = 0.0
        self._track: deque[tuple[float, float, float, float, float, float]] = deque()
        # absolute readings: (t_s, kind, payload)
        self._ranges: list[tuple[float, float, float, float, float]] = []  # t, mark_e, mark_n, range, sigma
        self._fixes: list[tuple[float, float, float, float]] = []  # t, e, n, sigma
        self._compass: list[tuple[float, float]] = []  # t, yaw
        self._last_try = -math.inf
        self._new = False
        # with a wheel, dead reckoning starts at its first sample: earlier
        # readings cannot be placed (the track before it would be a standstill)
        self._dr_from: float | None = None if has_wheel else -math.inf

    @property
    def started(self) -> bool:
        return self.state is not None

    def not_started(self) -> str:
        """What an estimator that never started says: :data:`NOT_STARTED`, and why the last attempt gave no start."""
        return NOT_STARTED if self.refused is None else f"{NOT_STARTED} (the last attempt: {self.refused})"

    # -- input ------------------------------------------------------------------
    def _advance(self, t_s: float) -> None:
        if self._t is None:
            self._t = t_s
            self._track.append((t_s, 0.0, 0.0, 0.0, 0.0, 0.0))
            if self.user is not None and not self.has_wheel:
                self._start_from_user(t_s)
            return
        dt = t_s - self._t
        if dt <= 0:
            return
        x, y, th, s, turned = self._pose
        x += self._speed * dt * math.cos(th)
        y += self._speed * dt * math.sin(th)
        s += abs(self._speed) * dt
        th += self._yaw_rate * dt
        turned += abs(self._yaw_rate) * dt
        self._pose = np.array([x, y, th, s, turned])
        self._t = t_s
        self._track.append((t_s, x, y, th, s, turned))
        horizon = t_s - self.config.window_s - 5.0
        if len(self._track) > 2048:  # drop the points older than the window from the left: O(1) a sample
            while self._track[0][0] < horizon:
                self._track.popleft()

    def at(self, t_s: float) -> StartState | None:
        """Advance to ``t_s`` without a reading (with a user pose: the start state, at the speed last read)."""
        self._advance(t_s)
        if self.user is not None and self.state is None:
            self._start_from_user(t_s)
        return self.state

    def speed(self, t_s: float, speed_mps: float) -> StartState | None:
        self._advance(t_s)
        self._speed = float(speed_mps)
        if self._dr_from is None:
            self._dr_from = float(t_s)
        if self.user is not None and self.state is None:
            self._start_from_user(t_s)
        return self.state

    def yaw_rate(self, t_s: float, yaw_rate_radps: float) -> StartState | None:
        self._advance(t_s)
        self._yaw_rate = float(yaw_rate_radps)
        return self.state

    def compass(self, t_s: float, yaw_rad: float) -> StartState | None:
        self._advance(t_s)
        self._compass.append((float(t_s), float(yaw_rad)))
        self._new = True
        return self._try()

    def fix(self, t_s: float, east_m: float, north_m: float, sigma_m: float) -> StartState | None:
        self._advance(t_s)
        self._fixes.append((float(t_s), float(east_m), float(north_m), float(sigma_m)))
        self._new = True
        self._last_try = -math.inf  # a fix is strong information: try at once
        return self._try()

    def ranges(self, t_s: float, marks_en_m: np.ndarray, ranges_m: np.ndarray, sigmas_m: np.ndarray) -> StartState | None:
        """Ranges taken at ``t_s`` to landmarks at ``marks_en_m`` (N, 2)."""
        self._advance(t_s)
        marks = np.asarray(marks_en_m, dtype=float).reshape(-1, 2)
        for (e, n), r, s in zip(marks, np.asarray(ranges_m, dtype=float), np.asarray(sigmas_m, dtype=float)):
            if math.isfinite(r) and math.isfinite(s) and s > 0:
                self._ranges.append((float(t_s), float(e), float(n), float(r), float(s)))
                self._new = True
        return self._try()

    def finish(self) -> StartState | None:
        """A last attempt at the end of the drive (whatever the solve period)."""
        if self.state is None and self._new:
            self._last_try = -math.inf
            return self._try()
        return self.state

    # -- solving ----------------------------------------------------------------
    def _start_from_user(self, t_s: float) -> None:
        u = self.user
        self.state = StartState(t_s, u.east_m, u.north_m, u.yaw_rad, self._speed, u.position_sigma_m, u.yaw_sigma_rad,
                                self.config.speed_sigma_mps if self.has_wheel else UNKNOWN_SPEED_SIGMA_MPS, "user")

    def _dr_at(self, t_s: np.ndarray) -> np.ndarray:
        """Dead-reckoned (x, y, theta, path, angle turned) at times (clamped to the track)."""
        tr = np.asarray(self._track)
        return np.column_stack([np.interp(t_s, tr[:, 0], tr[:, i]) for i in range(1, 6)])

    def _try(self) -> StartState | None:
        if self.state is not None:
            return self.state
        c = self.config
        now = self._t
        if not self._new or now - self._last_try < c.solve_every_s or not (self._fixes or self._ranges):
            return None
        if self._dr_from is None:
            return None  # the wheel has not spoken yet: no dead reckoning to place readings with, no start speed
        self._last_try = now
        self._new = False
        lo = max(now - (c.window_s if self.has_wheel else NO_DR_WINDOW_S), self._dr_from)
        ranges = np.array([r for r in self._ranges if r[0] >= lo]).reshape(-1, 5)
        fixes = np.array([f for f in self._fixes if f[0] >= lo]).reshape(-1, 4)
        compass = np.array([y for y in self._compass if y[0] >= lo]).reshape(-1, 2)
        self._ranges = [tuple(r) for r in ranges]
        self._fixes = [tuple(f) for f in fixes]
        self._compass = [tuple(y) for y in compass]
        if not (len(fixes) or len(ranges)):
            return None
        self.attempts += 1
        solution = self._solve(ranges, fixes, compass, check_consistency=not self.has_wheel)
        if solution is _MIXED_PLACES:
            # no dead reckoning relates the window's readings and they disagree: the vehicle moved between them
            # (on the long-tunnel drive, 22 m between two 1 Hz scans); the latest epoch's alone
            latest = max(a[:, 0].max() for a in (ranges, fixes) if len(a)) - SAME_EPOCH_S
            ranges, fixes, compass = (a[a[:, 0] >= latest] for a in (ranges, fixes, compass))
            solution = self._solve(ranges, fixes, compass)
        if solution is None:
            return None
        e, n, yaw, sigma_p, sigma_yaw, source, range_scale = solution
        speed = self._speed if self.has_wheel else 0.0
        self.state = StartState(now, e, n, yaw, speed, sigma_p, sigma_yaw,
                                c.speed_sigma_mps if self.has_wheel else UNKNOWN_SPEED_SIGMA_MPS, source, range_scale)
        return self.state

    def _plausible(self, x: np.ndarray) -> bool:
        """Whether a solution's position is on the road, not a mirror image behind a wall (:func:`between_walls`)."""
        return not len(self._tags) or between_walls(x[:2], self._tags, self._walls)

    def _solve(self, ranges: np.ndarray, fixes: np.ndarray, compass: np.ndarray, check_consistency: bool = False):
        """Best (east, north, yaw) now, its sigmas, source and the ranges' scale; None while undetermined or ambiguous.

        ``check_consistency``: :data:`_MIXED_PLACES` when the best fit's
        residuals fail a chi-square test (0.1 %) and the readings span more
        than one epoch.
        """
        c = self.config
        now_dr = self._pose
        travel = 0.0
        times = np.concatenate([ranges[:, 0], fixes[:, 0], compass[:, 0]])
        if times.size:
            dr = self._dr_at(times)
            travel = float(now_dr[3] - dr[:, 3].min())
        heading_from_compass = len(compass) > 0
        free_heading = not heading_from_compass and not self.has_wheel
        if not heading_from_compass and self.has_wheel and travel < c.min_travel_m:
            self.refused = f"no compass, and the vehicle had moved {travel:.2f} m of the {c.min_travel_m:g} m a heading from the ranges needs"
            return None
        if not _can_determine(ranges, fixes, heading_from_compass, free_heading):
            self.refused = "the readings in view could not determine a start (too few, or to one landmark with nothing to fix the heading)"
            return None

        def placed(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            """Each reading's dead-reckoned offset from now (start frame), heading change to now, and DR sigma."""
            d = self._dr_at(t)
            rel = d[:, :2] - now_dr[:2]
            sigma = np.hypot(c.dr_error_per_m * (now_dr[3] - d[:, 3]), c.dr_turn_error * (now_dr[4] - d[:, 4]) * np.hypot(*rel.T))
            return rel, d[:, 2] - now_dr[2], sigma

        r_rel, _, r_dr = placed(ranges[:, 0]) if len(ranges) else (np.zeros((0, 2)), None, np.zeros(0))
        f_rel, _, f_dr = placed(fixes[:, 0]) if len(fixes) else (np.zeros((0, 2)), None, np.zeros(0))
        c_dth = placed(compass[:, 0])[1] if len(compass) else np.zeros(0)
        r_sig = np.sqrt(ranges[:, 4] ** 2 + r_dr**2) if len(ranges) else np.zeros(0)
        f_sig = np.sqrt(fixes[:, 3] ** 2 + f_dr**2) if len(fixes) else np.zeros(0)
        th_now = float(now_dr[2])

        pose_columns = 2 if free_heading else 3

        def residuals(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            """Whitened residuals (S, N) and their analytic Jacobian (S, N, p) at S candidate starts (rows of X).

            X holds (east, north, yaw), or (east, north) with a free heading
            (yaw 0), then optionally the ranges' scale (a range reads the
            scale times the distance; prior 1 +- ``range_scale_sigma``).
            Without it the scale is 1.
            """
            X = np.atleast_2d(X)
            scaled = X.shape[1] > pose_columns
            e, n = X[:, :1], X[:, 1:2]
            yaw = np.zeros_like(e) if free_heading else X[:, 2:3]
            phi = yaw - th_now  # start frame -> local frame
            cp, sp = np.cos(phi), np.sin(phi)
            f, rows = [], []
            zero = np.zeros_like(e)
            if len(ranges):
                k = X[:, pose_columns:] if scaled else np.ones_like(e)
                de = cp * r_rel[:, 0] - sp * r_rel[:, 1]  # each reading's offset from now, local frame
                dn = sp * r_rel[:, 0] + cp * r_rel[:, 1]
                ue, un = e + de - ranges[:, 1], n + dn - ranges[:, 2]
                dist = np.hypot(ue, un)
                f.append((k * dist - ranges[:, 3]) / r_sig)
                d_k = dist / r_sig
                dist = np.maximum(dist, 1e-9)
                ue, un = k * ue / dist / r_sig, k * un / dist / r_sig
                rows.append(np.stack([ue, un, un * de - ue * dn, d_k], axis=-1))
            if len(fixes):
                de = cp * f_rel[:, 0] - sp * f_rel[:, 1]
                dn = sp * f_rel[:, 0] + cp * f_rel[:, 1]
                f += [(e + de - fixes[:, 1]) / f_sig, (n + dn - fixes[:, 2]) / f_sig]
                one, nil = np.broadcast_to(1.0 / f_sig, de.shape), np.zeros_like(de)
                rows += [np.stack([one, nil, -dn * one, nil], axis=-1), np.stack([nil, one, de * one, nil], axis=-1)]
            if len(compass):
                d = yaw + c_dth - compass[:, 1]
                f.append(np.arctan2(np.sin(d), np.cos(d)) / c.compass_sigma_rad)
                gain, nil = np.broadcast_to(1.0 / c.compass_sigma_rad, d.shape), np.zeros_like(d)
                rows.append(np.stack([nil, nil, gain, nil], axis=-1))
            if scaled:
                f.append((X[:, pose_columns:] - 1.0) / c.range_scale_sigma)
                rows.append(np.stack([zero, zero, zero, np.full_like(e, 1.0 / c.range_scale_sigma)], axis=-1))
            J = np.concatenate(rows, axis=1)
            columns = [0, 1] + ([] if free_heading else [2]) + ([3] if scaled else [])
            return np.concatenate(f, axis=1), J[..., columns]

        starts = []
        if len(fixes):
            anchors = [fixes[-1, 1:3]]
        else:
            last = ranges[-1]
            anchors = [last[1:3] + last[3] * np.array([math.cos(a), math.sin(a)]) for a in np.linspace(0, 2 * math.pi, _POSITION_STARTS, endpoint=False)]
        if heading_from_compass:
            yaws = [float(compass[-1, 1]) + k * math.pi / 2 for k in range(4)]
        else:
            yaws = list(np.linspace(-math.pi, math.pi, _HEADING_STARTS, endpoint=False))
        for a in anchors:
            if free_heading:
                starts.append(np.array([a[0], a[1]]))
                continue
            for yaw in yaws:
                starts.append(np.array([a[0], a[1], yaw]))
        # refine the minima that can be the start or its rival: the best plausible one and those within the rival margin of it
        minima = [(x, cost) for x, cost in _distinct_minima(residuals, np.array(starts), has_yaw=not free_heading) if self._plausible(x)]
        if not minima:
            self.refused = "every start that fitted the readings lay outside the road (behind a wall of tags)"
            return None
        times = np.concatenate([ranges[:, 0], fixes[:, 0]])

        def refine(scaled: bool):
            """The refined plausible minima, the best, its covariance; None when none is, or it is not determined.

            ``scaled``: with the ranges' scale free within 3 sigmas of its prior (unbounded, the robust loss would
            let a tiny scale explain any set of ranges from afar).
            """
            k_bounds = (1.0 - 3.0 * c.range_scale_sigma, 1.0 + 3.0 * c.range_scale_sigma)
            bounds = ([-np.inf] * pose_columns + [k_bounds[0]] * scaled, [np.inf] * pose_columns + [k_bounds[1]] * scaled)
            fits = []
            for x0 in [x for x, cost in minima if cost <= minima[0][1] + c.chi2_margin / 2 + 1.0]:
                try:
                    fit = least_squares(lambda x: residuals(x)[0][0], np.append(x0, [1.0] * scaled), jac=lambda x: residuals(x)[1][0],
                                        bounds=bounds, loss="soft_l1", f_scale=_ROBUST_SCALE, max_nfev=100, xtol=1e-12, ftol=1e-12, gtol=1e-12)
                except (ValueError, np.linalg.LinAlgError):
                    continue
                if np.all(np.isfinite(fit.x)):
                    fits.append(fit)
            plausible = [f for f in fits if self._plausible(f.x)]
            if not plausible:
                return None
            best = min(plausible, key=lambda f: f.cost)
            info = best.jac.T @ best.jac
            if np.linalg.cond(info) > 1e10:
                return None
            return plausible, best, np.linalg.inv(info)

        # the multi-start descends with the ranges' scale at 1; its minima are refined with the scale free, and that
        # solution is kept when the scale is significantly off 1; else (the scale is not determined: one beacon, a
        # single scan) the solution with the scale at 1, which a prior-bound scale would only widen
        refined = refine(True) if len(ranges) and c.range_scale_sigma > 0 else None
        if refined is not None and abs(refined[1].x[-1] - 1.0) < RANGE_SCALE_SIGNIFICANCE * math.sqrt(refined[2][-1, -1]):
            refined = None
        refined = refined or refine(False)
        if refined is None:
            self.refused = "the readings in view did not determine a start"
            return None
        plausible, best, cov = refined
        if check_consistency and np.ptp(times) > SAME_EPOCH_S and 2.0 * best.cost > chi2.ppf(0.999, max(best.fun.size - best.x.size, 1)):
            return _MIXED_PLACES
        sigma_p = math.sqrt(max(cov[0, 0], cov[1, 1]))
        sigma_yaw = math.pi if free_heading else math.sqrt(cov[2, 2])
        if sigma_p > c.max_position_sigma_m or (not free_heading and sigma_yaw > c.max_yaw_sigma_rad):
            self.refused = (f"the best start's 1-sigma was {sigma_p:.2f} m and {math.degrees(sigma_yaw):.1f} deg of heading, "
                            f"over this estimator's {c.max_position_sigma_m:g} m and {math.degrees(c.max_yaw_sigma_rad):g} deg")
            return None
        pose = (lambda x: (x[0], x[1], 0.0)) if free_heading else (lambda x: (x[0], x[1], x[2]))
        if rival_gap((*pose(best.x), best.cost), [(*pose(f.x), f.cost) for f in plausible], c) is not None:
            self.refused = "another start (a mirror image across a wall, or a turned track) fitted the readings almost as well"
            return None  # a rival (a mirror image, a turned track) fits almost as well: wait
        yaw = 0.0 if free_heading else math.remainder(float(best.x[2]), 2 * math.pi)
        source = "fix" if len(fixes) else "ranges"
        range_scale = float(best.x[pose_columns]) if best.x.size > pose_columns else 1.0
        return float(best.x[0]), float(best.x[1]), yaw, sigma_p, sigma_yaw, source, range_scale
