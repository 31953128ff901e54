"""LSSVM regression from RSS to distance (song2016 §3, eq. 1-9).

The model is ``f(x) = sum_k alpha_k K(x, x_k) + b`` (song2016 eq. 9) with the
RBF kernel ``K(x, x_k) = exp(-|x - x_k|^2 / (2 sigma^2))`` (eq. 8); ``b`` and
``alpha`` solve the bordered (N+1)x(N+1) linear system of eq. 6, obtained from
the KKT conditions (eq. 5) of the regularised least-squares problem (eq. 2-4).
The system is solved directly (block elimination with a Cholesky
factorisation; see :func:`solve_lssvm`), not by an iterative fit.

The paper says gamma and sigma are "determined during the training"; here
they are chosen by k-fold cross-validation (mean squared out-of-fold error)
over a log grid.

Deviations, each for a stated reason:

- Above ``max_train_samples`` (5000) readings the final fit uses a seeded
  random subsample of that size, and cross-validation a subsample of
  ``cv_samples``: eq. 6 is dense, O(N^3) to solve and O(N^2) in memory, and a
  fit must stay under 10 s. With 1-D input a few thousand samples already
  cover the curve densely.
- Inputs are clamped to the training range before eq. 9 is evaluated: the
  RBF expansion decays to ``b`` (a mid-range distance) away from the data, so
  a reading weaker than any training reading would otherwise map to a short
  distance. Predicted distances are clamped at zero.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.linalg
from threadpoolctl import threadpool_limits

from graphpos.errors import ConfigError
from graphpos.ranging.model import register
from graphpos.ranging.rss_model import RssRangeModel, clean_pairs
from graphpos.ranging.sigma import SigmaTable

#: Regularisation constants tried by cross-validation (song2016 eq. 2's gamma).
GAMMA_GRID = np.logspace(-1.0, 5.0, 7)
#: Kernel widths tried, as multiples of the training inputs' standard deviation.
KERNEL_SIGMA_FACTORS = np.logspace(-2.0, 0.5, 8)


def rbf_kernel(x_a: np.ndarray, x_b: np.ndarray, kernel_sigma: float) -> np.ndarray:
    """Kernel matrix ``K(x_a[i], x_b[j])`` of song2016 eq. 7-8 for scalar inputs."""
    return np.exp(-np.subtract.outer(x_a, x_b) ** 2 / (2.0 * kernel_sigma**2))


def solve_lssvm(x: np.ndarray, y: np.ndarray, gamma: float, kernel_sigma: float) -> tuple[float, np.ndarray]:
    """Solve song2016 eq. 6 for the bias ``b`` and multipliers ``alpha``.

    ``[[0, 1^T], [1, H]] [b; alpha] = [0; Y]`` with ``H = Omega + I/gamma``.
    The bordered matrix is symmetric indefinite, but ``H`` is positive
    definite, so the system is solved exactly by block elimination with one
    Cholesky factorisation of ``H`` (half the work of LU on the bordered
    matrix): ``b = 1^T H^-1 Y / 1^T H^-1 1``, ``alpha = H^-1 Y - b H^-1 1``.

    Returns
    -------
    b : float
    alpha : array (N,)
    """
    h = rbf_kernel(x, x, kernel_sigma)
    h[np.diag_indices_from(h)] += 1.0 / gamma
    factor = scipy.linalg.cho_factor(h, lower=True, overwrite_a=True, check_finite=False)
    h_inv_y, h_inv_1 = scipy.linalg.cho_solve(factor, np.column_stack([y, np.ones_like(y)]), check_finite=False).T
    b = float(h_inv_y.sum() / h_inv_1.sum())
    return b, h_inv_y - b * h_inv_1


def fold_predictions(
    x_train: np.ndarray, y_train: np.ndarray, x_test: np.ndarray, kernel_sigma: float, gammas: np.ndarray
) -> np.ndarray:
    """eq. 9 at ``x_test`` of the eq. 6 solutions for every gamma, shape (len(gammas), len(x_test)).

    Solved through the eigendecomposition ``Omega = U diag(lam) U^T``: with
    ``H = Omega + I/gamma``, eliminating ``alpha`` from eq. 6 gives
    ``b = 1^T H^-1 Y / 1^T H^-1 1`` and ``alpha = H^-1 (Y - b 1)`` — the same
    solution as :func:`solve_lssvm`, but one decomposition serves every gamma.
    """
    lam, u = np.linalg.eigh(rbf_kernel(x_train, x_train, kernel_sigma))
    ut_y, ut_1 = u.T @ y_train, u.sum(axis=0)
    k_test_u = rbf_kernel(x_test, x_train, kernel_sigma) @ u
    out = np.empty((len(gammas), x_test.size))
    for g, gamma in enumerate(gammas):
        h = 1.0 / (np.maximum(lam, 0.0) + 1.0 / gamma)
        b = (ut_1 * h) @ ut_y / ((ut_1 * h) @ ut_1)
        out[g] = k_test_u @ (h * (ut_y - b * ut_1)) + b
    return out


def _cross_validate(
    x: np.ndarray, y: np.ndarray, folds: int, rng: np.random.Generator
) -> tuple[float, float, np.ndarray]:
    """k-fold CV over the (gamma, sigma) grid (mean squared out-of-fold error).

    Returns the best gamma, the best kernel sigma and the out-of-fold
    predictions at that pair (for learning the range sigma honestly).
    """
    fold_of = rng.permutation(x.size) % folds
    spread = float(np.std(x)) or 1.0
    best = (np.inf, 0.0, 0.0, np.empty(0))
    for kernel_sigma in spread * KERNEL_SIGMA_FACTORS:
        out_of_fold = np.empty((GAMMA_GRID.size, x.size))
        for fold in range(folds):
            test = fold_of == fold
            out_of_fold[:, test] = fold_predictions(x[~test], y[~test], x[test], kernel_sigma, GAMMA_GRID)
        mse = np.mean((out_of_fold - y) ** 2, axis=1)
        g = int(np.argmin(mse))
        if mse[g] < best[0]:
            best = (float(mse[g]), float(GAMMA_GRID[g]), float(kernel_sigma), out_of_fold[g])
    return best[1], best[2], best[3]


@register
class LssvmRangeModel(RssRangeModel):
    """RSS (0-255) -> distance by LSSVM regression (song2016 eq. 1-9).

    Parameters
    ----------
    gamma, kernel_sigma : float, optional
        Fixed hyper-parameters; when both are given :meth:`fit` skips the
        cross-validation (the range sigma then comes from in-sample residuals).
        A model loaded from a file keeps the hyper-parameters it was saved with.
    folds : int
        k of the k-fold cross-validation.
    seed : int
        Seeds the fold assignment and the subsampling.
    max_train_samples : int
        Largest training set solved exactly; larger ones are subsampled.
    cv_samples : int
        Largest set the hyper-parameter search runs on.
    """

    kind = "lssvm"

    def __init__(
        self,
        gamma: float | None = None,
        kernel_sigma: float | None = None,
        folds: int = 5,
        seed: int = 0,
        max_train_samples: int = 5000,
        cv_samples: int = 400,
    ):
        if (gamma is None) != (kernel_sigma is None):
            raise ConfigError("give both gamma and kernel_sigma, or neither (cross-validation picks them)")
        if gamma is not None and not (gamma > 0 and kernel_sigma > 0):
            raise ConfigError(f"gamma and kernel_sigma must be positive, got {gamma}, {kernel_sigma}")
        if folds < 2:
            raise ConfigError(f"cross-validation needs at least 2 folds, got {folds}")
        self.gamma = gamma
        self.kernel_sigma = kernel_sigma
        self._search = gamma is None  # re-fitting searches again unless fixed by the caller
        self.folds = int(folds)
        self.seed = int(seed)
        self.max_train_samples = int(max_train_samples)
        self.cv_samples = int(cv_samples)
        self.support_x = np.empty(0)
        self.alpha = np.empty(0)
        self.bias_m = 0.0
        self.sigma_table: SigmaTable | None = None

    # -- fitting -------------------------------------------------------------
    def fit(self, reading: np.ndarray, true_distance_m: np.ndarray) -> "LssvmRangeModel":
        # one BLAS thread: the many small decompositions of the cross-validation
        # only suffer from threads, and fits often run inside process pools
        with threadpool_limits(limits=1, user_api="blas"):
            return self._fit(reading, true_distance_m)

    def _fit(self, reading: np.ndarray, true_distance_m: np.ndarray) -> "LssvmRangeModel":
        x, y = clean_pairs(reading, true_distance_m, need=max(2 * self.folds, 3))
        rng = np.random.default_rng(self.seed)
        if x.size > self.max_train_samples:
            keep = np.sort(rng.choice(x.size, self.max_train_samples, replace=False))
            x, y = x[keep], y[keep]
        held_out = None
        if self._search:
            cv = np.sort(rng.choice(x.size, self.cv_samples, replace=False)) if x.size > self.cv_samples else np.arange(x.size)
            self.gamma, self.kernel_sigma, out_of_fold = _cross_validate(x[cv], y[cv], self.folds, rng)
            held_out = (np.maximum(out_of_fold, 0.0), y[cv])
        self.bias_m, self.alpha = solve_lssvm(x, y, self.gamma, self.kernel_sigma)
        self.support_x = x
        if held_out is None:  # fixed hyper-parameters: in-sample residuals
            held_out = (self.predict_distance_m(x), y)
        self.sigma_table = SigmaTable.fit(*held_out)
        return self

    # -- prediction ----------------------------------------------------------
    def _is_fitted(self) -> bool:
        return self.support_x.size > 0

    @property
    def input_range(self) -> tuple[float, float]:
        """Smallest and largest training reading (inputs are clamped to it)."""
        self._require_fitted()
        return float(self.support_x.min()), float(self.support_x.max())

    def predict_distance_m(self, reading: np.ndarray) -> np.ndarray:
        """song2016 eq. 9 on the clamped reading (NaN in, NaN out)."""
        self._require_fitted()
        x = np.asarray(reading, dtype=np.float64)
        out = np.full(x.shape, np.nan)
        ok = np.isfinite(x)
        xc = np.clip(x[ok], *self.input_range)
        pred = np.empty(xc.size)
        chunk = max(1, 4_000_000 // max(self.support_x.size, 1))
        for start in range(0, xc.size, chunk):
            part = xc[start : start + chunk]
            pred[start : start + chunk] = rbf_kernel(part, self.support_x, self.kernel_sigma) @ self.alpha + self.bias_m
        out[ok] = np.maximum(pred, 0.0)
        return out

    # -- persistence ---------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        self._require_fitted()
        return {
            "gamma": self.gamma,
            "kernel_sigma": self.kernel_sigma,
            "folds": self.folds,
            "seed": self.seed,
            "max_train_samples": self.max_train_samples,
            "cv_samples": self.cv_samples,
            "support_x": self.support_x.tolist(),
            "alpha": self.alpha.tolist(),
            "bias_m": self.bias_m,
            "sigma_table": self.sigma_table.to_dict(),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "LssvmRangeModel":
        model = cls(
            float(data["gamma"]),
            float(data["kernel_sigma"]),
            int(data["folds"]),
            int(data["seed"]),
            int(data["max_train_samples"]),
            int(data["cv_samples"]),
        )
        model.support_x = np.asarray(data["support_x"], dtype=np.float64)
        model.alpha = np.asarray(data["alpha"], dtype=np.float64)
        if model.support_x.ndim != 1 or model.support_x.size == 0 or model.alpha.shape != model.support_x.shape:
            raise ValueError("support_x and alpha must be equal-length non-empty lists")
        model.bias_m = float(data["bias_m"])
        model.sigma_table = SigmaTable.from_dict(data["sigma_table"])
        return model

