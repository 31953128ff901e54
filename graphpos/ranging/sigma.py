"""Distance-dependent 1-sigma learned from range residuals.

The filters and the factor graph weight each range by the 1-sigma its
:class:`~graphpos.ranging.model.RangeModel` predicts, so that sigma must be
honest: it is the root-mean-square of residuals (bias included) measured on
data the model was not fitted to (cross-validation folds or a held-out
collection), tabulated against the predicted distance and interpolated
linearly between bins (flat beyond the first and last bin).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from graphpos.errors import ConfigError

#: Smallest sigma a table reports (m): no range is believed to better than this.
SIGMA_FLOOR_M = 0.05


@dataclass(frozen=True)
class SigmaTable:
    """RMS range residual against predicted distance.

    Attributes
    ----------
    distance_m : tuple of float
        Bin centres (median predicted distance in each bin), increasing.
    sigma_m : tuple of float
        RMS residual in each bin (at least :data:`SIGMA_FLOOR_M`).
    """

    distance_m: tuple[float, ...]
    sigma_m: tuple[float, ...]

    def __post_init__(self) -> None:
        if len(self.distance_m) != len(self.sigma_m) or not self.distance_m:
            raise ConfigError("a sigma table needs as many sigmas as distances, at least one")
        d = np.asarray(self.distance_m, dtype=np.float64)
        s = np.asarray(self.sigma_m, dtype=np.float64)
        if not (np.isfinite(d).all() and np.isfinite(s).all()) or np.any(np.diff(d) < 0) or np.any(s <= 0):
            raise ConfigError("a sigma table needs increasing finite distances and positive sigmas")

    @classmethod
    def fit(cls, predicted_m: np.ndarray, true_m: np.ndarray, min_per_bin: int = 50, max_bins: int = 12) -> "SigmaTable":
        """Tabulate the RMS of ``predicted - true`` in quantile bins of the prediction.

        Parameters
        ----------
        predicted_m, true_m : array
            Predicted and true distances of held-out readings (NaN pairs are dropped).
        min_per_bin : int
            Fewest residuals behind one bin's RMS.
        max_bins : int
            Most bins.
        """
        predicted_m = np.asarray(predicted_m, dtype=np.float64)
        true_m = np.asarray(true_m, dtype=np.float64)
        ok = np.isfinite(predicted_m) & np.isfinite(true_m)
        p, t = predicted_m[ok], true_m[ok]
        if p.size < 2:
            raise ConfigError("need at least two held-out residuals to learn a range sigma")
        n_bins = int(np.clip(p.size // min_per_bin, 1, max_bins))
        order = np.argsort(p, kind="stable")
        centres, sigmas = [], []
        for idx in np.array_split(order, n_bins):
            resid = p[idx] - t[idx]
            centres.append(float(np.median(p[idx])))
            sigmas.append(max(float(np.sqrt(np.mean(resid**2))), SIGMA_FLOOR_M))
        return cls(tuple(centres), tuple(sigmas))

    def __call__(self, distance_m: np.ndarray) -> np.ndarray:
        """Sigma at each distance (NaN in, NaN out)."""
        d = np.asarray(distance_m, dtype=np.float64)
        return np.where(np.isfinite(d), np.interp(np.nan_to_num(d), self.distance_m, self.sigma_m), np.nan)

    def to_dict(self) -> dict[str, Any]:
        return {"distance_m": list(self.distance_m), "sigma_m": list(self.sigma_m)}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "SigmaTable":
        return cls(tuple(float(v) for v in data["distance_m"]), tuple(float(v) for v in data["sigma_m"]))
