"""Point-cloud helpers in numpy/scipy: finite filtering, voxel downsampling, normals.

Points are (N, 3) float arrays in metres. Every function accepts empty clouds and returns
empty outputs of the right shape rather than failing deep inside numpy.
"""

from __future__ import annotations

import numpy as np

from vtrack.errors import InputError


def as_points(points, name: str = "points") -> np.ndarray:
    """Validate and return an (N, 3) float64 array (N may be 0)."""
    P = np.asarray(points, dtype=np.float64)
    if P.size == 0:
        return np.zeros((0, 3))
    if P.ndim != 2 or P.shape[1] != 3:
        raise InputError("wrong shape", field=name, expected="(N, 3)", got=P.shape)
    return P


def row_norms(x: np.ndarray) -> np.ndarray:
    """Euclidean norms (N,) of the rows of ``x`` (N, 3): ``np.linalg.norm(x, axis=1)`` bit for bit (its reduction adds
    ``(x0^2 + x1^2) + x2^2``), without its generic path over a last axis of 3 (~3x the time on a few hundred rows,
    6x on 3000)."""
    x2 = x * x
    return np.sqrt((x2[:, 0] + x2[:, 1]) + x2[:, 2])


def finite_mask(points: np.ndarray) -> np.ndarray:
    """Rows whose three coordinates are finite."""
    P = np.asarray(points)
    return np.isfinite(P).all(axis=-1) if P.size else np.zeros(len(P), dtype=bool)


def voxel_keys(points: np.ndarray, voxel_size: float, origin: np.ndarray | None = None) -> np.ndarray:
    """Integer voxel coordinates (N, 3) int64 of each point for a grid of ``voxel_size`` metres.

    Coordinates are taken relative to ``origin`` (default: the cloud's minimum) so that clouds far
    from the world origin keep full precision.
    """
    if voxel_size <= 0 or not np.isfinite(voxel_size):
        raise InputError("voxel size must be positive", field="voxel_size", expected="> 0", got=voxel_size)
    P = as_points(points)
    if len(P) == 0:
        return np.zeros((0, 3), dtype=np.int64)
    o = P.min(axis=0) if origin is None else np.asarray(origin, dtype=np.float64)
    return np.floor((P - o) / voxel_size).astype(np.int64)


def voxel_downsample(
    points: np.ndarray, voxel_size: float, *attrs: np.ndarray, group: np.ndarray | None = None
) -> tuple[np.ndarray, ...]:
    """Average points (and per-point attributes) that fall into the same voxel.

    Args:
        points: (N, 3) metres. Non-finite rows are dropped first.
        voxel_size: voxel edge in metres.
        attrs: arrays with N rows averaged alongside (e.g. normals, colours, confidences).
            Integer/bool attributes take the value of the first point in the voxel.
        group: optional (N,) integer labels; points of different groups never merge (keeps e.g.
            vision and touch points apart).

    Returns:
        (points_ds, *attrs_ds), one row per occupied voxel (per group).
    """
    P = as_points(points)
    for i, a in enumerate(attrs):
        if len(a) != len(P):
            raise InputError(
                "attribute length differs from the number of points",
                field=f"attrs[{i}]",
                expected=str(len(P)),
                got=len(a),
            )
    keep = finite_mask(P)
    P = P[keep]
    attrs = tuple(np.asarray(a)[keep] for a in attrs)
    if len(P) == 0:
        return (P, *attrs)
    keys = voxel_keys(P, voxel_size)
    if group is not None:
        keys = np.concatenate([keys, np.asarray(group)[keep].astype(np.int64)[:, None]], axis=1)
    _, first, inverse, counts = np.unique(keys, axis=0, return_index=True, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    n = len(counts)

    def mean(a: np.ndarray) -> np.ndarray:
        a2 = a.reshape(len(a), -1).astype(np.float64)
        out = np.zeros((n, a2.shape[1]))
        np.add.at(out, inverse, a2)
        return (out / counts[:, None]).reshape((n,) + a.shape[1:])

    out = [mean(P)]
    for a in attrs:
        out.append(mean(a).astype(a.dtype) if a.dtype.kind == "f" else a[first])
    return tuple(out)


def estimate_normals(points: np.ndarray, k: int = 16, viewpoint: np.ndarray | None = None) -> np.ndarray:
    """Unit normals (N, 3) by PCA of the ``k`` nearest neighbours (scipy cKDTree).

    Normals are oriented towards ``viewpoint`` when given (e.g. the camera centre). Points with
    fewer than 3 neighbours or a degenerate neighbourhood get a zero normal, which callers can
    detect with ``np.linalg.norm(n, axis=1) == 0``.
    """
    from scipy.spatial import cKDTree

    P = as_points(points)
    n = len(P)
    normals = np.zeros((n, 3))
    if n < 3:
        return normals
    k = int(min(max(k, 3), n))
    _, idx = cKDTree(P).query(P, k=k)
    nb = P[idx]  # (N, k, 3)
    centred = nb - nb.mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", centred, centred) / k
    w, v = np.linalg.eigh(cov)
    normals = v[:, :, 0]  # eigenvector of the smallest eigenvalue
    # Degenerate neighbourhoods (collinear/coincident): second eigenvalue ~ 0.
    scale = np.maximum(w[:, 2], 1e-300)
    degenerate = w[:, 1] / scale < 1e-10
    normals[degenerate] = 0.0
    if viewpoint is not None:
        to_view = np.asarray(viewpoint, dtype=np.float64) - P
        flip = np.einsum("ni,ni->n", normals, to_view) < 0
        normals[flip] *= -1.0
    return normals


def remove_outliers(points: np.ndarray, k: int = 16, std_ratio: float = 2.5) -> np.ndarray:
    """Boolean inlier mask by statistical outlier removal (mean kNN distance within mean + r*std)."""
    from scipy.spatial import cKDTree

    P = as_points(points)
    if len(P) <= k:
        return np.ones(len(P), dtype=bool)
    d, _ = cKDTree(P).query(P, k=k + 1)
    md = d[:, 1:].mean(axis=1)
    return md <= md.mean() + std_ratio * md.std()
