"""Propagation-model baseline: log-distance (Friis) law ``RSS = A - 10 n log10(d)``.

song2016 §6.1 compares LSSVM with "the propagation model-based algorithm
utilising Friis transmission equation"; in its log form Friis is the
log-distance law above (free space: n = 2). ``A`` (RSS at 1 m) and ``n`` are
fitted by linear least squares in RSS, and the law is inverted for distance:
``d = 10^((A - RSS) / (10 n))``. As for the LSSVM, a reading is first clamped
to the training range (a clipped RSS of 0 would otherwise mean kilometres).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from graphpos.errors import ConfigError
from graphpos.ranging.model import register
from graphpos.ranging.rss_model import RssRangeModel, clean_pairs
from graphpos.ranging.sigma import SigmaTable


@register
class PropagationRangeModel(RssRangeModel):
    """RSS -> distance by the inverted log-distance law.

    Parameters
    ----------
    rss_at_1m : float
        A, the RSS at 1 m.
    path_loss_exponent : float
        n, in RSS units: the law is fitted to the 0-255 readings, not to dBm,
        so n is the physical exponent times the radio's RSS units per dB
        (about 3 in :mod:`graphpos.sim.rss`: a free-space n of 2 fits as 6).
    """

    kind = "propagation"

    def __init__(self, rss_at_1m: float = np.nan, path_loss_exponent: float = np.nan):
        self.rss_at_1m = float(rss_at_1m)
        self.path_loss_exponent = float(path_loss_exponent)
        self.input_range = (np.nan, np.nan)
        self.sigma_table: SigmaTable | None = None

    def fit(self, reading: np.ndarray, true_distance_m: np.ndarray) -> "PropagationRangeModel":
        rss, d = clean_pairs(reading, true_distance_m, need=2)
        if np.any(d <= 0):
            raise ConfigError("the log-distance law needs positive true distances")
        design = np.column_stack([np.ones_like(d), -10.0 * np.log10(d)])
        (a, n), *_ = np.linalg.lstsq(design, rss, rcond=None)
        if not n > 0:
            raise ConfigError(f"fitted path-loss exponent {n:.3g} is not positive: RSS does not fall with distance in these data")
        self.rss_at_1m, self.path_loss_exponent = float(a), float(n)
        self.input_range = (float(rss.min()), float(rss.max()))
        # two parameters: in-sample residuals are an honest estimate of the spread
        self.sigma_table = SigmaTable.fit(self.predict_distance_m(rss), d)
        return self

    def _is_fitted(self) -> bool:
        return bool(np.isfinite(self.input_range[0]))

    def predict_rss(self, distance_m: np.ndarray) -> np.ndarray:
        """The fitted law's RSS at a distance."""
        return self.rss_at_1m - 10.0 * self.path_loss_exponent * np.log10(np.asarray(distance_m, dtype=np.float64))

    def predict_distance_m(self, reading: np.ndarray) -> np.ndarray:
        self._require_fitted()
        rss = np.clip(np.asarray(reading, dtype=np.float64), *self.input_range)
        return 10.0 ** ((self.rss_at_1m - rss) / (10.0 * self.path_loss_exponent))

    def to_dict(self) -> dict[str, Any]:
        self._require_fitted()
        return {
            "rss_at_1m": self.rss_at_1m,
            "path_loss_exponent": self.path_loss_exponent,
            "input_range": list(self.input_range),
            "sigma_table": self.sigma_table.to_dict(),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "PropagationRangeModel":
        model = cls(float(data["rss_at_1m"]), float(data["path_loss_exponent"]))
        if not model.path_loss_exponent > 0:
            raise ValueError("path_loss_exponent must be positive")
        lo, hi = (float(v) for v in data["input_range"])
        model.input_range = (lo, hi)
        model.sigma_table = SigmaTable.from_dict(data["sigma_table"])
        return model
