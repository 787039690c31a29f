"""Reconstruction metrics against a ground-truth mesh, both in the same frame (object frame, m).

Definitions (as in Tanks and Temples / NeuralFeels):
- Sample ``n_points`` (default 10k) points uniformly on each surface (area-weighted, fixed seed).
- precision@tau = fraction of reconstructed samples within ``tau`` of the GT samples;
  recall@tau = fraction of GT samples within ``tau`` of the reconstruction;
  F@tau = 2 P R / (P + R) (0 when both are 0).
- Chamfer (mm) = mean of the two mean nearest-neighbour distances (rec->GT and GT->rec).
- Normal consistency = mean over both directions of |n_a . n_b| for nearest-neighbour pairs.

Empty or degenerate reconstructions give precision = recall = F = 0, ``chamfer_mm = None`` and
``empty = True`` (never NaN or Inf).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from vtrack.errors import InputError

#: thresholds reported by default, metres -> key
DEFAULT_THRESHOLDS_M: dict[str, float] = {"1mm": 0.001, "2mm": 0.002, "5mm": 0.005, "10mm": 0.010}


def sample_surface(
    vertices: np.ndarray, faces: np.ndarray, n: int = 10_000, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """``n`` area-weighted surface samples and their face normals; empty arrays for an empty mesh."""
    V = np.asarray(vertices, np.float64).reshape(-1, 3)
    F = np.asarray(faces, np.int64).reshape(-1, 3)
    if len(V) == 0 or len(F) == 0 or not np.isfinite(V).all():
        return np.zeros((0, 3)), np.zeros((0, 3))
    tri = V[F]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area2 = np.linalg.norm(cross, axis=1)
    total = area2.sum()
    if not np.isfinite(total) or total <= 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    rng = np.random.default_rng(seed)
    fid = rng.choice(len(F), size=n, p=area2 / total)
    u, v = rng.random(n), rng.random(n)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    t = tri[fid]
    pts = t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])
    nrm = cross[fid] / np.maximum(area2[fid, None], 1e-300)
    return pts, nrm


#: length units the metrics accept -> metres per unit
UNITS = {"m": 1.0, "mm": 1e-3}


def point_metrics(
    rec_points: np.ndarray,
    gt_points: np.ndarray,
    rec_normals: np.ndarray | None = None,
    gt_normals: np.ndarray | None = None,
    thresholds_m: dict[str, float] | None = None,
    *,
    units: str = "m",
) -> dict[str, Any]:
    """F-score / precision / recall / Chamfer / HD95 / normal consistency between two point samples.

    ``units``: the unit of the points (``m`` or ``mm``); thresholds are always given in metres and the
    distances are reported in mm (``chamfer_mm``, ``accuracy_mm``, ``completeness_mm``, ``hd95_mm``: 95th
    percentile of the pooled nearest-neighbour distances of both directions).
    """
    from scipy.spatial import cKDTree

    if units not in UNITS:
        raise InputError("unknown length unit", field="units", expected=" | ".join(UNITS), got=units)
    to_m = UNITS[units]
    th = {k: v / to_m for k, v in (thresholds_m or DEFAULT_THRESHOLDS_M).items()}  # in the points' unit
    R = np.asarray(rec_points, np.float64).reshape(-1, 3)
    G = np.asarray(gt_points, np.float64).reshape(-1, 3)
    keep = np.isfinite(R).all(1)
    R = R[keep]
    if rec_normals is not None:
        rec_normals = np.asarray(rec_normals, np.float64).reshape(-1, 3)[keep]
    if len(G) == 0:
        raise InputError("ground-truth sample is empty", field="gt_points", expected="> 0 points")
    if len(R) == 0:
        zero = {k: 0.0 for k in th}
        return {
            "fscore": dict(zero),
            "precision": dict(zero),
            "recall": dict(zero),
            "chamfer_mm": None,
            "accuracy_mm": None,
            "completeness_mm": None,
            "hd95_mm": None,
            "normal_consistency": None,
            "n_rec": 0,
            "n_gt": len(G),
            "empty": True,
        }
    d_rg, i_rg = cKDTree(G).query(R)  # precision side: rec -> GT
    d_gr, i_gr = cKDTree(R).query(G)  # recall side: GT -> rec
    fs, pr, rc = {}, {}, {}
    for k, tau in th.items():
        p = float(np.mean(d_rg < tau))
        r = float(np.mean(d_gr < tau))
        pr[k], rc[k] = p, r
        fs[k] = 2 * p * r / (p + r) if p + r > 0 else 0.0
    nc = None
    if rec_normals is not None and gt_normals is not None:
        Gn = np.asarray(gt_normals, np.float64).reshape(-1, 3)

        def unit(a: np.ndarray) -> np.ndarray:
            return a / np.maximum(np.linalg.norm(a, axis=1, keepdims=True), 1e-12)

        Rn, Gn = unit(rec_normals), unit(Gn)
        a = np.abs(np.einsum("ij,ij->i", Rn, Gn[i_rg]))
        b = np.abs(np.einsum("ij,ij->i", Gn, Rn[i_gr]))
        nc = float(0.5 * (a.mean() + b.mean()))
    mm = to_m * 1e3
    acc = float(d_rg.mean() * mm)
    comp = float(d_gr.mean() * mm)
    hd95 = float(np.percentile(np.concatenate([d_rg, d_gr]), 95) * mm)
    return {
        "fscore": fs,
        "precision": pr,
        "recall": rc,
        "chamfer_mm": 0.5 * (acc + comp),
        "accuracy_mm": acc,
        "completeness_mm": comp,
        "hd95_mm": hd95,
        "normal_consistency": nc,
        "n_rec": int(len(R)),
        "n_gt": int(len(G)),
        "empty": False,
    }


def mesh_metrics(
    rec_vertices: np.ndarray,
    rec_faces: np.ndarray,
    gt_vertices: np.ndarray,
    gt_faces: np.ndarray,
    n_points: int = 10_000,
    seed: int = 0,
    thresholds_m: dict[str, float] | None = None,
) -> dict[str, Any]:
    """Metrics between a reconstructed and a ground-truth mesh (same frame, metres).

    Both surfaces are sampled with ``n_points`` points (seeded). See the module docstring.
    """
    G, Gn = sample_surface(gt_vertices, gt_faces, n_points, seed)
    if len(G) == 0:
        raise InputError("ground-truth mesh is empty or degenerate", field="gt_mesh", expected="faces with area")
    R, Rn = sample_surface(rec_vertices, rec_faces, n_points, seed + 1)
    out = point_metrics(R, G, Rn, Gn, thresholds_m)
    out["n_points"] = int(n_points)
    return out
