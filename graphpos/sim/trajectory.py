"""One vehicle trajectory from which every truth quantity is derived.

The vehicle follows the route's centreline at a lateral offset ``d(s)``
(the centre of its lane; a lane change is a quintic "smootherstep" between
lanes) with a speed profile ``v`` that has piecewise constant acceleration
along the path. Drives longer than one pass go out and back: at each end of
the route the vehicle continues along the approach road, makes a
right-left-right U-turn ("bulb") of radius ``turnaround_radius_m`` into the
opposite lane, and drives the route back. One lap (out, turn, back, turn)
repeats for as long as the drive lasts; the return pass drives the same speed
profile along the road in reverse, so an accelerating pattern decelerates on
the way back.

From the path (positions, heading ``psi``, path curvature ``kappa`` sampled
every 2 cm of arc length, closed forms) and the speed profile (exact
closed forms in time), the truth at any time is::

    v_e, v_n     = v cos psi, v sin psi
    yaw_rate     = kappa v
    accel_x      = dv/dt            (body x forward; planar, gravity-free)
    accel_y      = kappa v^2        (body y left, centripetal)

so integrating the body accelerations and yaw rate reproduces the track.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from graphpos.errors import ConfigError
from graphpos.sim.route import Route, advance

#: Arc-length step of the sampled path (finer for short routes).
_MIN_STEP_M = 0.02
_MAX_SAMPLES_PER_PASS = 200_000


def _smootherstep(u: np.ndarray):
    """S(u) = 6u^5 - 15u^4 + 10u^3 on [0, 1] with its first two derivatives."""
    u = np.clip(u, 0.0, 1.0)
    s = u**3 * (10 - 15 * u + 6 * u**2)
    ds = 30 * u**2 * (1 - u) ** 2
    dds = 60 * u * (1 - u) * (1 - 2 * u)
    return s, ds, dds


@dataclass(frozen=True)
class LanePlan:
    """Lateral offset of the vehicle from the centreline.

    Attributes
    ----------
    half_m : float
        Offset of a lane centre from the centreline (lane width / 2).
    change_start_s, change_length_m : float or None
        Route span of a lane change (from the driving lane to the other one),
        or None to keep the lane.
    """

    half_m: float
    change_start_s: float | None = None
    change_length_m: float = 0.0

    def forward_offset(self, s: np.ndarray, direction: int):
        """Offset to the left of the route's forward direction, and d/ds, d2/ds2.

        Outbound (``direction=+1``) the vehicle keeps right (``-half``);
        returning (``-1``) its right lane is the other one (``+half``). A lane
        change is the same S-curve on the road in both directions.
        """
        s = np.asarray(s, dtype=np.float64)
        h = self.half_m
        if self.change_start_s is None:
            return np.full_like(s, -h * direction), np.zeros_like(s), np.zeros_like(s)
        L = self.change_length_m
        S, dS, ddS = _smootherstep((s - self.change_start_s) / L)
        return -h + 2 * h * S, 2 * h * dS / L, 2 * h * ddS / L**2


@dataclass
class _Piece:
    sigma: np.ndarray
    x: np.ndarray
    y: np.ndarray
    psi: np.ndarray
    kappa: np.ndarray
    route_s: np.ndarray
    zone: np.ndarray
    turnaround: bool


def _pass_piece(route: Route, plan: LanePlan, direction: int) -> _Piece:
    n = int(min(np.ceil(route.length_m / _MIN_STEP_M), _MAX_SAMPLES_PER_PASS)) + 1
    s = np.linspace(0.0, route.length_m, n)
    x, y, th, k = route.centre(s)
    d, d1, d2 = plan.forward_offset(s, direction)
    a = 1.0 - k * d
    px, py = x - d * np.sin(th), y + d * np.cos(th)
    psi = th + np.arctan2(d1, a)
    dsigma = np.hypot(a, d1)
    # d psi / ds = kappa + d/ds atan2(d', 1 - kappa d), with kappa piecewise constant.
    kappa_v = (k + (a * d2 + k * d1**2) / (a**2 + d1**2)) / dsigma
    sigma = np.concatenate([[0.0], np.cumsum(0.5 * (dsigma[1:] + dsigma[:-1]) * np.diff(s))])
    zone = route.zone_index(s)
    if direction < 0:
        return _Piece(sigma[-1] - sigma[::-1], px[::-1], py[::-1], psi[::-1] + np.pi, -kappa_v[::-1], s[::-1], zone[::-1], False)
    return _Piece(sigma, px, py, psi, kappa_v, s, zone, False)


def _turnaround_piece(pose, extension_m: float, radius_m: float, shift_m: float, end_s: float, zone: int) -> _Piece:
    """Straight on, a right-left-right U-turn, straight back.

    The bulb turns right by alpha, left by pi + 2 alpha and right by alpha on
    one radius R; it ends at the along-road position where it began, ``R (4
    cos(alpha) - 2)`` to the left, heading back: alpha is chosen so that
    this is ``shift_m`` (the lateral distance between the two lanes).
    """
    c = (shift_m / radius_m + 2.0) / 4.0
    if not -1.0 <= c <= 1.0:
        raise ConfigError(f"turnaround radius {radius_m} m cannot join lanes {shift_m} m apart")
    alpha = float(np.arccos(c))
    parts = [(extension_m, 0.0), (radius_m * alpha, -1.0 / radius_m), (radius_m * (np.pi + 2 * alpha), 1.0 / radius_m),
             (radius_m * alpha, -1.0 / radius_m), (extension_m, 0.0)]
    xs, ys, hs, ks, sig = [], [], [], [], []
    x0, y0, h0 = pose
    sigma0 = 0.0
    for length, k in parts:
        if length <= 0:
            continue
        n = int(np.ceil(length / _MIN_STEP_M)) + 1
        u = np.linspace(0.0, length, n)
        x, y, h = advance(x0, y0, h0, k, u)
        first = 0 if not xs else 1
        xs.append(x[first:]), ys.append(y[first:]), hs.append(h[first:])
        ks.append(np.full(n - first, k)), sig.append(sigma0 + u[first:])
        x0, y0, h0 = float(x[-1]), float(y[-1]), float(h[-1])
        sigma0 += length
    sigma = np.concatenate(sig)
    return _Piece(sigma, np.concatenate(xs), np.concatenate(ys), np.concatenate(hs), np.concatenate(ks),
                  np.full(sigma.size, end_s), np.full(sigma.size, zone), True)


@dataclass(frozen=True)
class SpeedPlan:
    """Speed knots ``(route s, speed)`` of the outbound pass; v^2 is linear in
    arc length between knots (constant acceleration)."""

    s_m: tuple[float, ...]
    v_mps: tuple[float, ...]

    def at(self, s: float) -> float:
        return float(np.sqrt(np.interp(s, self.s_m, np.square(self.v_mps))))


class Trajectory:
    """The vehicle's motion for any time ``t >= 0`` (closed forms, vectorised).

    Parameters
    ----------
    route : Route
    lanes : LanePlan
    speeds : SpeedPlan
    turnaround_radius_m, turnaround_speed_mps, turnaround_accel_mps2 : float
        U-turn geometry and the speed change before/after it.
    """

    def __init__(self, route: Route, lanes: LanePlan, speeds: SpeedPlan, turnaround_radius_m: float,
                 turnaround_speed_mps: float, turnaround_accel_mps2: float):
        self.route = route
        out = _pass_piece(route, lanes, +1)
        back = _pass_piece(route, lanes, -1)
        L = route.length_m
        pieces = [out]
        knots: list[tuple[float, float]] = []
        sigma0 = 0.0

        def add_pass(piece: _Piece, s_knots, v_knots):
            nonlocal sigma0
            order = np.argsort(piece.route_s)
            for s, v in zip(s_knots, v_knots):
                knots.append((sigma0 + float(np.interp(s, piece.route_s[order], piece.sigma[order])), v))
            sigma0 += float(piece.sigma[-1])

        def add_turn(end_s: float, start: _Piece, nxt: _Piece):
            nonlocal sigma0
            v_end = speeds.at(end_s)
            v_turn = min(turnaround_speed_mps, v_end)
            ext = max(abs(v_end**2 - v_turn**2) / (2 * turnaround_accel_mps2), 2.0)
            # lateral shift from the arriving lane to the leaving one, to the
            # left of the arriving direction (+1 outbound, -1 returning)
            direction = +1 if start is out else -1
            d_from = float(lanes.forward_offset(np.array([end_s]), direction)[0][0])
            d_to = float(lanes.forward_offset(np.array([end_s]), -direction)[0][0])
            shift = direction * (d_to - d_from)
            pose = (float(start.x[-1]), float(start.y[-1]), float(start.psi[-1]))
            turn = _turnaround_piece(pose, ext, turnaround_radius_m, shift, end_s, int(start.zone[-1]))
            bulb = float(turn.sigma[-1]) - 2 * ext
            for ds, v in ((0.0, v_end), (ext, v_turn), (ext + bulb, v_turn), (2 * ext + bulb, v_end)):
                knots.append((sigma0 + ds, v))
            pieces.append(turn)
            pieces.append(nxt)
            sigma0 += float(turn.sigma[-1])

        add_pass(out, speeds.s_m, speeds.v_mps)
        self.first_pass_sigma_m = sigma0
        add_turn(L, out, back)
        add_pass(back, speeds.s_m[::-1], speeds.v_mps[::-1])
        add_turn(0.0, back, out)
        pieces.pop()  # the lap ends where the next outbound pass begins

        # Lap arrays (drop each piece's first sample, which repeats the last one).
        offsets = np.cumsum([0.0] + [float(p.sigma[-1]) for p in pieces[:-1]])

        def cat(name: str) -> np.ndarray:
            return np.concatenate([getattr(p, name)[(0 if i == 0 else 1):] for i, p in enumerate(pieces)])

        self.sigma = np.concatenate([p.sigma[(0 if i == 0 else 1):] + offsets[i] for i, p in enumerate(pieces)])
        self.x = cat("x")
        self.y = cat("y")
        self.psi = np.unwrap(cat("psi"))
        self.kappa = cat("kappa")
        self.route_s = cat("route_s")
        self.zone = cat("zone")
        self.turnaround = np.concatenate([np.full(p.sigma.size - (0 if i == 0 else 1), p.turnaround) for i, p in enumerate(pieces)])
        self.lap_length_m = float(self.sigma[-1])
        # Heading gained per lap: two left U-turns.
        self.psi_per_lap = float(self.psi[-1] - self.psi[0])

        # Speed knots -> time knots (piecewise constant acceleration).
        ks = np.array([k[0] for k in knots])
        kv = np.array([k[1] for k in knots])
        keep = np.concatenate([[True], np.diff(ks) > 1e-9])
        ks, kv = ks[keep], kv[keep]
        if ks[-1] < self.lap_length_m - 1e-6:
            ks, kv = np.append(ks, self.lap_length_m), np.append(kv, kv[0])
        ks[-1] = self.lap_length_m
        seg = np.diff(ks)
        self.knot_sigma = ks
        self.knot_v = kv
        self.knot_accel = (kv[1:] ** 2 - kv[:-1] ** 2) / (2 * seg)
        self.knot_t = np.concatenate([[0.0], np.cumsum(2 * seg / (kv[1:] + kv[:-1]))])
        self.lap_time_s = float(self.knot_t[-1])
        self.first_pass_time_s = float(np.interp(self.first_pass_sigma_m, ks, self.knot_t))

    def state(self, t_s: np.ndarray) -> dict[str, np.ndarray]:
        """Truth at times ``t_s`` (seconds from the start, >= 0).

        Returns
        -------
        dict of arrays
            ``east_m, north_m, yaw_rad`` (unwrapped), ``speed_mps``,
            ``v_east_mps, v_north_mps, yaw_rate_radps, accel_x_mps2,
            accel_y_mps2``, ``route_s`` (the route end in turnarounds), ``zone`` (index
            into ``route.zones``), ``turnaround`` (bool), ``lap`` (int),
            ``sigma_m`` (distance driven).
        """
        t = np.asarray(t_s, dtype=np.float64)
        lap = np.floor(t / self.lap_time_s)
        tl = t - lap * self.lap_time_s
        i = np.clip(np.searchsorted(self.knot_t, tl, side="right") - 1, 0, self.knot_t.size - 2)
        tau = tl - self.knot_t[i]
        a = self.knot_accel[i]
        v = self.knot_v[i] + a * tau
        sig = np.minimum(self.knot_sigma[i] + self.knot_v[i] * tau + 0.5 * a * tau**2, self.lap_length_m)
        j = np.clip(np.searchsorted(self.sigma, sig), 0, self.sigma.size - 1)
        psi = np.interp(sig, self.sigma, self.psi) + lap * self.psi_per_lap
        kappa = np.interp(sig, self.sigma, self.kappa)
        return {
            "east_m": np.interp(sig, self.sigma, self.x),
            "north_m": np.interp(sig, self.sigma, self.y),
            "yaw_rad": psi,
            "speed_mps": v,
            "v_east_mps": v * np.cos(psi),
            "v_north_mps": v * np.sin(psi),
            "yaw_rate_radps": kappa * v,
            "accel_x_mps2": a,
            "accel_y_mps2": kappa * v**2,
            "route_s": np.interp(sig, self.sigma, self.route_s),
            "zone": self.zone[j],
            "turnaround": self.turnaround[j],
            "lap": lap.astype(np.int64),
            "sigma_m": lap * self.lap_length_m + sig,
        }
