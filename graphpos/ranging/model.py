"""The RangeModel interface: how a reading becomes a distance and a sigma.

Every estimator that uses RFID or RSU ranges gets its distances and 1-sigmas
through a RangeModel; estimators never hold their own RSS conversion
(issue 3). A model reads one column of the ``rfid`` channel (``rss`` for
RSS-based radios, ``range_m`` for radios that report a range) and predicts a
distance in metres and a distance-dependent 1-sigma in metres.
"""

from __future__ import annotations

import json
import os
from abc import ABC, abstractmethod
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from graphpos.drive import Channel
from graphpos.errors import ConfigError, FileFormatError
from graphpos.io.files import read_input
from graphpos.io.outputs import atomic_output


class RangeModel(ABC):
    """Reading (RSS or raw range) -> distance and 1-sigma.

    Subclasses set ``kind`` (the name used in saved files) and ``input_column``
    (the ``rfid`` column they read), and implement fit/predict/to_dict.
    """

    kind: ClassVar[str]
    input_column: ClassVar[str]

    @abstractmethod
    def fit(self, reading: np.ndarray, true_distance_m: np.ndarray) -> "RangeModel":
        """Fit on readings against true distances; returns self."""

    @abstractmethod
    def predict_distance_m(self, reading: np.ndarray) -> np.ndarray:
        """Distance for each reading (NaN in, NaN out)."""

    @abstractmethod
    def predict_sigma_m(self, distance_m: np.ndarray) -> np.ndarray:
        """1-sigma of a reading's distance taken at this true distance.

        The spread of the measurement given the state (what a filter's or a
        factor's noise model is), so a caller evaluates it at its best
        estimate of the true distance: the factor graph at its estimate's,
        the filters (and :meth:`ranges`) at the reading's own distance.
        """

    @abstractmethod
    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable parameters (without ``kind``)."""

    @classmethod
    @abstractmethod
    def from_dict(cls, data: dict[str, Any]) -> "RangeModel":
        """Inverse of :meth:`to_dict`."""

    # -- shared --------------------------------------------------------------
    def ranges(self, rfid: Channel) -> tuple[np.ndarray, np.ndarray]:
        """Distance and 1-sigma for every row of an ``rfid`` (or ``rsu``) channel.

        Raises
        ------
        ConfigError
            When the channel carries no usable value in this model's column.
        """
        reading = rfid[self.input_column]
        if len(rfid) and not np.isfinite(reading).any():
            raise ConfigError(
                f"range model '{self.kind}' reads '{self.input_column}', which this drive's {rfid.kind} channel does not carry"
            )
        d = self.predict_distance_m(reading)
        return d, self.predict_sigma_m(d)

    def save(self, path: str | os.PathLike) -> None:
        """Write the model as JSON (atomically: temporary file, then rename)."""
        payload = json.dumps({"kind": self.kind, **self.to_dict()}, indent=1)
        with atomic_output(Path(path)) as stream:
            stream.write(payload.encode())


_KINDS: dict[str, type[RangeModel]] = {}


def register(cls: type[RangeModel]) -> type[RangeModel]:
    """Class decorator: make a model kind loadable by :func:`load_range_model`."""
    _KINDS[cls.kind] = cls
    return cls


def load_range_model(path: str | os.PathLike) -> RangeModel:
    """Read a model saved by :meth:`RangeModel.save`; clear errors for bad files."""
    path = Path(path)
    try:
        data = json.loads(read_input(path))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise FileFormatError(f"{path}: not a range-model JSON file ({exc})") from None
    if not isinstance(data, dict) or data.get("kind") not in _KINDS:
        raise FileFormatError(f"{path}: unknown range-model kind {data.get('kind') if isinstance(data, dict) else None!r}")
    try:
        return _KINDS[data.pop("kind")].from_dict(data)
    except (KeyError, TypeError, ValueError) as exc:
        raise FileFormatError(f"{path}: malformed range model ({exc})") from None


@register
class LinearCalibration(RangeModel):
    """Scale/offset calibration of a reported range: ``d = (r - offset) / scale``.

    The identity (scale 1, offset 0) is the default for drives whose radio
    reports ranges. ``sigma_m = sigma0_m + sigma_slope * d``.
    """

    kind = "linear"
    input_column = "range_m"

    def __init__(self, scale: float = 1.0, offset_m: float = 0.0, sigma0_m: float = 0.3, sigma_slope: float = 0.0):
        if not np.isfinite(scale) or scale <= 0:
            raise ConfigError(f"range scale must be positive, got {scale}")
        self.scale = float(scale)
        self.offset_m = float(offset_m)
        self.sigma0_m = float(sigma0_m)
        self.sigma_slope = float(sigma_slope)

    def fit(self, reading: np.ndarray, true_distance_m: np.ndarray) -> "LinearCalibration":
        ok = np.isfinite(reading) & np.isfinite(true_distance_m)
        if ok.sum() < 2:
            raise ConfigError("need at least two readings with true distances to fit a calibration")
        r, d = reading[ok], true_distance_m[ok]
        if np.ptp(d) == 0:
            raise ConfigError("need readings at more than one true distance to fit a calibration")
        scale, offset = np.polyfit(d, r, 1)  # r = scale * d + offset
        if not scale > 0:
            raise ConfigError(f"fitted range scale {scale:.3g} is not positive: the readings do not grow with distance")
        self.scale, self.offset_m = float(scale), float(offset)
        resid = self.predict_distance_m(r) - d
        # sigma(d) = a + b d from absolute residuals (E|e| = sigma sqrt(2/pi));
        # a spread that does not grow with distance is a constant: the RMS
        b, a = np.polyfit(d, np.abs(resid) * np.sqrt(np.pi / 2), 1)
        if b < 0:
            a, b = np.sqrt(np.mean(resid**2)), 0.0
        self.sigma0_m, self.sigma_slope = max(float(a), 1e-3), float(b)
        return self

    def predict_distance_m(self, reading: np.ndarray) -> np.ndarray:
        return (np.asarray(reading, dtype=np.float64) - self.offset_m) / self.scale

    def predict_sigma_m(self, distance_m: np.ndarray) -> np.ndarray:
        d = np.asarray(distance_m, dtype=np.float64)
        return self.sigma0_m + self.sigma_slope * np.abs(d)

    def to_dict(self) -> dict[str, Any]:
        return {"scale": self.scale, "offset_m": self.offset_m, "sigma0_m": self.sigma0_m, "sigma_slope": self.sigma_slope}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "LinearCalibration":
        return cls(**data)


@register
class ScaledRangeModel(RangeModel):
    """Another model's distances divided by a scale: ``d = inner(reading) / scale``.

    The range scale of a sensor profile for an RSS radio (``graphpos
    calibrate``): the RSS model was fitted on a calibration stand, and a
    reader on the vehicle that hears a few dB weaker (antenna behind the car
    body) reads every distance long by a common factor where RSS falls with
    the log of the distance (2-3 dB at a path-loss exponent near 2.5: 20-30 %).
    The 1-sigma scales with the distance: ``inner.sigma(scale * d) / scale``.
    """

    kind = "scaled"

    def __init__(self, inner: RangeModel, scale: float):
        if not np.isfinite(scale) or scale <= 0:
            raise ConfigError(f"range scale must be positive, got {scale}")
        self.inner = inner
        self.scale = float(scale)
        self.input_column = inner.input_column

    def fit(self, reading: np.ndarray, true_distance_m: np.ndarray) -> "ScaledRangeModel":
        raise ConfigError("a scaled range model is not fitted: fit its inner model, then scale it")

    def predict_distance_m(self, reading: np.ndarray) -> np.ndarray:
        return self.inner.predict_distance_m(reading) / self.scale

    def predict_sigma_m(self, distance_m: np.ndarray) -> np.ndarray:
        return self.inner.predict_sigma_m(np.asarray(distance_m, dtype=np.float64) * self.scale) / self.scale

    def to_dict(self) -> dict[str, Any]:
        return {"scale": self.scale, "inner": {"kind": self.inner.kind, **self.inner.to_dict()}}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "ScaledRangeModel":
        inner = dict(data["inner"])
        return cls(_KINDS[inner.pop("kind")].from_dict(inner), data["scale"])
