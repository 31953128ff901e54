"""The road a layout is planned for, and the candidate layouts on its walls (issue 18, item 3).

A :class:`TunnelSpec` (length, width, an optional curve, speed, sensor
profile) becomes the parameters of a simulated drive through it
(:meth:`TunnelSpec.overrides`, over the ``paper-comprehensive`` scenario: a
straight approach, the tunnel as straight, curve, straight, a straight exit),
driven at constant speed in its lane. A :class:`Candidate` is one layout
family (:data:`graphpos.sim.infrastructure.FAMILIES`) with its spacing; its
``tags`` parameters are what ``graphpos simulate --config`` reads.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from graphpos.errors import ConfigError
from graphpos.sim.infrastructure import FAMILIES, family_offsets

#: The simulated scenario whose route and sensors a plan's drives take.
BASE_SCENARIO = "paper-comprehensive"
#: Motion pattern of a plan's drives: constant speed in the lane.
PATTERN = "constant"
#: Seconds of approach before the portal: the 5 s of DGPS-grade fixes the
#: estimators start from (graphpos.sim.params, gnss_approach) and 2 s more.
APPROACH_S = 7.0
#: The papers' sensors: RFID, IMU, wheel, compass, and DGPS-grade fixes on the approach.
PAPERS_SENSORS = "imu,wheel,compass,rfid,gnss"
#: Pitch (m) of the pairs within a group (song2016 §5.1: 6 m).
GROUP_PITCH_M = 6.0
#: Closest spacing (m) searched between tags on a wall (song2016's dense layout: 6 m; half of it).
MIN_SPACING_M = 3.0
#: Spacings searched per family (geometric from MIN_SPACING_M to the tunnel's length).
GRID_POINTS = 20


@dataclass(frozen=True)
class TunnelSpec:
    """A tunnel to plan tags for.

    Attributes
    ----------
    length_m, width_m : float
        Centreline length and wall-to-wall width.
    speed_mps : float
        Constant driving speed.
    curve_radius_m : float or None
        Radius of a curve (left bend) inside the tunnel; None for a straight tunnel.
    curve_length_m, curve_start_m : float
        Arc length of the curve and where it starts, measured from the entry portal.
    profile : str
        Simulator sensor profile of the drives (``ideal`` or ``paper``).
    sensors : str
        The sensors the vehicle carries, comma-separated (simulator parameter
        ``sensors``: ``graphpos.sim.params.SENSORS``); the papers': RFID,
        IMU, wheel, compass and the DGPS fixes on the approach (``gnss``).
    reader_range_m : float
        Range of the RFID reader (simulator parameter ``rfid.reader_range_m``,
        at most the RSS law's 9 m).
    pattern : str
        Motion pattern of the drives: the speed profile (``constant``;
        ``accel``, ``decel`` and the others of :data:`BASE_SCENARIO`, at
        speeds about ``speed_mps``).
    """

    length_m: float
    width_m: float
    speed_mps: float
    curve_radius_m: float | None = None
    curve_length_m: float = 0.0
    curve_start_m: float = 0.0
    profile: str = "ideal"
    sensors: str = PAPERS_SENSORS
    reader_range_m: float = 9.0
    pattern: str = PATTERN

    def __post_init__(self) -> None:
        from graphpos.sim import SCENARIOS
        from graphpos.sim.params import default_params, sensor_set
        from graphpos.sim.rss import ENVIRONMENTS

        if "rfid" not in sensor_set(self.sensors):
            raise ConfigError("plan-layout: the sensors must include rfid (the tags are what is planned)")
        reach_m = ENVIRONMENTS[default_params(BASE_SCENARIO)["rss_environment"]].max_range_m
        if not (math.isfinite(self.reader_range_m) and 0 < self.reader_range_m <= reach_m):
            raise ConfigError(f"plan-layout: the reader range must be in (0, {reach_m:g}] m (the RSS law's reach), "
                              f"got {self.reader_range_m!r}")
        patterns = SCENARIOS[BASE_SCENARIO].patterns
        if self.pattern not in patterns:
            raise ConfigError(f"plan-layout: unknown motion pattern '{self.pattern}' (known: {', '.join(patterns)})")
        for name, what in (("length_m", "the tunnel length (--length-m)"), ("width_m", "the tunnel width (--width-m)"),
                           ("speed_mps", "the driving speed (--speed-kmh)")):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                shown = value * 3.6 if name == "speed_mps" else value  # in the unit the option takes
                raise ConfigError(f"plan-layout: {what} must be positive, got {shown!r}")
        if self.width_m < 2.0:
            raise ConfigError(f"plan-layout: a tunnel {self.width_m:g} m wide has no lane; give at least 2 m")
        if self.curve_radius_m is not None:
            if not (self.curve_radius_m >= 5.0):
                raise ConfigError(f"plan-layout: curve radius must be at least 5 m, got {self.curve_radius_m!r}")
            if not self.curve_length_m > 0:
                raise ConfigError(f"plan-layout: a curve needs its arc length (--curve-length-m), positive; got {self.curve_length_m!r}")
            if not (self.curve_start_m >= 0 and self.curve_start_m + self.curve_length_m <= self.length_m + 1e-9):
                raise ConfigError(f"plan-layout: the curve ({self.curve_start_m:g} m + {self.curve_length_m:g} m, --curve-start-m "
                                  f"+ --curve-length-m) must lie inside the {self.length_m:g} m tunnel")

    def overrides(self) -> dict[str, Any]:
        """Simulator parameters (over :data:`BASE_SCENARIO`) of a drive through the tunnel."""
        curve = self.curve_length_m if self.curve_radius_m is not None else 0.0
        before = self.curve_start_m if curve > 0 else self.length_m
        route = {
            "approach_before_m": max(14.0, APPROACH_S * self.speed_mps),
            "tunnel_straight_m": before,
            "tunnel_curve_m": curve,
            "curve_radius_m": self.curve_radius_m or 50.0,
            "tunnel_straight_after_m": self.length_m - before - curve,
            "approach_after_m": max(18.0, APPROACH_S * self.speed_mps),
            "width_m": self.width_m,
            "lane_width_m": min(3.75, self.width_m / 2),
        }
        motion = {"speed_mps": self.speed_mps, "speed_low_mps": 0.6 * self.speed_mps,
                  "speed_high_mps": 1.4 * self.speed_mps}
        return {"profile": self.profile, "sensors": self.sensors, "rfid": {"reader_range_m": self.reader_range_m},
                "route": route, "motion": motion}

    def describe(self) -> str:
        curve = (f", a {self.curve_length_m:g} m curve of radius {self.curve_radius_m:g} m from {self.curve_start_m:g} m"
                 if self.curve_radius_m is not None else ", straight")
        motion = "" if self.pattern == PATTERN else f" ({self.pattern} pattern)"
        return (f"{self.length_m:g} m long, {self.width_m:g} m wide{curve}, at {self.speed_mps:.3g} m/s "
                f"({self.speed_mps * 3.6:.0f} km/h){motion}, {self.profile} sensor profile, sensors {self.sensors}, "
                f"reader range {self.reader_range_m:g} m")


@dataclass(frozen=True)
class Candidate:
    """One layout: a family and its spacing (between tags on a wall, or between group starts)."""

    family: str
    spacing_m: float
    group_tags: int = 2

    def tags(self) -> dict[str, Any]:
        """The ``tags`` parameters of this layout (``graphpos simulate --config``)."""
        return {"family": self.family, "family_spacing_m": float(self.spacing_m),
                "family_group_tags": int(self.group_tags), "family_group_pitch_m": GROUP_PITCH_M}

    def n_tags(self, spec: TunnelSpec) -> int:
        return int(family_offsets(self.tags(), spec.length_m)[0].size)

    @property
    def label(self) -> str:
        if self.family == "groups":
            return f"groups of {2 * self.group_tags} every {self.spacing_m:g} m"
        return f"{self.family} every {self.spacing_m:g} m"


def family_grid(spec: TunnelSpec, family: str) -> list[Candidate]:
    """The candidates of one family, from the most tags to the fewest (one per tag count).

    Spacings run geometrically from :data:`MIN_SPACING_M` (for groups: the
    group's own length plus one pitch) to the tunnel's length.
    """
    if family not in FAMILIES:
        raise ConfigError(f"unknown layout family '{family}' (known: {', '.join(FAMILIES)})")
    low = MIN_SPACING_M if family != "groups" else 2 * GROUP_PITCH_M
    high = max(spec.length_m, low)
    out: list[Candidate] = []
    seen: set[int] = set()
    for spacing in np.geomspace(low, high, GRID_POINTS):
        c = Candidate(family, float(round(spacing, 1)))
        n = c.n_tags(spec)
        if n > 0 and n not in seen:
            seen.add(n)
            out.append(c)
    return out
