"""Per-frame tracker input: world-frame vision points and tactile contacts at one timestamp.

A :class:`TrackingFrame` is what a live pipeline (or :mod:`vtrack.tracking.frontend` reading a
session) hands to ``tracker.step(frame)``. Everything is in the **world** frame, metres:

- ``vision_points``: object surface points from depth (segmented), (N, 3), or ``None``.
- ``touch_points`` / ``touch_normals``: contact points on the object surface and the object's
  *outward* surface normals there (= minus the gel normal of the tactile frame), (M, 3) each.
- ``free_points``: points on gel surfaces of sensors that are **not** in contact (K, 3); the
  object must not penetrate them (non-penetration residual).

:func:`sanitize` drops non-finite rows, subsamples to budgets and never raises on empty inputs.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vtrack.errors import InputError
from vtrack.geometry.pointcloud import as_points, row_norms


@dataclass
class TrackingFrame:
    """Observations of one time step (world frame, metres, seconds)."""

    t: float
    vision_points: np.ndarray | None = None
    touch_points: np.ndarray | None = None
    touch_normals: np.ndarray | None = None
    free_points: np.ndarray | None = None
    info: dict = field(default_factory=dict)

    @property
    def n_vision(self) -> int:
        return 0 if self.vision_points is None else len(self.vision_points)

    @property
    def n_touch(self) -> int:
        return 0 if self.touch_points is None else len(self.touch_points)


def _rows(a: np.ndarray | None, name: str) -> np.ndarray:
    """(N, 3) float64 points (a missing stream is no points); validation by the geometry layer's ``as_points``."""
    return np.zeros((0, 3)) if a is None else as_points(a, name)


def _subsample(n: int, budget: int, rng: np.random.Generator) -> np.ndarray:
    if budget <= 0:
        return np.zeros(0, dtype=np.int64)
    if n <= budget:
        return np.arange(n)
    return np.sort(rng.choice(n, budget, replace=False))


def sanitize(
    frame: TrackingFrame, max_vision: int = 400, max_touch: int = 160, max_free: int = 64, seed: int = 0
) -> TrackingFrame:
    """A copy of ``frame`` with finite rows only, subsampled to the given budgets.

    Raises:
        InputError: the timestamp is not finite, or an array has the wrong shape.
    """
    t = float(frame.t)
    if not np.isfinite(t):
        raise InputError("frame timestamp is not finite", field="frame.t", expected="finite seconds", got=t)
    rng = np.random.default_rng(seed)
    # row gathers with take on flat row indices: numpy's 2-D masked / fancy row indexing is 2-4x slower (same rows)
    V = _rows(frame.vision_points, "vision_points")
    V = V.take(np.flatnonzero(np.isfinite(V).all(1)), 0)
    V = V.take(_subsample(len(V), max_vision, rng), 0)
    P = _rows(frame.touch_points, "touch_points")
    N = _rows(frame.touch_normals, "touch_normals") if frame.touch_normals is not None else np.zeros((0, 3))
    if len(N) != len(P):
        # Normals missing or mismatched: keep the points, drop the normal term (NaN marks it).
        N = np.full(P.shape, np.nan)
    ok = np.flatnonzero(np.isfinite(P).all(1))
    P, N = P.take(ok, 0), N.take(ok, 0)
    nn = row_norms(N)  # = np.linalg.norm(N, axis=1) bit for bit
    good_n = np.isfinite(nn) & (nn > 1e-9)
    N = np.where(good_n[:, None], N / np.where(good_n, nn, 1.0)[:, None], np.nan)
    k = _subsample(len(P), max_touch, rng)
    P, N = P.take(k, 0), N.take(k, 0)
    F = _rows(frame.free_points, "free_points")
    F = F.take(np.flatnonzero(np.isfinite(F).all(1)), 0)
    F = F.take(_subsample(len(F), max_free, rng), 0)
    return TrackingFrame(t=t, vision_points=V, touch_points=P, touch_normals=N, free_points=F, info=dict(frame.info))
