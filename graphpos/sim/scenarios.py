"""The scenarios: the papers' test set-ups as routes, motion patterns and defaults.

Each scenario names its route (built from the ``route`` parameters), the
motion patterns it allows and its default pattern. Motion patterns are those
of song2016 §6.3.2 (straight: acceleration, deceleration, constant speed) and
song2016 Table 4 (comprehensive: the same with constant angular velocity in
the curve, acceleration/deceleration with variable angular velocity in the
curve, lane change on the straight, lane change in the curve).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import numpy as np

from graphpos.errors import ConfigError
from graphpos.sim.params import default_params
from graphpos.sim.route import Route, Segment
from graphpos.sim.trajectory import LanePlan, SpeedPlan, Trajectory

STRAIGHT_PATTERNS = ("accel", "decel", "constant")
#: song2016 Table 4, in the table's order.
CURVE_PATTERNS = (
    "accel",
    "decel",
    "constant",
    "accel-variable",
    "decel-variable",
    "lane-change-straight",
    "lane-change-curve",
)


@dataclass(frozen=True)
class Scenario:
    """A simulated test set-up.

    Attributes
    ----------
    name : str
    summary : str
        One line: what it reproduces.
    patterns : tuple of str
        Allowed motion patterns.
    default_pattern : str
    """

    name: str
    summary: str
    patterns: tuple[str, ...]
    default_pattern: str = "constant"

    @functools.cached_property
    def default_duration_s(self) -> float:
        """Duration of one pass of the route with the default pattern and parameters."""
        params = default_params(self.name)
        return trajectory(self.name, self.default_pattern, params).first_pass_time_s

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "summary": self.summary,
            "patterns": list(self.patterns),
            "default_pattern": self.default_pattern,
            "default_duration_s": round(self.default_duration_s, 3),
        }


SCENARIOS: dict[str, Scenario] = {
    s.name: s
    for s in (
        Scenario("paper-straight", "song2016 §6.3.2: straight 6 m tunnel, 42 tags every 6 m on both walls, ~2 m/s, approach roads without tags", STRAIGHT_PATTERNS),
        Scenario("paper-comprehensive", "song2016 §6.3.3: 6 m tunnel, 60 m straight then a 60 m curve, 42 tags, the seven motion patterns of Table 4", CURVE_PATTERNS),
        Scenario("paper-imm", "song2014 §5: 7.5 m two-lane tunnel, straight + curve, tags about 6 m apart on both walls", CURVE_PATTERNS),
        Scenario("urban-rsu-gnss", "liu2016 §3: open road with GNSS, tunnel with 7 RSUs and no GNSS, street with multipath GNSS, 20 km/h", CURVE_PATTERNS),
        Scenario("long-tunnel", "beyond the papers: 3 km straight road tunnel at 80 km/h, tag groups every 30 m, GNSS on the approaches", STRAIGHT_PATTERNS),
    )
}


def build_route(scenario: str, route: dict[str, Any]) -> Route:
    """The road of a scenario from its ``route`` parameters."""
    if scenario == "urban-rsu-gnss":
        turn_m = route["turn_radius_m"] * np.deg2rad(route["turn_angle_deg"])
        segments = [
            Segment(route["open_m"], 0.0, "open"),
            Segment(route["tunnel_m"], 0.0, "tunnel"),
            Segment(turn_m, 1.0 / route["turn_radius_m"], "street"),
            Segment(route["street_m"], 0.0, "street"),
        ]
    else:
        curve_m = route.get("tunnel_curve_m", 0.0)
        curvature = 1.0 / route["curve_radius_m"] if curve_m > 0 else 0.0
        segments = [
            Segment(route["approach_before_m"], 0.0, "approach"),
            Segment(route["tunnel_straight_m"], 0.0, "tunnel"),
            Segment(curve_m, curvature, "tunnel"),
            Segment(route.get("tunnel_straight_after_m", 0.0), 0.0, "tunnel"),
            Segment(route["approach_after_m"], 0.0, "approach"),
        ]
    if segments[0].length_m <= 0 or segments[-1].length_m <= 0:
        raise ConfigError(f"scenario '{scenario}': the route must begin and end with a straight road of positive length")
    return Route(segments, route["width_m"], route["lane_width_m"])


def motion_plan(pattern: str, route: Route, motion: dict[str, Any]) -> tuple[LanePlan, SpeedPlan]:
    """Lane plan and speed knots of a motion pattern on a route.

    ``accel``/``decel`` change speed from the start of the route to the start
    of the first curve (the route's end when it has none) and hold it through
    the curve (constant angular velocity); the ``-variable`` patterns keep
    changing speed to the end of the curve (variable angular velocity). Lane
    changes (constant speed) are centred on the middle of the first straight
    tunnel section or of the first curve.
    """
    L = route.length_m
    v, lo, hi = motion["speed_mps"], motion["speed_low_mps"], motion["speed_high_mps"]
    curves = route.spans(curved=True)
    curve = curves[0] if curves else (L, L)
    knots = {
        "constant": ((0.0, L), (v, v)),
        "accel": ((0.0, curve[0], L), (lo, hi, hi)),
        "decel": ((0.0, curve[0], L), (hi, lo, lo)),
        "accel-variable": ((0.0, curve[1], L), (lo, hi, hi)),
        "decel-variable": ((0.0, curve[1], L), (hi, lo, lo)),
        "lane-change-straight": ((0.0, L), (v, v)),
        "lane-change-curve": ((0.0, L), (v, v)),
    }[pattern]
    s_k, v_k = knots
    keep = [0] + [i for i in range(1, len(s_k)) if s_k[i] > s_k[i - 1]]
    speeds = SpeedPlan(tuple(s_k[i] for i in keep), tuple(v_k[i] for i in keep))
    half = route.lane_width_m / 2.0
    if not pattern.startswith("lane-change"):
        return LanePlan(half), speeds
    if pattern == "lane-change-curve":
        if not curves:
            raise ConfigError("pattern 'lane-change-curve' needs a route with a curve")
        span = curves[0]
    else:
        straight = route.spans(curved=False)
        tunnel = route.spans(zone="tunnel")
        inside = [(max(a, t0), min(b, t1)) for a, b in straight for t0, t1 in tunnel if min(b, t1) > max(a, t0)]
        span = inside[0] if inside else straight[0]
    length = motion["lane_change_length_m"]
    if length <= 0 or length > span[1] - span[0]:
        raise ConfigError(
            f"parameter 'motion.lane_change_length_m' = {length} does not fit the {span[1] - span[0]:.1f} m section it is driven in"
        )
    return LanePlan(half, 0.5 * (span[0] + span[1]) - 0.5 * length, length), speeds


def trajectory(scenario: str, pattern: str, params: dict[str, Any]) -> Trajectory:
    """The vehicle trajectory of a scenario, pattern and parameter set."""
    route = build_route(scenario, params["route"])
    lanes, speeds = motion_plan(pattern, route, params["motion"])
    motion = params["motion"]
    return Trajectory(
        route, lanes, speeds, motion["turnaround_radius_m"], motion["turnaround_speed_mps"], motion["turnaround_accel_mps2"]
    )
