"""Real TacTip frames (``shared/data/tactip_frames``): marker-detection stability and a pose regressor.

- Detection stability: markers per frame (mean, std, fraction of frames with exactly the sensor's pin count)
  and *track continuity*: the fraction of the no-contact frame's markers that find a one-to-one partner
  (Hungarian assignment, gated at 0.6 x the median pin spacing) in each pressed frame.
- Pose regression: a small marker-graph GNN (same encoder as the dome GNN; node input = S5 descriptor +
  displacement to the matched no-contact pin) regresses contact depth ``pose_2`` (mm) and roll ``pose_6``
  (deg) on a fixed 80/20 train/test split of the available frames; a ridge regression on the matched
  displacement field is reported beside it.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vtrack.errors import InputError

#: per set: expected pin count, mask radius (fraction of half the image size; excludes the dome rim)
SETS = {"tactip_331": (331, 0.90), "tactip_127": (127, 0.86)}


@dataclass
class TacTipSet:
    name: str
    images: list[np.ndarray]
    init: np.ndarray
    depth_mm: np.ndarray
    roll_deg: np.ndarray
    files: list[str]


def load_set(root: Path, name: str) -> TacTipSet:
    import cv2

    d = Path(root) / name
    lab = d / "targets_included_frames.csv"
    if not lab.exists():
        raise InputError("TacTip label file missing", path=lab)
    rows = list(csv.DictReader(open(lab)))
    imgs, files, depth, roll = [], [], [], []
    for r in rows:
        p = d / "frames_bw" / r["image_name"]
        a = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        if a is None:
            continue
        imgs.append(a)
        files.append(r["image_name"])
        depth.append(float(r["pose_2"]))
        roll.append(float(r["pose_6"]))
    init = cv2.imread(str(d / "frames_bw" / "init_0.png"), cv2.IMREAD_GRAYSCALE)
    if init is None:
        raise InputError("no-contact frame missing", path=d / "frames_bw" / "init_0.png")
    return TacTipSet(name, imgs, init, np.array(depth), np.array(roll), files)


def match_to_reference(centers: np.ndarray, ref: np.ndarray, gate_px: float) -> np.ndarray:
    """Index of the matched reference marker per detected marker (-1 = unmatched): the most pairs within
    ``gate_px``, then the least total distance (:func:`vtrack.dome.features.gated_assignment`, the matcher the
    GNN features use)."""
    from scipy.spatial import cKDTree

    from vtrack.dome.features import gated_assignment

    out = np.full(len(centers), -1, np.int64)
    if len(centers) == 0 or len(ref) == 0:
        return out
    r, c = gated_assignment(np.asarray(centers, np.float64), np.asarray(ref, np.float64), cKDTree(ref), gate_px)
    out[r] = c
    return out


def analyse_set(ts: TacTipSet, *, seed: int = 0, epochs: int = 150, log=print) -> dict:
    """Detection stability + pose regression results for one set (numbers, no plots)."""
    from vtrack.dome.markers import build_graph, extract_markers

    expected, mask_r = SETS[ts.name]
    ref = extract_markers(ts.init, polarity="bright", mask_radius=mask_r)
    from vtrack.dome.model import knn_np

    _, dd = knn_np(ref.centers, ref.centers, 2)
    spacing = float(np.median(dd[:, 1]))
    counts, cont, graphs, disp_fields = [], [], [], []
    half = min(ts.init.shape) / 2.0
    for img in ts.images:
        ms = extract_markers(img, polarity="bright", mask_radius=mask_r)
        counts.append(len(ms))
        m = match_to_reference(ms.centers, ref.centers, 0.6 * spacing)
        cont.append(float((m >= 0).sum()) / max(len(ref), 1))
        g = build_graph(ms)
        dref = np.zeros((len(ms), 2), np.float32)
        dref[m >= 0] = (ms.centers[m >= 0] - ref.centers[m[m >= 0]]) / half
        graphs.append(
            {
                "x": np.concatenate([g.x, dref], 1).astype(np.float32),
                "edge_index": g.edge_index,
                "edge_attr": g.edge_attr,
                "pos": np.zeros((len(ms), 3), np.float32),
            }
        )
        field = np.zeros((len(ref), 2))
        field[m[m >= 0]] = dref[m >= 0]
        disp_fields.append(field.ravel())
    counts_a = np.array(counts)
    res = {
        "set": ts.name,
        "frames": len(ts.images),
        "expected_pins": expected,
        "init_count": len(ref),
        "count_mean": float(counts_a.mean()),
        "count_std": float(counts_a.std()),
        "count_min": int(counts_a.min()),
        "count_max": int(counts_a.max()),
        "frac_exact_count": float((counts_a == expected).mean()),
        "track_continuity_mean": float(np.mean(cont)),
        "track_continuity_min": float(np.min(cont)),
        "pin_spacing_px": spacing,
    }
    # fixed split
    rng = np.random.default_rng(seed)
    perm = rng.permutation(len(graphs))
    n_te = max(1, len(graphs) // 5)
    te, tr = perm[:n_te], perm[n_te:]
    y = np.stack([ts.depth_mm, ts.roll_deg], 1)
    res.update(_ridge(np.array(disp_fields), y, tr, te))
    res.update(_gnn_regressor(graphs, y, tr, te, seed, epochs, log))
    res["n_train"], res["n_test"] = len(tr), len(te)
    return res


def _ridge(X: np.ndarray, y: np.ndarray, tr: np.ndarray, te: np.ndarray, lam: float = 1e-2) -> dict:
    mu, sd = X[tr].mean(0), X[tr].std(0) + 1e-6
    Xn = (X - mu) / sd
    A = np.c_[Xn, np.ones(len(X))]
    W = np.linalg.solve(A[tr].T @ A[tr] + lam * len(tr) * np.eye(A.shape[1]), A[tr].T @ y[tr])
    err = np.abs(A[te] @ W - y[te]).mean(0)
    return {"ridge_depth_mae_mm": float(err[0]), "ridge_roll_mae_deg": float(err[1])}


def _gnn_regressor(graphs, y, tr, te, seed, epochs, log) -> dict:
    import torch
    from torch import nn

    from vtrack.dome.features import collate_graphs
    from vtrack.dome.nets import GraphEncoder, mlp

    torch.manual_seed(seed)
    enc = GraphEncoder(32, 3, node_in=graphs[0]["x"].shape[1])  # S5 + [dx, dy] to the reference pin
    head = mlp(64, 32, 2)
    mu, sd = y[tr].mean(0), y[tr].std(0) + 1e-9
    yt = torch.tensor((y - mu) / sd, dtype=torch.float32)
    params = list(enc.parameters()) + list(head.parameters())
    opt = torch.optim.Adam(params, lr=3e-3, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, epochs)
    rng = np.random.default_rng(seed)
    for _ep in range(epochs):
        perm = rng.permutation(tr)
        for b in range(0, len(perm), 16):
            idx = perm[b : b + 16]
            bt = collate_graphs([graphs[i] for i in idx])
            _, g = enc(bt["x"], bt["edge_index"], bt["edge_attr"], bt["batch"], len(idx))
            loss = nn.functional.mse_loss(head(g), yt[idx])
            opt.zero_grad()
            loss.backward()
            opt.step()
        sched.step()
    with torch.no_grad():
        bt = collate_graphs([graphs[i] for i in te])
        _, g = enc(bt["x"], bt["edge_index"], bt["edge_attr"], bt["batch"], len(te))
        pred = head(g).numpy() * sd + mu
    err = np.abs(pred - y[te]).mean(0)
    log(f"[tactip] gnn test MAE depth {err[0]:.3f} mm, roll {err[1]:.2f} deg")
    return {
        "gnn_depth_mae_mm": float(err[0]),
        "gnn_roll_mae_deg": float(err[1]),
        "label_std_depth_mm": float(y[te, 0].std()),
        "label_std_roll_deg": float(y[te, 1].std()),
    }


def analyse_all(root: Path | None = None, **kw) -> list[dict]:
    from vtrack.paths import shared_data_dir

    root = Path(root) if root else shared_data_dir() / "tactip_frames"
    if not root.exists():
        raise InputError("TacTip frames folder not found", path=root)
    return [analyse_set(load_set(root, name), **kw) for name in SETS]
