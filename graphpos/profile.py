"""A sensor profile: the calibration of one sensor set, found on one drive and reused on the next.

Real sensors read off in ways the papers' models do not carry: a gyro with a
turn-on bias, a turn rate or a wheel speed off by a scale, ranges that read
long. A :class:`SensorProfile` holds those corrections and the range noise
level, estimated from a drive without its truth (``graph-batch`` does it
offline, :mod:`graphpos.graph.calibration`; ``graphpos calibrate DRIVE -o
profile.json`` saves it) and applied to a drive's readings before any
estimator, filter or graph, sees them (``--profile profile.json``). The
readings are corrected rather than the models changed, so the papers'
state vectors stay as printed:

- yaw rate: ``(reading - gyro_bias_radps) / yaw_rate_scale``
  (``reading = yaw_rate_scale * true + gyro_bias_radps``);
- wheel speed: ``reading / wheel_scale``;
- reported ranges (``rfid.range_m``):
  ``(reading - range_bearing2_m_per_rad2 * bearing^2 - range_offset_m) / range_scale``
  (the bearing term only where the reading has a ``bearing_rad``, as a
  camera's has), with 1-sigma ``range_sigma0_m + range_sigma_slope * distance``
  (:meth:`SensorProfile.range_model`). RSS readings keep their RSS model
  (itself a calibration), its distances divided by ``range_scale``
  (:meth:`graphpos.estimator.Estimator.resolved_range_model`);
- compass yaw: ``reading - compass_bias_rad`` (a compass deviated by its
  installation);
- tag readings' times (``rfid.t_s``): ``stamp - range_delay_s`` (a reader
  or logger that stamps each reading that long after it was taken); the
  arrival time stays, so the estimators take the reading as a late one.

Its noise levels go to every estimator config that has the matching field
(:meth:`SensorProfile.tuned`): the heading noise the yaw-rate sensor leaves
after correction (a density; the graph's ``heading_noise_radps_per_sqrt_s``,
song2016's ``yaw_model_psd_rad2ps``) and the
part proportional to the turn (``turn_scale_density_per_sqrt_s``), and the
factor on range sigmas for errors that repeat between readings
(``range_sigma_scale``).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from graphpos.drive import Drive
from graphpos.errors import ConfigError, FileFormatError, is_finite_number

#: Plausible limits of each correction; a profile outside them is refused.
PLAUSIBLE_LIMITS = {
    "gyro_bias_radps": (-0.2, 0.2),
    "yaw_rate_scale": (0.5, 2.0),
    "wheel_scale": (0.5, 2.0),
    "range_scale": (0.5, 2.0),
    "range_offset_m": (-10.0, 10.0),
    "range_bearing2_m_per_rad2": (-10.0, 10.0),
    "compass_bias_rad": (-0.5, 0.5),
    "range_delay_s": (-5.0, 5.0),
}


class ImplausibleProfileError(ConfigError):
    """A profile field outside :data:`PLAUSIBLE_LIMITS`: ``name``, ``value`` and the ``limits`` (lo, hi)."""

    def __init__(self, name: str, value: Any, limits: tuple[float, float]):
        self.name, self.value, self.limits = name, value, limits
        what = "is outside the plausible range" if is_finite_number(value) else "is not a number; plausible range"
        super().__init__(f"sensor profile: {name} = {value!r} {what} [{limits[0]:g}, {limits[1]:g}]")


@dataclass(frozen=True)
class SensorProfile:
    """Corrections and noise levels of one sensor set (see the module docstring).

    Attributes
    ----------
    gyro_bias_radps, yaw_rate_scale : float
        The yaw-rate sensor (gyro or odometry turn rate).
    wheel_scale : float
        The wheel speed.
    range_scale, range_offset_m : float
        Reported ranges; the scale also applies to the distances of an RSS
        radio's model (:class:`~graphpos.ranging.model.ScaledRangeModel`:
        a reader hearing weaker than the calibration's reads long).
    range_bearing2_m_per_rad2 : float
        Reported ranges' error per squared bearing (m/rad^2), for readings
        with a bearing (a camera's range from a landmark's image, whose error
        grows towards the image's edges: MRCLAM's, :mod:`graphpos.io.mrclam`).
    compass_bias_rad : float
        The compass's constant deviation (``reading = yaw + bias``).
    range_delay_s : float
        How long after it was taken each tag reading is stamped, s.
    range_sigma0_m, range_sigma_slope : float or None
        1-sigma of a corrected range at zero distance and its growth per
        metre; None: the drive's default range model's.
    range_sigma_scale : float or None
        Factor on every range sigma for errors that repeat between readings
        of one landmark (the estimators' ``range_sigma_scale``); None: defaults.
    heading_noise_radps_per_sqrt_s : float or None
        Heading random walk the corrected yaw rate leaves (rad/sqrt(s));
        None: the estimators' defaults.
    turn_scale_density_per_sqrt_s : float or None
        Heading error per radian turned, as a density (1/sqrt(s)): the
        corrected turn rate's remaining scale error. None: defaults.
    source : dict
        Where the profile comes from (drive name, estimator, figures).
    """

    gyro_bias_radps: float = 0.0
    yaw_rate_scale: float = 1.0
    wheel_scale: float = 1.0
    range_scale: float = 1.0
    range_offset_m: float = 0.0
    range_bearing2_m_per_rad2: float = 0.0
    compass_bias_rad: float = 0.0
    range_delay_s: float = 0.0
    range_sigma0_m: float | None = None
    range_sigma_slope: float | None = None
    range_sigma_scale: float | None = None
    heading_noise_radps_per_sqrt_s: float | None = None
    turn_scale_density_per_sqrt_s: float | None = None
    source: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name, (lo, hi) in PLAUSIBLE_LIMITS.items():
            value = getattr(self, name)
            if not (is_finite_number(value) and lo <= value <= hi):
                raise ImplausibleProfileError(name, value, (lo, hi))
        for name in ("range_sigma0_m", "range_sigma_slope", "range_sigma_scale", "heading_noise_radps_per_sqrt_s", "turn_scale_density_per_sqrt_s"):
            value = getattr(self, name)
            if value is not None and not (is_finite_number(value) and value >= 0):
                raise ConfigError(f"sensor profile: {name} must be a non-negative number or null, got {value!r}")

    # -- use ----------------------------------------------------------------------
    def correct(self, drive: Drive) -> Drive:
        """The drive with its yaw rates, wheel speeds and reported ranges corrected."""
        channels = dict(drive.channels)
        for name, ch in drive.channels.items():
            fixed = self._corrections(name, ch.columns)
            if fixed:
                channels[name] = ch.replace(**fixed)
        return drive.replace(channels=channels)

    def corrected_values(self, channel: str, values: dict[str, float]) -> dict[str, float]:
        """One measurement's values (a row of ``channel``, as live mode receives it) corrected as :meth:`correct` corrects a drive."""
        fixed = self._corrections(channel, {k: np.float64(v) for k, v in values.items()})
        return {**values, **{k: float(v) for k, v in fixed.items()}} if fixed else values

    def _corrections(self, channel: str, columns: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """The corrected columns of one channel (arrays, or numpy scalars for one row); empty when nothing changes."""
        if channel == "imu" and (self.gyro_bias_radps != 0.0 or self.yaw_rate_scale != 1.0):
            return {"yaw_rate_radps": (columns["yaw_rate_radps"] - self.gyro_bias_radps) / self.yaw_rate_scale}
        if channel == "wheel" and self.wheel_scale != 1.0:
            return {"speed_mps": columns["speed_mps"] / self.wheel_scale}
        if channel == "compass" and self.compass_bias_rad != 0.0:
            from filters.models.angles import wrap_angle

            return {"yaw_rad": wrap_angle(columns["yaw_rad"] - self.compass_bias_rad)}
        if channel == "rfid":
            fixed = {}
            if self.range_scale != 1.0 or self.range_offset_m != 0.0 or self.range_bearing2_m_per_rad2 != 0.0:
                range_m = columns["range_m"]
                bearing = columns.get("bearing_rad")
                if self.range_bearing2_m_per_rad2 != 0.0 and bearing is not None:
                    range_m = range_m - self.range_bearing2_m_per_rad2 * np.where(np.isfinite(bearing), bearing, 0.0) ** 2
                corrected = np.maximum((range_m - self.range_offset_m) / self.range_scale, 0.0)
                fixed["range_m"] = np.where(np.isfinite(range_m), corrected, np.nan)
            if self.range_delay_s != 0.0 and "t_s" in columns:  # a drive's column (live rows: corrected_time)
                fixed["t_s"] = columns["t_s"] - self.range_delay_s
                # received when it was (a late reading now); a reading stamped early (negative delay) arrives
                # no sooner than it was taken
                fixed["arrival_s"] = np.maximum(columns["arrival_s"], fixed["t_s"])
            return fixed
        return {}

    def corrected_time(self, channel: str, t_s: float) -> float:
        """One reading's time (a row of ``channel``, as live mode receives it) corrected as :meth:`correct` corrects a drive's."""
        return t_s - self.range_delay_s if channel == "rfid" else t_s

    def tuned(self, config: Any) -> Any:
        """``config`` with the profile's noise levels in the fields it has (see the module docstring)."""
        values: dict[str, float] = {}
        h, turn = self.heading_noise_radps_per_sqrt_s, self.turn_scale_density_per_sqrt_s
        if h is not None:
            values["heading_noise_radps_per_sqrt_s"] = h
            values["yaw_model_psd_rad2ps"] = h * h
        if turn is not None:
            values["turn_scale_density_per_sqrt_s"] = turn
        if (h is not None or turn is not None) and self.source.get("noise_dof") is not None:
            values["noise_dof"] = float(self.source["noise_dof"])
        if self.range_sigma_scale is not None:
            values["range_sigma_scale"] = max(self.range_sigma_scale, 1.0)
        names = {f.name for f in dataclasses.fields(config)}
        values = {k: max(v, 1e-9) for k, v in values.items() if k in names}
        return dataclasses.replace(config, **values) if values else config

    def range_model(self):
        """A LinearCalibration with the profile's range sigma (for the corrected ranges), or None."""
        if self.range_sigma0_m is None:
            return None
        from graphpos.ranging.model import LinearCalibration

        return LinearCalibration(sigma0_m=max(self.range_sigma0_m, 1e-3), sigma_slope=self.range_sigma_slope or 0.0)

    def combined(self, later: "SensorProfile") -> "SensorProfile":
        """This profile followed by ``later`` (found on readings this one had corrected): one profile for raw readings.

        The corrections compose. The odometry's noise levels do not: each
        profile fitted them on its own windows of the drive (``source``
        ``windows``; graph-isam2's online learning fits each on the readings
        since the last), and a sensor's noise is one level, so the two
        variances are pooled, weighed by their windows.
        """
        noise = {}
        mine, theirs = int(self.source.get("windows", 0)), int(later.source.get("windows", 0))
        if mine > 0 and theirs > 0:
            for name in ("heading_noise_radps_per_sqrt_s", "turn_scale_density_per_sqrt_s"):
                a, b = getattr(self, name), getattr(later, name)
                if a is not None and b is not None:
                    noise[name] = math.sqrt((mine * a**2 + theirs * b**2) / (mine + theirs))
                elif a is not None:  # the later fit did not determine it: this one's stands
                    noise[name] = a
            noise["source"] = {**later.source, "windows": mine + theirs}
            if "noise_dof" in self.source and "noise_dof" in later.source:  # independent windows: their degrees of freedom add
                noise["source"]["noise_dof"] = self.source["noise_dof"] + later.source["noise_dof"]
        return dataclasses.replace(
            later,
            **noise,
            gyro_bias_radps=self.gyro_bias_radps + self.yaw_rate_scale * later.gyro_bias_radps,
            yaw_rate_scale=self.yaw_rate_scale * later.yaw_rate_scale,
            wheel_scale=self.wheel_scale * later.wheel_scale,
            range_scale=self.range_scale * later.range_scale,
            range_offset_m=self.range_offset_m + self.range_scale * later.range_offset_m,
            range_bearing2_m_per_rad2=self.range_bearing2_m_per_rad2 + self.range_scale * later.range_bearing2_m_per_rad2,
            compass_bias_rad=self.compass_bias_rad + later.compass_bias_rad,
            range_delay_s=self.range_delay_s + later.range_delay_s,
        )

    # -- files ----------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return {"kind": "graphpos-sensor-profile", **dataclasses.asdict(self)}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "SensorProfile":
        if not isinstance(data, dict) or data.get("kind") != "graphpos-sensor-profile":
            raise ConfigError("not a graphpos sensor profile (no \"kind\": \"graphpos-sensor-profile\")")
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known - {"kind"})
        if unknown:
            raise ConfigError(f"sensor profile: unknown field(s) {', '.join(unknown)}")
        return cls(**{k: v for k, v in data.items() if k in known})

    def save(self, path: str | os.PathLike) -> None:
        from graphpos.io.outputs import atomic_output

        with atomic_output(path) as f:
            f.write((json.dumps(self.to_dict(), indent=1) + "\n").encode())

    @classmethod
    def load(cls, path: str | os.PathLike) -> "SensorProfile":
        from graphpos.errors import naming_file
        from graphpos.io.files import read_input

        raw = read_input(path)
        try:
            data = json.loads(raw.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise FileFormatError(f"{path}: not a JSON sensor profile ({exc})") from None
        with naming_file(path):
            return cls.from_dict(data)
