"""Primitive fits to point sets: algebraic sphere / circle, and its robust (trimmed) form.

Units are the caller's (metres for object-frame clouds, pixels for tactile images); nothing here assumes a frame.
"""

from __future__ import annotations

import numpy as np

from vtrack.errors import InputError


def fit_sphere(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Algebraic least-squares sphere (3-D) or circle (2-D) fit: (centre (D,), radius) of (N, D) points.

    Needs N >= D + 1 points not all on one hyperplane; a degenerate set (all on one plane / line: the linear
    system has a lower rank) gives radius ``inf``.
    """
    P = np.asarray(points, np.float64)
    if P.ndim != 2 or P.shape[1] not in (2, 3) or len(P) < P.shape[1] + 1 or not np.isfinite(P).all():
        raise InputError("sphere/circle fit needs >= D+1 finite 2-D or 3-D points", field="points", got=np.shape(P))
    D = P.shape[1]
    mu = P.mean(0)
    Q = P - mu
    scale = max(np.abs(Q).max(), 1e-12)
    Q = Q / scale  # conditioning
    A = np.column_stack([2 * Q, np.ones(len(Q))])
    b = (Q * Q).sum(1)
    sol, _, rank, _ = np.linalg.lstsq(A, b, rcond=None)
    if rank < D + 1:  # the minimum-norm solution of a rank-deficient system is a finite but arbitrary sphere
        return mu, float("inf")
    c = sol[:D]
    r2 = sol[D] + c @ c
    if not np.isfinite(r2) or r2 <= 0:
        return mu, float("inf")
    return c * scale + mu, float(np.sqrt(r2) * scale)


def robust_sphere(
    points: np.ndarray, floor: float, k: float = 2.5, iters: int = 4, min_keep: int = 8
) -> tuple[np.ndarray, float, float, np.ndarray]:
    """:func:`fit_sphere` with outlier rejection: refit on the points whose residual ``| |p - c| - r |`` is below
    ``max(floor, k * median residual of the kept points)`` until the kept set stops changing (at most ``iters``
    rounds, never below ``min_keep`` points). Returns (centre (D,), radius, RMS residual of the kept points, kept
    mask (N,)); the radius is not finite (and the RMS NaN) for a degenerate set. Needs >= D + 1 points."""
    P = np.asarray(points, np.float64)
    keep = np.ones(len(P), bool)
    for _ in range(iters):
        c, r = fit_sphere(P[keep])
        if not np.isfinite(r):
            return c, r, float("nan"), keep
        res = np.abs(np.linalg.norm(P - c, axis=1) - r)
        new = res < max(floor, k * float(np.median(res[keep])))
        if new.sum() < min_keep or (new == keep).all():
            break
        keep = new
    res = np.linalg.norm(P[keep] - c, axis=1) - r
    return c, r, float(np.sqrt(np.mean(res * res))), keep
