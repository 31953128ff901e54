"""The yaw-rate bias measured while the vehicle stands still (from the sensors, never the truth).

A gyro's turn-on bias (and its slow drift) is the one sensor error a
vehicle shows for free: while the wheels report zero speed the true yaw
rate is zero, so the mean yaw rate over the standstill is the bias. Most
drives begin standing (engine start, a gate, traffic) and stop again at
lights. Filters whose paper state vector has no gyro bias (song2016's
fusion EKF, ...) and the graphs alike take their yaw rates through one
:class:`StandstillGyroBias`, which subtracts the current estimate, causally:
a yaw rate is corrected with what the standstills before it showed.

A standstill is a run of wheel-speed samples with ``|speed| <=``
:attr:`StandstillConfig.max_speed_mps`; the yaw rates inside it, less
:attr:`StandstillConfig.margin_s` at each end (the vehicle settling and
starting), are averaged once the run lasts
:attr:`StandstillConfig.min_duration_s`. A run whose mean exceeds
:attr:`StandstillConfig.max_bias_radps` is not a standstill but a turn on
the spot (a robot rotating with zero forward speed, MRCLAM) and is ignored.

The estimate is a scalar Kalman filter on a random-walk bias: each
standstill is a measurement with the variance of its mean (sample variance
over the number of samples, never below :attr:`StandstillConfig.floor_radps`
squared: the samples are correlated), and between standstills the
variance grows by :attr:`StandstillConfig.walk_radps_per_sqrt_s` squared
per second.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class StandstillConfig:
    """Settings of :class:`StandstillGyroBias`.

    Parameters
    ----------
    max_speed_mps : float
        Wheel speed at or under which the vehicle stands (0.01 m/s: a car
        at its tightest turn then yaws at most ~0.1 deg/s).
    min_duration_s : float
        Shortest standstill (after the margins) that measures the bias.
    margin_s : float
        Time dropped at each end of a standstill.
    max_bias_radps : float
        A larger mean yaw rate while standing is a turn on the spot, not a
        bias (1 deg/s: twice the turn-on bias of the cheapest gyros the
        simulator's ``realistic`` profile draws).
    floor_radps : float
        Smallest 1-sigma of one standstill's mean.
    walk_radps_per_sqrt_s : float
        Random-walk density of the bias between standstills.
    """

    max_speed_mps: float = 0.01
    min_duration_s: float = 2.0
    margin_s: float = 0.5
    max_bias_radps: float = math.radians(1.0)
    floor_radps: float = math.radians(0.005)
    walk_radps_per_sqrt_s: float = math.radians(0.005)


class StandstillGyroBias:
    """Causal yaw-rate bias from standstills; feed it wheel speeds and yaw rates in time order."""

    def __init__(self, config: StandstillConfig | None = None) -> None:
        self.config = config or StandstillConfig()
        self.bias_radps = 0.0
        self.variance_rad2ps2 = math.inf  # no standstill yet
        self.standstills = 0
        self.standing_s = 0.0
        self._at_s = -math.inf  # time of the last committed standstill
        self._standing_since: float | None = None
        self._recent: deque[tuple[float, float]] = deque()  # the last margin_s of yaw rates, not yet summed
        self._n, self._sum, self._sum2 = 0, 0.0, 0.0
        self._first_s = self._last_s = math.nan  # of the summed samples

    def speed(self, t_s: float, speed_mps: float) -> None:
        """One wheel-speed sample."""
        if not math.isfinite(speed_mps):
            return
        if abs(speed_mps) <= self.config.max_speed_mps:
            if self._standing_since is None:
                self._standing_since = float(t_s)
                self._recent.clear()
                self._n, self._sum, self._sum2 = 0, 0.0, 0.0
            return
        if self._standing_since is not None:
            measured = self._measured()
            if measured is not None:
                self.bias_radps, self.variance_rad2ps2 = self._fused(float(t_s), *measured)
                self._at_s = float(t_s)
                self.standstills += 1
                self.standing_s += float(t_s) - self._standing_since
            self._standing_since = None

    def yaw_rate(self, t_s: float, yaw_rate_radps: float) -> float:
        """One yaw-rate sample: returns it corrected by the bias known so far."""
        if self._standing_since is not None and math.isfinite(yaw_rate_radps):
            self._recent.append((float(t_s), float(yaw_rate_radps)))
            settled = self._standing_since + self.config.margin_s
            while self._recent and self._recent[0][0] < t_s - self.config.margin_s:
                t, w = self._recent.popleft()
                if t >= settled:
                    if self._n == 0:
                        self._first_s = t
                    self._n, self._sum, self._sum2, self._last_s = self._n + 1, self._sum + w, self._sum2 + w * w, t
        return yaw_rate_radps - self.current_bias_radps()

    def current_bias_radps(self) -> float:
        """The estimate, with the standstill in progress counted once it is long enough."""
        measured = self._measured() if self._standing_since is not None else None
        if measured is None:
            return self.bias_radps
        return self._fused(self._last_s, *measured)[0]

    def describe(self) -> dict[str, Any]:
        """JSON-serialisable summary for diagnostics."""
        sigma = math.sqrt(self.variance_rad2ps2) if math.isfinite(self.variance_rad2ps2) else None
        return {"gyro_bias_radps": self.bias_radps, "gyro_bias_sigma_radps": sigma,
                "standstills": self.standstills, "standing_s": self.standing_s}

    def _measured(self) -> tuple[float, float] | None:
        """Mean yaw rate of the standstill in progress (settled samples) and its variance, or None."""
        c = self.config
        n = self._n
        if n < 2 or self._last_s - self._first_s < c.min_duration_s:
            return None
        mean = self._sum / n
        if abs(mean) > c.max_bias_radps:
            return None
        var = max(self._sum2 / n - mean * mean, 0.0) * n / (n - 1) / n
        return mean, max(var, c.floor_radps**2)

    def _fused(self, t_s: float, mean: float, var: float) -> tuple[float, float]:
        """The bias estimate and its variance after a standstill measured ``mean`` (variance ``var``) at ``t_s``."""
        if not math.isfinite(self.variance_rad2ps2):
            return mean, var
        prior = self.variance_rad2ps2 + self.config.walk_radps_per_sqrt_s**2 * max(t_s - self._at_s, 0.0)
        gain = prior / (prior + var)
        return self.bias_radps + gain * (mean - self.bias_radps), (1.0 - gain) * prior
