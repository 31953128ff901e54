"""The estimator contract shared by the filters and the factor graphs.

An estimator is built from a config (a dataclass whose field names carry
units), declares the channels it needs, and turns a drive into an
:class:`~graphpos.estimate.Estimate`::

    est = FusionEkf(config, layout="optimized", range_model=model)
    estimate = est.run(drive)

Online use is the same object fed one measurement at a time::

    est.start(drive)                    # maps, origin; channel data unused
    for m in live_feed:                 # graphpos.drive.Measurement, arrival order
        for row in est.process(m):      # OutputRow for each output epoch passed
            publish(row)
    estimate = est.finish()

``run`` is exactly that loop over ``drive.measurements(...)`` in arrival
order (an estimator may override ``run``, or the loop alone,
``_process_recorded``, with a faster equivalent, which its tests must show
gives the same result).
"""

from __future__ import annotations

import dataclasses
import math
import time
from abc import ABC, abstractmethod
from typing import Any, ClassVar

from graphpos.drive import CHANNEL_NAMES, Drive, Measurement
from graphpos.errors import ConfigError, MissingChannelError
from graphpos.estimate import Estimate, OutputRow
from graphpos.ignition import StartPose
from graphpos.profile import SensorProfile


#: Fastest output an estimator may be asked for (``output_rate_hz``, ``keyframe_rate_hz``), Hz: one a
#: millisecond, ten times the fastest sensor of the papers (100 Hz IMU). Memory and time grow with it
#: (10 kHz on a 30 s drive: 300,001 rows, 0.8 GB), and nothing is gained beyond the sensors' rates.
MAX_OUTPUT_RATE_HZ = 1000.0
#: The config fields :data:`MAX_OUTPUT_RATE_HZ` bounds.
OUTPUT_RATE_FIELDS = ("output_rate_hz", "keyframe_rate_hz")


def require_valid_numbers(config: Any, skip: tuple[str, ...] = ()) -> None:
    """Raise ConfigError unless every float field of ``config`` (but ``skip``) is finite and positive,
    and each output rate (:data:`OUTPUT_RATE_FIELDS`) at most :data:`MAX_OUTPUT_RATE_HZ`.

    Sigmas, rates, densities and scale factors are all positive; a zero or
    negative one would give a singular or meaningless filter, not an error.
    """
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if f.name not in skip and isinstance(value, float) and not (math.isfinite(value) and value > 0):
            raise ConfigError(f"{f.name} must be a positive finite number, got {value}")
        if f.name in OUTPUT_RATE_FIELDS and isinstance(value, float) and value > MAX_OUTPUT_RATE_HZ:
            raise ConfigError(f"{f.name} must be at most {MAX_OUTPUT_RATE_HZ:g} Hz (one output a millisecond), got {value:g}")


class Estimator(ABC):
    """Base class of every estimator.

    Parameters
    ----------
    config : dataclass instance, optional
        The estimator's tunables; ``default_config()`` when None.
    layout : str, optional
        Restrict RFID readings to a named tag layout of the drive.
    range_model : graphpos.ranging.RangeModel, optional
        How RFID/RSU readings become distances and sigmas. None: the drive's
        default (:func:`graphpos.ranging.default_range_model`).
    initial_pose : graphpos.ignition.StartPose, optional
        A start pose the user gives (``--initial-pose``); None: the one
        stored in the drive (``params["initial_pose"]``), else ignition finds
        one from the sensors (:mod:`graphpos.ignition`).
    profile : graphpos.profile.SensorProfile, optional
        A sensor calibration (``--profile``, found on another drive of the
        same sensors): the drive's readings are corrected before the
        estimator sees them, its range sigma and heading noise are used.
    """

    #: Registry name (``fusion-ekf``).
    name: ClassVar[str]
    #: One-line description for ``graphpos estimators``.
    summary: ClassVar[str] = ""
    #: Channels without which the estimator refuses a drive.
    required_channels: ClassVar[tuple[str, ...]] = ()
    #: Groups of channels of which the estimator needs at least one each: ``(("rsu", "gnss"),)``
    #: refuses a drive with neither an ``rsu`` nor a ``gnss`` channel (and uses whichever it has).
    required_any: ClassVar[tuple[tuple[str, ...], ...]] = ()
    #: Channels used when present (with documented fallbacks when absent).
    optional_channels: ClassVar[tuple[str, ...]] = ()
    #: Order ``run`` feeds measurements in (:meth:`Drive.measurements`):
    #: ``arrival`` (what a live system sees), or ``t`` for an offline
    #: smoother, to which no reading is late.
    merge_by: ClassVar[str] = "arrival"

    def __init__(self, config: Any = None, layout: str | None = None, range_model: Any = None, initial_pose: StartPose | None = None,
                 profile: SensorProfile | None = None):
        self.config = config if config is not None else self.default_config()
        self.layout = layout
        self.range_model = range_model
        self.initial_pose = initial_pose
        self.profile = profile

    def start_pose(self, drive: Drive) -> StartPose | None:
        """The user's start pose: the one given, else the drive's stored one, else None."""
        return self.initial_pose if self.initial_pose is not None else StartPose.from_params(drive.params)

    @classmethod
    @abstractmethod
    def default_config(cls) -> Any:
        """The papers' defaults."""

    # -- checks ---------------------------------------------------------------
    @classmethod
    def needs(cls) -> str:
        """What the estimator needs, as ``graphpos estimators`` lists it: ``imu, wheel, and rsu or gnss``
        (:attr:`required_channels`, then each group of :attr:`required_any`); ``-`` for nothing."""
        parts = [*cls.required_channels, *(" or ".join(group) for group in cls.required_any)]
        if cls.required_any and len(parts) > 1:
            return ", ".join(parts[:-1]) + (", and " if len(parts) > 2 else " and ") + parts[-1]
        return ", ".join(parts) or "-"

    def check(self, drive: Drive) -> None:
        """Raise :class:`MissingChannelError` if the drive lacks a needed channel (:meth:`needs`)."""
        missing = [c for c in self.required_channels if not drive.has(c)]
        if missing:
            raise MissingChannelError(
                f"{self.name} needs channel(s) {', '.join(missing)}, which drive '{drive.name}' does not have"
            )
        for group in self.required_any:
            if not any(drive.has(c) for c in group):
                raise MissingChannelError(f"{self.name} needs a channel of {' or '.join(group)}; drive '{drive.name}' has none")

    def prepare(self, drive: Drive) -> Drive:
        """Validate the drive, apply the layout restriction and the sensor profile's corrections and noise levels."""
        self.check(drive)
        if self.profile is not None:
            drive = self.profile.correct(drive)
            self.config = self.profile.tuned(self.config)
        return drive.with_layout(self.layout) if self.layout else drive

    def resolved_range_model(self, drive: Drive) -> Any:
        """The given range model, else the profile's, else the drive's default (for RSS, scaled by the profile's range scale)."""
        if self.range_model is not None:
            return self.range_model
        if self.profile is not None and self.profile.range_model() is not None and drive.reports_ranges:
            return self.profile.range_model()
        from graphpos.ranging import default_range_model

        model = default_range_model(drive)
        if self.profile is not None and self.profile.range_scale != 1.0 and model.input_column == "rss":
            from graphpos.ranging.model import ScaledRangeModel

            return ScaledRangeModel(model, self.profile.range_scale)
        return model

    def channels_used(self, drive: Drive) -> tuple[str, ...]:
        """Channels fed to ``process``, in tie-break order: the drive's channel order
        (:data:`graphpos.drive.CHANNEL_NAMES`, ``imu`` first, so that a filter predicts before it
        updates), the same for every estimator because it is the order a live feed delivers
        readings of equal time in (:mod:`graphpos.live`)."""
        named = {*self.required_channels, *(c for group in self.required_any for c in group), *self.optional_channels}
        return tuple(c for c in CHANNEL_NAMES if c in named and drive.has(c))

    # -- online -------------------------------------------------------------
    @abstractmethod
    def start(self, drive: Drive) -> None:
        """Reset for a new drive (reads maps and origin, not channel data)."""

    @abstractmethod
    def process(self, measurement: Measurement) -> list[OutputRow]:
        """Take one measurement; return the outputs of epochs now complete."""

    @abstractmethod
    def finish(self) -> Estimate:
        """Flush and return the whole estimate."""

    # -- offline --------------------------------------------------------------
    def run(self, drive: Drive) -> Estimate:
        """Process a whole drive in :attr:`merge_by` order and return the estimate."""
        drive = self.prepare(drive)
        t0 = time.perf_counter()
        self.start(drive)
        self._process_recorded(drive)
        est = self.finish()
        return est.with_wall_time(time.perf_counter() - t0)

    def _process_recorded(self, drive: Drive) -> None:
        """Everything of a recorded drive through :meth:`process`, in :attr:`merge_by` order (``run`` between
        ``start`` and ``finish``); an estimator may take it faster, with the same result (tested)."""
        for m in drive.measurements(self.channels_used(drive), by=self.merge_by):
            self.process(m)
