"""Simulated RSS-distance calibration collections (song2016 §6.1).

song2016 §6.1 collects RSS "in the 0-1.5 m range [every] 0.1 m, and in
1.5-9 m range [every] 0.25 m. There are four tags at each collecting location,
and the collecting time is five minutes. The average value of RSS is
considered as the true RSS value of this location." The same is simulated
here from the RSS law the simulated drives obey (:mod:`graphpos.sim.rss`):
four tags, each with its own shadowing offset, read at 1 Hz for 5 minutes at
every distance, in the laboratory, outdoor and tunnel environments.

Deviation: the grid starts at 0.1 m, not 0 m. A tag cannot sit at zero
distance from the antenna, and the log-distance law is undefined there.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from graphpos.errors import ConfigError
from graphpos.sim.rss import ENVIRONMENTS

#: Collecting distances of song2016 §6.1 (m): 0.1-1.5 every 0.1, then 1.75-9 every 0.25.
CALIBRATION_DISTANCES_M = np.round(np.concatenate([np.arange(1, 16) * 0.1, 1.5 + 0.25 * np.arange(1, 31)]), 10)


@dataclass(frozen=True)
class CalibrationCollection:
    """One collection: every tag read at every distance for a while.

    Attributes
    ----------
    environment : str
    distance_m : array (L*T,)
        True distance of each (location, tag) pair.
    tag : array of int (L*T,)
        Tag index (0..T-1) of each pair.
    readings : array (L*T, R)
        The individual 1 Hz RSS readings (0-255, whole units).
    """

    environment: str
    distance_m: np.ndarray
    tag: np.ndarray
    readings: np.ndarray

    @property
    def mean_rss(self) -> np.ndarray:
        """Averaged RSS per (location, tag): the paper's "true RSS value"."""
        return self.readings.mean(axis=1)

    @property
    def reading_distance_m(self) -> np.ndarray:
        """True distance of every individual reading (flattened like ``readings``)."""
        return np.repeat(self.distance_m, self.readings.shape[1])


def simulate_collection(
    environment: str,
    seed: int | Sequence[int],
    n_tags: int = 4,
    duration_s: float = 300.0,
    rate_hz: float = 1.0,
    distances_m: np.ndarray = CALIBRATION_DISTANCES_M,
) -> CalibrationCollection:
    """Simulate one calibration collection (seeded: same seed, same data).

    Parameters
    ----------
    environment : str
        A key of :data:`graphpos.sim.rss.ENVIRONMENTS`.
    seed : int or sequence of int
        Draws the tags' shadowing and every reading's fading
        (``numpy.random.default_rng(seed)``).
    n_tags : int
        Tags read at each location (song2016: four).
    duration_s, rate_hz : float
        Collecting time and reading rate (song2016: five minutes at 1 Hz).
    distances_m : array
        Collecting distances.
    """
    if environment not in ENVIRONMENTS:
        raise ConfigError(f"unknown RSS environment '{environment}' (known: {', '.join(ENVIRONMENTS)})")
    env = ENVIRONMENTS[environment]
    rng = np.random.default_rng(seed)
    n_readings = max(int(round(duration_s * rate_hz)), 1)
    offsets_db = env.draw_tag_offsets_db(n_tags, rng)
    distance = np.repeat(np.asarray(distances_m, dtype=np.float64), n_tags)
    tag = np.tile(np.arange(n_tags), len(distances_m))
    readings = env.sample_rss(
        np.repeat(distance[:, None], n_readings, axis=1), rng, tag_offset_db=offsets_db[tag][:, None]
    )
    return CalibrationCollection(environment, distance, tag, readings)
