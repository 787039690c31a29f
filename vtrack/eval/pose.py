"""Pose metrics for tracking: ADD and ADD-S (symmetric), in metres, over model points (object frame)."""

from __future__ import annotations

import numpy as np

from vtrack.geometry.pointcloud import as_points


def _apply(T: np.ndarray, P: np.ndarray) -> np.ndarray:
    return P @ T[:3, :3].T + T[:3, 3]


def add(T_est: np.ndarray, T_gt: np.ndarray, model_points: np.ndarray) -> float:
    """Average distance (m) of corresponding model points under the estimated and true pose."""
    P = as_points(model_points, "model_points")
    if len(P) == 0:
        return 0.0
    return float(np.linalg.norm(_apply(np.asarray(T_est), P) - _apply(np.asarray(T_gt), P), axis=1).mean())


def adds(T_est: np.ndarray, T_gt: np.ndarray, model_points: np.ndarray) -> float:
    """ADD-S (m): mean distance from each true-pose model point to the closest estimated-pose point."""
    from scipy.spatial import cKDTree

    P = as_points(model_points, "model_points")
    if len(P) == 0:
        return 0.0
    A = _apply(np.asarray(T_est), P)
    B = _apply(np.asarray(T_gt), P)
    d, _ = cKDTree(A).query(B)
    return float(d.mean())
