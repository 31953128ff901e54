"""The RSS law: received signal strength (normalised 0-255) against distance.

One law serves the simulated drives and the simulated calibration data of
song2016 §6.1 (issue 3), so a range model fitted on the calibration data is
fitted to the law the drives obey.

The law is a log-distance path loss (song2016 §3, Friis in its log form)
plus a deterministic multipath ripple (a two-ray-like interference pattern
that depends on the environment's geometry, so averaging does not remove it
and a log-distance fit cannot follow it; this is what LSSVM learns), plus
per-tag shadowing and per-reading fast fading::

    P_dB(d)  = -10 n log10(d / 1 m) + ripple_db * sin(2 pi d / ripple_period_m + phase) * exp(-d / ripple_decay_m)
    RSS(d)   = clip(rss_at_1m + units_per_db * (P_dB(d) + shadowing + fading), 0, 255)

Beyond ``reliable_range_m`` the reading deteriorates (song2016 §6.1: "the RSS
signal will deteriorate beyond 6 m"): fading grows linearly to twice its
value at ``max_range_m``, where the tag is no longer heard.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class RssEnvironment:
    """Parameters of the RSS law in one environment.

    Attributes
    ----------
    rss_at_1m : float
        Mean RSS (0-255 units) at 1 m.
    path_loss_exponent : float
        n of the log-distance law.
    units_per_db : float
        RSS units per dB of received power.
    ripple_db, ripple_period_m, ripple_phase_rad, ripple_decay_m : float
        Deterministic multipath interference term.
    shadowing_db : float
        1-sigma of a per-tag constant offset (tag-to-tag spread).
    fading_db : float
        1-sigma of per-reading fast fading within the reliable range.
    reliable_range_m, max_range_m : float
        song2016 §6.1: reliable within 6 m, heard up to 9 m.
    """

    rss_at_1m: float
    path_loss_exponent: float
    units_per_db: float
    ripple_db: float
    ripple_period_m: float
    ripple_phase_rad: float
    ripple_decay_m: float
    shadowing_db: float
    fading_db: float
    reliable_range_m: float = 6.0
    max_range_m: float = 9.0

    def mean_rss(self, distance_m: np.ndarray) -> np.ndarray:
        """Noise-free RSS at a distance (unclipped)."""
        d = np.maximum(np.asarray(distance_m, dtype=np.float64), 0.05)
        p_db = -10.0 * self.path_loss_exponent * np.log10(d) + self.ripple_db * np.sin(
            2 * np.pi * d / self.ripple_period_m + self.ripple_phase_rad
        ) * np.exp(-d / self.ripple_decay_m)
        return self.rss_at_1m + self.units_per_db * p_db

    def fading_sigma_db(self, distance_m: np.ndarray) -> np.ndarray:
        """Per-reading fading 1-sigma, growing beyond the reliable range."""
        d = np.asarray(distance_m, dtype=np.float64)
        excess = np.clip((d - self.reliable_range_m) / (self.max_range_m - self.reliable_range_m), 0.0, None)
        return self.fading_db * (1.0 + excess)

    def sample_rss(
        self,
        distance_m: np.ndarray,
        rng: np.random.Generator,
        tag_offset_db: np.ndarray | float = 0.0,
        n_average: int = 1,
    ) -> np.ndarray:
        """Noisy RSS readings, clipped to 0-255 and rounded to whole units.

        Parameters
        ----------
        distance_m : array
            True tag-reader distances.
        rng : numpy Generator
        tag_offset_db : array or float
            Per-tag shadowing already drawn (see :meth:`draw_tag_offsets_db`).
        n_average : int
            Readings averaged into one (calibration collections average many;
            the averaged fading shrinks by sqrt(n)).
        """
        d = np.asarray(distance_m, dtype=np.float64)
        fading = rng.standard_normal(d.shape) * self.fading_sigma_db(d) / np.sqrt(n_average)
        rss = self.mean_rss(d) + self.units_per_db * (np.asarray(tag_offset_db) + fading)
        return np.clip(np.round(rss), 0.0, 255.0)

    def draw_tag_offsets_db(self, n_tags: int, rng: np.random.Generator) -> np.ndarray:
        """Per-tag shadowing offsets (dB)."""
        return rng.standard_normal(n_tags) * self.shadowing_db


#: Calibration environments of song2016 §6.1, in order of increasing multipath.
#: The ripple is kept small enough that the mean law stays monotonic in
#: 0.05-9 m (so distance is a function of RSS, as the paper's regression assumes).
ENVIRONMENTS: dict[str, RssEnvironment] = {
    "laboratory": RssEnvironment(200.0, 2.0, 3.0, 0.8, 3.0, 0.3, 5.0, 0.8, 1.5),
    "outdoor": RssEnvironment(200.0, 2.0, 3.0, 0.5, 4.0, 1.1, 5.0, 0.6, 1.2),
    "tunnel": RssEnvironment(200.0, 1.8, 3.0, 1.5, 3.5, 0.7, 5.0, 1.0, 2.5),
}
