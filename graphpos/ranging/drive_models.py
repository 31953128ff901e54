"""Range models for a drive: the default one, one calibrated per environment, one fitted to a drive.

A drive whose radio reports ranges (``rfid.range_m``) uses them through a
:class:`~graphpos.ranging.model.LinearCalibration`, the identity by default.
A drive whose radio reports RSS is converted by an LSSVM (song2016 §3) fitted
offline on simulated calibration data of its environment (song2016 §6.1):
the averaged collection of four tags trains the model, and the individual
1 Hz readings of a second collection, with twenty other tags, give its
1-sigma (a drive's tags are not the calibration tags, and a drive's readings
are not averaged, so only such held-out readings make the sigma honest; with
four tags the tag-to-tag shadowing spread would be guessed from four draws).
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from graphpos.drive import Channel, Drive
from graphpos.io.checks import true_ranges_m as truth_distances_m
from graphpos.errors import ConfigError, MissingChannelError
from graphpos.ranging.calibration_data import simulate_collection
from graphpos.ranging.lssvm import LssvmRangeModel
from graphpos.ranging.model import LinearCalibration, RangeModel
from graphpos.ranging.propagation import PropagationRangeModel
from graphpos.ranging.rss_model import RssRangeModel

#: Seed of the simulated calibration collections behind the default models.
CALIBRATION_SEED = 2016

#: 1-sigma of reported ranges used as they are (identity calibration): an
#: uncalibrated ranging radio is off by a few per cent of the range (Plaza's
#: UWB ranges read 7 % long), beyond its short-range noise.
DEFAULT_RANGE_SIGMA0_M = 0.3
DEFAULT_RANGE_SIGMA_SLOPE = 0.05

#: Held-out collection the calibrated models learn their sigma from.
SIGMA_COLLECTION = {"n_tags": 20, "duration_s": 60.0}

#: Model kinds :func:`fit_from_drive` can fit.
FIT_KINDS = ("auto", "lssvm", "propagation", "linear")

_RSS_KINDS: dict[str, type[RssRangeModel]] = {"lssvm": LssvmRangeModel, "propagation": PropagationRangeModel}


def calibrated_model(environment: str, kind: str = "lssvm", seed: int = CALIBRATION_SEED) -> RssRangeModel:
    """An RSS model fitted on a simulated calibration collection (song2016 §6.1).

    Trained on the averaged RSS of collection ``[seed, 0]`` (four tags, five
    minutes); its 1-sigma is learned from the individual readings of
    collection ``[seed, 2]`` (:data:`SIGMA_COLLECTION`: other tags). Cached
    per (environment, kind, seed); each call returns a copy.
    """
    cached = _calibrated(environment, kind, seed)
    return type(cached).from_dict(cached.to_dict())


@functools.cache
def _calibrated(environment: str, kind: str, seed: int) -> RssRangeModel:
    if kind not in _RSS_KINDS:
        raise ConfigError(f"unknown RSS model kind '{kind}' (known: {', '.join(_RSS_KINDS)})")
    train = simulate_collection(environment, [seed, 0])
    held_out = simulate_collection(environment, [seed, 2], **SIGMA_COLLECTION)
    model = _RSS_KINDS[kind]().fit(train.mean_rss, train.distance_m)
    return model.fit_sigma(held_out.readings.ravel(), held_out.reading_distance_m)


#: The ``rfid`` fields a range model reads: a range the radio reports, and RSS.
READING_FIELDS = ("range_m", "rss")


def default_model_for(drive: Drive, field: str) -> RangeModel:
    """The drive's default range model for readings of one field.

    ``range_m`` (ranges reported by the radio) -> identity
    :class:`LinearCalibration` with 1-sigma ``0.3 m + 5 % of the range``
    (:data:`DEFAULT_RANGE_SIGMA0_M`, :data:`DEFAULT_RANGE_SIGMA_SLOPE`);
    ``rss`` -> LSSVM calibrated in ``drive.params["rss_environment"]``
    (default ``"tunnel"``).
    """
    if field == "range_m":
        return LinearCalibration(sigma0_m=DEFAULT_RANGE_SIGMA0_M, sigma_slope=DEFAULT_RANGE_SIGMA_SLOPE)
    return calibrated_model(str(drive.params.get("rss_environment", "tunnel")), "lssvm")


def default_range_model(drive: Drive) -> RangeModel:
    """The range model a drive is used with when the user gives none.

    The default model (:func:`default_model_for`) of ``range_m`` when the
    radio reports ranges, else of ``rss`` when the readings carry RSS. A
    drive without RFID readings gets the identity too.
    """
    rss_only = drive.has("rfid") and not drive.reports_ranges and np.isfinite(drive.rfid.rss).any()
    return default_model_for(drive, "rss" if rss_only else "range_m")


def reading_models(drive: Drive, model: RangeModel, who: str) -> dict[str, RangeModel]:
    """The range model of each field the drive's RFID readings carry, ``model``'s own first.

    Both fields are optional in a reading, and a drive may mix readings
    with a range and readings with RSS only (a radio that reports a range
    only when its ranging exchange succeeds). ``model`` reads its own field
    (``model.input_column``); readings without a value there but with one
    in the other field go through the drive's default model for that
    field (:func:`default_model_for`). Use with :func:`ranges_by_field`.

    Raises
    ------
    ConfigError
        Naming ``who`` (the estimator) when no reading carries ``model``'s
        field: the model the user chose cannot be applied to this drive.
    """
    models = {model.input_column: model}
    if not drive.has("rfid"):
        return models
    rfid = drive.rfid
    own = np.isfinite(rfid[model.input_column])
    if not own.any():
        raise ConfigError(
            f"{who}: range model '{model.kind}' reads '{model.input_column}', which drive '{drive.name}' does not carry in its rfid readings"
        )
    for field in READING_FIELDS:
        if field not in models and (~own & np.isfinite(rfid[field])).any():
            models[field] = default_model_for(drive, field)
    return models


def ranges_by_field(models: dict[str, RangeModel], rfid: Channel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distance, 1-sigma and field of each reading, from the first field of ``models`` the reading carries.

    Returns
    -------
    distance_m, sigma_m : arrays
        NaN for a reading that carries none of the fields (or that its
        model cannot convert).
    field : array of int
        Index into ``models`` of the field each reading was taken from,
        -1 for none.
    """
    n = len(rfid)
    distance, sigma, field = np.full(n, np.nan), np.full(n, np.nan), np.full(n, -1)
    for i, (name, model) in enumerate(models.items()):
        rows = (field < 0) & np.isfinite(rfid[name])
        if rows.any():
            distance[rows] = model.predict_distance_m(rfid[name][rows])
            sigma[rows] = model.predict_sigma_m(distance[rows])
            field[rows] = i
    return distance, sigma, field


def true_ranges_m(drive: Drive) -> np.ndarray:
    """True reader-tag distance of every RFID reading.

    :func:`graphpos.io.checks.true_ranges_m`, with errors for a drive that
    has no readings or no truth.

    Raises
    ------
    MissingChannelError
        No ``rfid`` channel.
    ConfigError
        Neither true ranges nor a truth trajectory.
    """
    if not drive.has("rfid"):
        raise MissingChannelError(f"drive '{drive.name}' has no RFID readings to fit a range model to")
    true_m = truth_distances_m(drive)
    if not np.isfinite(true_m).any():
        raise ConfigError(
            f"drive '{drive.name}' has no truth: neither true ranges (rfid.true_range_m) nor a truth trajectory"
        )
    return true_m


def fit_from_drive(drive: Drive, kind: str = "auto", **options: Any) -> RangeModel:
    """Fit a range model to a drive's readings against its true ranges.

    Parameters
    ----------
    drive : Drive
        Needs RFID readings and truth (true ranges or a truth trajectory).
    kind : {"auto", "lssvm", "propagation", "linear"}
        ``auto``: ``linear`` when the radio reports ranges, else ``lssvm``.
    **options
        Passed to the model's constructor (e.g. ``seed`` for the LSSVM).
    """
    if kind not in FIT_KINDS:
        raise ConfigError(f"unknown range-model kind '{kind}' (known: {', '.join(FIT_KINDS)})")
    true_m = true_ranges_m(drive)
    if kind == "auto":
        kind = "linear" if drive.reports_ranges else "lssvm"
    model = LinearCalibration(**options) if kind == "linear" else _RSS_KINDS[kind](**options)
    reading = drive.rfid[model.input_column]
    if not np.isfinite(reading).any():
        raise ConfigError(f"drive '{drive.name}' has no '{model.input_column}' readings for a {kind} range model")
    return model.fit(reading, true_m)
