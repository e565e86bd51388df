"""Small dense matrices over lanes: ``(n, n, K)`` arrays, one matrix per lane (last axis).

The batch engine keeps K covariances of a few states each; numpy's stacked ``linalg`` wants
the stack first and pays a call per matrix inside LAPACK, so the factorization is written out
over ``n`` (a few rows) with every operation vectorized over the K lanes.
"""

from __future__ import annotations

import numpy as np

#: The eigenvalue floor of :func:`soc_estimator_ros.estimators.base.condition_covariance`.
EIGEN_FLOOR = 1e-15


def cholesky_lanes(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The lower Cholesky factor of every lane's matrix, and which lanes have one.

    Column by column as LAPACK's unblocked ``dpotf2``: pivot ``d_j = a_jj - sum_k L_jk^2``,
    ``L_jj = sqrt(d_j)``, ``L_ij = (a_ij - sum_k L_ik L_jk) / L_jj`` (k < j), reading the
    lower triangle only. A lane fails, as ``dpotrf`` does, when a pivot is not > 0 (NaN
    included); its factor is then NaN.
    """
    n = a.shape[0]
    low = np.zeros_like(a)
    ok = np.ones(a.shape[2:], dtype=bool)
    with np.errstate(invalid="ignore", divide="ignore"):
        for j in range(n):
            d = a[j, j]
            for k in range(j):
                d = d - low[j, k] * low[j, k]
            ok &= d > 0.0  # NaN fails too
            ljj = np.sqrt(d)  # NaN where d < 0: the failed lane's factor
            low[j, j] = ljj
            for i in range(j + 1, n):
                s = a[i, j]
                for k in range(j):
                    s = s - low[i, k] * low[j, k]
                low[i, j] = s / ljj
    return low, ok


def symmetrize_lanes(p: np.ndarray) -> np.ndarray:
    """``0.5 (P + P^T)`` per lane."""
    return 0.5 * (p + p.swapaxes(0, 1))


def floor_eigenvalues_lanes(p: np.ndarray, floor: float = EIGEN_FLOOR) -> np.ndarray:
    """``condition_covariance``'s repair of a matrix that is not positive definite, per lane:
    eigenvalues floored at ``floor``, ``V diag(w) V^T`` symmetrized (``np.linalg.eigh``)."""
    stack = np.moveaxis(p, 2, 0)  # (K, n, n): numpy's stacked layout
    w, v = np.linalg.eigh(stack)
    w = np.maximum(w, floor)
    out = (v * w[:, np.newaxis, :]) @ v.swapaxes(1, 2)
    out = 0.5 * (out + out.swapaxes(1, 2))
    return np.moveaxis(out, 0, 2)


def condition_lanes(p: np.ndarray) -> np.ndarray:
    """:func:`~soc_estimator_ros.estimators.base.condition_covariance` for every lane:
    symmetrize, and where the Cholesky factorization fails, floor the eigenvalues."""
    p = symmetrize_lanes(p)
    _, ok = cholesky_lanes(p)
    if not ok.all():
        bad = np.flatnonzero(~ok)
        p[:, :, bad] = floor_eigenvalues_lanes(p[:, :, bad])
    return p
