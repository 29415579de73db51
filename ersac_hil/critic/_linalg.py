"""Cholesky helpers on raw LAPACK: failure is a return value, not an exception."""

from __future__ import annotations

import numpy as np
from scipy.linalg import blas, lapack, solve_triangular


def cholesky(A: np.ndarray) -> np.ndarray | None:
    """Lower Cholesky factor of a symmetric (n, n) matrix, or None if it is not PD."""
    L, info = lapack.dpotrf(A, lower=1, clean=1, overwrite_a=0)
    if info != 0 or not np.all(np.isfinite(np.diagonal(L))):
        return None
    return L


def chol_solve(L: np.ndarray, B: np.ndarray) -> np.ndarray:
    """A^-1 B given the lower factor L of A.  B (n,) or (n, k)."""
    x, info = lapack.dpotrs(L, B, lower=1)
    if info != 0:  # pragma: no cover - only on malformed input
        raise np.linalg.LinAlgError(f"dpotrs info={info}")
    return x


def chol_inverse(L: np.ndarray) -> np.ndarray:
    """Full symmetric A^-1 given the lower factor L of A, (n, n)."""
    inv, info = lapack.dpotri(L, lower=1)
    if info != 0:  # pragma: no cover
        raise np.linalg.LinAlgError(f"dpotri info={info}")
    inv = np.tril(inv)
    return inv + np.tril(inv, -1).T


def tri_solve(L: np.ndarray, B: np.ndarray) -> np.ndarray:
    """L^-1 B for lower-triangular L."""
    return blas.dtrsm(1.0, L, B, lower=1) if B.ndim == 2 else solve_triangular(L, B, lower=True, check_finite=False)


def logdet(L: np.ndarray) -> float:
    """log|A| from its lower Cholesky factor."""
    return 2.0 * float(np.log(np.diagonal(L)).sum())


def tri_inverse(L: np.ndarray) -> np.ndarray:
    """L^-1 for lower-triangular L (LAPACK dtrtri)."""
    Li, info = lapack.dtrtri(L, lower=1)
    if info != 0:  # pragma: no cover
        raise np.linalg.LinAlgError(f"dtrtri info={info}")
    return Li
