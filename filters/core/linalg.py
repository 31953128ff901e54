"""Small dense linear algebra of the filters' hot paths, called through LAPACK directly.

``numpy.linalg``'s wrappers cost 3-10 us a call on the 2x2 to 21x21
matrices of the filters (argument checks, an ``errstate`` context), several
times the factorisation itself; ``scipy.linalg.lapack``'s wrappers cost
about 1 us. The results are LAPACK's, as numpy's: :func:`cholesky_lower` is
``np.linalg.cholesky`` to the bit; :func:`solve_spd` solves through the
Cholesky factor (``dposv``) instead of an LU factorisation, which differs
from ``np.linalg.solve`` in rounding only.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import lapack


def cholesky_lower(A: np.ndarray) -> np.ndarray | None:
    """Lower Cholesky factor of a symmetric positive-definite ``A`` (its lower
    triangle is read), or None when ``A`` is not positive definite."""
    L, info = lapack.dpotrf(A, lower=1, clean=1)
    return L if info == 0 else None


def solve_spd(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A^-1 B`` for a symmetric positive-definite ``A`` (its upper triangle
    is read), through its Cholesky factor; by LU (``np.linalg.solve``) when
    ``A`` is not positive definite."""
    return solve_spd_logdet(A, B)[0]


def solve_spd_logdet(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, float]:
    """:func:`solve_spd` and ``log det A``, the latter from the same Cholesky
    factor (``2 sum log diag``; ``np.linalg.slogdet`` when ``A`` is not
    positive definite)."""
    factor, X, info = lapack.dposv(A, B)
    if info != 0:
        return np.linalg.solve(A, B), float(np.linalg.slogdet(A)[1])
    return X, 2.0 * float(np.log(factor.diagonal()).sum())
