"""What the RSS-based range models share: input column, learned sigma, clean inputs."""

from __future__ import annotations

from abc import abstractmethod
from typing import ClassVar

import numpy as np

from graphpos.errors import ConfigError
from graphpos.ranging.model import RangeModel
from graphpos.ranging.sigma import SigmaTable


class RssRangeModel(RangeModel):
    """A model reading the ``rss`` column (0-255) whose sigma is a :class:`SigmaTable`.

    Subclasses set ``sigma_table`` in :meth:`fit` from residuals the model was
    not fitted to (or, for a two-parameter law, its in-sample residuals).
    """

    input_column: ClassVar[str] = "rss"
    sigma_table: SigmaTable | None = None
    #: Smallest and largest training reading; readings are clamped to it.
    input_range: tuple[float, float]

    def fit_sigma(self, reading: np.ndarray, true_distance_m: np.ndarray) -> "RssRangeModel":
        """Re-learn the range sigma from held-out readings (e.g. a fresh collection)."""
        self._require_fitted()
        self.sigma_table = SigmaTable.fit(self.predict_distance_m(reading), true_distance_m)
        return self

    def predict_sigma_m(self, distance_m: np.ndarray) -> np.ndarray:
        if self.sigma_table is None:
            raise ConfigError(f"this {self.kind} range model's sigma has not been learned (fit it first)")
        return self.sigma_table(distance_m)

    @abstractmethod
    def _is_fitted(self) -> bool:
        """True once the distance function has parameters."""

    def _require_fitted(self) -> None:
        if not self._is_fitted():
            raise ConfigError(f"this {self.kind} range model has not been fitted")


def clean_pairs(reading: np.ndarray, true_distance_m: np.ndarray, need: int) -> tuple[np.ndarray, np.ndarray]:
    """Finite (reading, distance) pairs as float arrays; a clear error when too few."""
    x = np.asarray(reading, dtype=np.float64).reshape(-1)
    y = np.asarray(true_distance_m, dtype=np.float64).reshape(-1)
    if x.shape != y.shape:
        raise ConfigError(f"{x.size} readings but {y.size} true distances")
    ok = np.isfinite(x) & np.isfinite(y)
    if ok.sum() < need:
        raise ConfigError(f"need at least {need} readings with true distances to fit a range model, got {int(ok.sum())}")
    return x[ok], y[ok]
