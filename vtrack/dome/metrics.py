"""Reconstruction, contact and force metrics (lengths in mm, forces in N).

- ``cd``: symmetric Chamfer distance, the mean of the two directed mean nearest-neighbour distances (mm).
- ``hd95``: 95th percentile of the pooled symmetric nearest-neighbour distances (mm).
- ``f2mm``: F-score at 2 mm (harmonic mean of precision and recall of points within 2 mm).
- ``contact_l2``: RMS difference between the predicted contact probability and the GT mask (coarse template).
- ``force_mae`` / ``force_rmse``: per axis and mean over axes (N).
"""

from __future__ import annotations

import numpy as np


def surface_metrics(pred: np.ndarray, gt: np.ndarray, tau_mm: float = 2.0) -> dict[str, float]:
    """Chamfer, HD95 and F-score at ``tau_mm`` between two point sets (n, 3) and (m, 3) in mm
    (:func:`vtrack.eval.reconstruction.point_metrics` in mm; an empty or non-finite prediction scores inf / 0)."""
    from vtrack.eval.reconstruction import point_metrics

    if len(pred) == 0 or len(gt) == 0 or not np.all(np.isfinite(pred)):
        return {"cd": float("inf"), "hd95": float("inf"), "f": 0.0}
    m = point_metrics(pred, gt, thresholds_m={"f": tau_mm * 1e-3}, units="mm")
    return {"cd": m["chamfer_mm"], "hd95": m["hd95_mm"], "f": m["fscore"]["f"]}


def set_ground_truth(data: dict[str, np.ndarray], dense_rest: np.ndarray) -> dict[str, np.ndarray]:
    """The ``gt`` argument of :func:`evaluate_predictions` for a simulated set (``vtrack.dome.simulate``):
    coarse / dense surfaces (mm, dome frame), coarse contact, force (N) and the dense rest template (mm)."""
    return {
        "coarse": data["coarse_mm"],
        "dense": data["dense_mm"],
        "contact": data["contact_coarse"],
        "force": data["force_n"],
        "dense_rest": dense_rest,
    }


def evaluate_predictions(pred: dict[str, np.ndarray], gt: dict[str, np.ndarray]) -> dict[str, float]:
    """Mean metrics over a set. ``pred``/``gt``: coarse (N, 256, 3), dense (N, Nd, 3) mm, contact (N, 256),
    force (N, 3) N (pred may also hold ``force_nop``)."""
    n = len(gt["dense"])
    cdc, cdf, hd, f2, f05, verr, verr_def = [], [], [], [], [], [], []
    for i in range(n):
        cdc.append(surface_metrics(pred["coarse"][i], gt["coarse"][i])["cd"])
        m = surface_metrics(pred["dense"][i], gt["dense"][i])
        cdf.append(m["cd"])
        hd.append(m["hd95"])
        f2.append(m["f"])
        f05.append(surface_metrics(pred["dense"][i], gt["dense"][i], 0.5)["f"])
        e = np.linalg.norm(pred["dense"][i] - gt["dense"][i], axis=1)
        verr.append(e.mean())
        moved = np.linalg.norm(gt["dense"][i] - gt["dense_rest"], axis=1) > 0.5
        if moved.any():
            verr_def.append(e[moved].mean())
    out = {
        "cd_coarse": float(np.mean(cdc)),
        "cd_fine": float(np.mean(cdf)),
        "hd95": float(np.mean(hd)),
        "f2mm": float(np.mean(f2)),
        "f05mm": float(np.mean(f05)),
        "vertex_err": float(np.mean(verr)),
        "vertex_err_moved": float(np.mean(verr_def)) if verr_def else 0.0,
        "contact_l2": float(np.sqrt(np.mean((pred["contact"] - gt["contact"].astype(np.float64)) ** 2))),
    }
    for name in sorted(k for k in pred if k.startswith("force")):  # force, force_nop, ablation heads
        err = pred[name] - gt["force"]
        mae = np.abs(err).mean(0)
        out[f"{name}_mae"] = float(mae.mean())
        out[f"{name}_rmse"] = float(np.sqrt((err**2).mean()))
        for a, v in zip("xyz", mae, strict=True):
            out[f"{name}_mae_{a}"] = float(v)
    return out
