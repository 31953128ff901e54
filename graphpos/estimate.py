"""The one output type every estimator returns."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

#: CSV / export columns, in order (issue 4: `graphpos run` output).
CSV_COLUMNS = (
    "t_s",
    "east_m",
    "north_m",
    "v_east_mps",
    "v_north_mps",
    "yaw_rad",
    "var_east_m2",
    "var_north_m2",
    "cov_en_m2",
)


@dataclass(frozen=True)
class OutputRow:
    """One output epoch of an online estimator.

    ``v_east_mps``, ``v_north_mps`` and ``yaw_rad`` are None where the
    estimator does not estimate them; ``cov_en_m2`` is the 2x2 east/north
    position covariance, or None.
    """

    t_s: float
    east_m: float
    north_m: float
    v_east_mps: float | None = None
    v_north_mps: float | None = None
    yaw_rad: float | None = None
    cov_en_m2: np.ndarray | None = None

    def to_dict(self) -> dict[str, Any]:
        """The row as JSON values: None for a quantity not estimated (or NaN), ``cov_en_m2`` row-major [ee, en, ne, nn]."""

        def number(x: float | None) -> float | None:
            return None if x is None or x != x else float(x)

        cov = None if self.cov_en_m2 is None else [number(v) for v in np.asarray(self.cov_en_m2).reshape(-1)]
        return {"t_s": float(self.t_s), "east_m": float(self.east_m), "north_m": float(self.north_m), "v_east_mps": number(self.v_east_mps),
                "v_north_mps": number(self.v_north_mps), "yaw_rad": number(self.yaw_rad), "cov_en_m2": cov}


@dataclass(frozen=True, eq=False)
class Estimate:
    """A trajectory estimate.

    Parameters
    ----------
    name : str
        The estimator's name (``fusion-ekf``, ``graph-batch`` ...).
    t_s, east_m, north_m : (N,) arrays
        Output epochs and positions.
    v_east_mps, v_north_mps, yaw_rad : (N,) arrays or None
        None where the estimator does not estimate the quantity.
    cov_en_m2 : (N, 2, 2) array or None
        East/north position covariance.
    rate_hz : float
        Nominal output rate.
    diagnostics : dict
        JSON-serialisable counters and figures (gated ranges, isolations,
        model probabilities ...).
    wall_time_s : float
        Processing time of ``run``.
    """

    name: str
    t_s: np.ndarray
    east_m: np.ndarray
    north_m: np.ndarray
    v_east_mps: np.ndarray | None = None
    v_north_mps: np.ndarray | None = None
    yaw_rad: np.ndarray | None = None
    cov_en_m2: np.ndarray | None = None
    rate_hz: float = float("nan")
    diagnostics: dict[str, Any] = field(default_factory=dict)
    wall_time_s: float = float("nan")

    def __post_init__(self) -> None:
        n = np.asarray(self.t_s).shape[0]
        for name in ("t_s", "east_m", "north_m", "v_east_mps", "v_north_mps", "yaw_rad"):
            arr = getattr(self, name)
            if arr is None:
                continue
            arr = np.asarray(arr, dtype=np.float64).reshape(-1)
            if arr.shape[0] != n:
                raise ValueError(f"Estimate.{name} has {arr.shape[0]} rows, t_s has {n}")
            object.__setattr__(self, name, arr)
        if self.cov_en_m2 is not None:
            cov = np.asarray(self.cov_en_m2, dtype=np.float64)
            if cov.shape != (n, 2, 2):
                raise ValueError(f"Estimate.cov_en_m2 has shape {cov.shape}, expected ({n}, 2, 2)")
            object.__setattr__(self, "cov_en_m2", cov)

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    @property
    def has_velocity(self) -> bool:
        return self.v_east_mps is not None and self.v_north_mps is not None

    @property
    def position(self) -> np.ndarray:
        """(N, 2) east/north."""
        return np.column_stack([self.east_m, self.north_m])

    @classmethod
    def from_rows(cls, name: str, rows: Sequence[OutputRow], **kwargs: Any) -> "Estimate":
        """Assemble an estimate from online output rows.

        A quantity is kept only if every row has it.
        """

        def column(attr: str) -> np.ndarray | None:
            values = [getattr(r, attr) for r in rows]
            if not values or any(v is None for v in values):
                return None
            return np.asarray(values, dtype=np.float64)

        cov = None
        if rows and all(r.cov_en_m2 is not None for r in rows):
            cov = np.stack([np.asarray(r.cov_en_m2, dtype=np.float64) for r in rows])
        return cls(
            name=name,
            t_s=np.asarray([r.t_s for r in rows], dtype=np.float64),
            east_m=np.asarray([r.east_m for r in rows], dtype=np.float64),
            north_m=np.asarray([r.north_m for r in rows], dtype=np.float64),
            v_east_mps=column("v_east_mps"),
            v_north_mps=column("v_north_mps"),
            yaw_rad=column("yaw_rad"),
            cov_en_m2=cov,
            **kwargs,
        )

    def rows(self) -> list[OutputRow]:
        """The output rows (:meth:`from_rows` inverted; None where the estimate lacks a quantity)."""
        optional = [getattr(self, f) for f in ("v_east_mps", "v_north_mps", "yaw_rad")]
        return [
            OutputRow(float(self.t_s[i]), float(self.east_m[i]), float(self.north_m[i]),
                      *(None if col is None else float(col[i]) for col in optional),
                      None if self.cov_en_m2 is None else self.cov_en_m2[i])
            for i in range(len(self))
        ]

    def with_wall_time(self, wall_time_s: float) -> "Estimate":
        """The same estimate, stamped with the processing time of its run."""
        return dataclasses.replace(self, wall_time_s=wall_time_s)

    def table(self) -> dict[str, np.ndarray]:
        """Columns of :data:`CSV_COLUMNS`; NaN where not estimated."""
        n = len(self)
        nan = np.full(n, np.nan)
        cov = self.cov_en_m2
        return {
            "t_s": self.t_s,
            "east_m": self.east_m,
            "north_m": self.north_m,
            "v_east_mps": self.v_east_mps if self.v_east_mps is not None else nan,
            "v_north_mps": self.v_north_mps if self.v_north_mps is not None else nan,
            "yaw_rad": self.yaw_rad if self.yaw_rad is not None else nan,
            "var_east_m2": cov[:, 0, 0] if cov is not None else nan,
            "var_north_m2": cov[:, 1, 1] if cov is not None else nan,
            "cov_en_m2": cov[:, 0, 1] if cov is not None else nan,
        }
