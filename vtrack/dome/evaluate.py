"""Evaluation of shipped/trained dome models on the held-out simulated test set (``vtrack dome eval``)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

EVAL_KEYS = ("cd_coarse", "cd_fine", "hd95", "f2mm", "contact_l2", "force_mae", "ms_per_frame")


def time_end_to_end(
    method: str, weights: Path, images: np.ndarray, pressures: np.ndarray, dense_rest: np.ndarray | None = None
) -> tuple[float, float]:
    """Median (wall ms, CPU ms) per frame of ``DomeReconstructor.reconstruct`` (the public call: input checks,
    marker extraction, (graph ->) dense surface + force, and the marker-match validity check), one frame at a
    time, every thread pool (torch, OpenCV, BLAS) capped at one thread. CPU time (``time.process_time``) is
    reported too because wall time on a shared machine includes waiting for the core; with one thread it
    should not exceed the wall time."""
    from vtrack.dome.reconstruct import DomeReconstructor
    from vtrack.threads import limit_threads

    limit_threads(1)
    rec = DomeReconstructor(method, weights)
    if dense_rest is not None:
        rec.model.decoder.set_dense(dense_rest)
    for p in pressures:  # a session's reference frame is prepared once, before its frames arrive
        rec.reference(float(p))
    rec.reconstruct(images[0], float(pressures[0]))  # warm-up
    ts, cs = [], []
    for img, p in zip(images, pressures, strict=True):
        t0, c0 = time.perf_counter(), time.process_time()
        rec.reconstruct(img, float(p))
        ts.append((time.perf_counter() - t0) * 1e3)
        cs.append((time.process_time() - c0) * 1e3)
    return float(np.median(ts)), float(np.median(cs))


def evaluate(
    weights_dir: Path | None = None,
    n_test: int = 300,
    test_seed: int = 12345,
    methods: tuple[str, ...] = ("gnn", "cnn"),
    timing_frames: int = 40,
    dense_rest: np.ndarray | None = None,
    data: dict | None = None,
) -> dict[str, dict[str, float]]:
    """Metrics of each method on the simulated test set (same samples for every method)."""
    import torch

    from vtrack.dome.bundle import load_bundle
    from vtrack.dome.bundle import weights_dir as wdir
    from vtrack.dome.metrics import evaluate_predictions, set_ground_truth
    from vtrack.dome.model import DomeGeometry
    from vtrack.dome.simulate import make_dataset
    from vtrack.dome.train import Batcher, predict
    from vtrack.errors import InputError

    torch.set_num_threads(1)
    weights_dir = Path(weights_dir) if weights_dir else wdir()
    results: dict[str, dict[str, float]] = {}
    for m in methods:
        path = weights_dir / f"{m}.pt"
        if not path.exists():
            raise InputError("weights not found (run `vtrack dome train`)", path=path)
        model, heads, cfg, _ = load_bundle(path)
        geo = DomeGeometry(cfg)
        te = data if data is not None else make_dataset(n_test, test_seed, cfg)
        bte = Batcher(m, te, geo, f"{len(te['image'])}-{test_seed}-{cfg.to_dict()}" if data is None else None)
        pred = predict(model, heads, bte)
        gt = set_ground_truth(te, geo.dense_rest)
        r = evaluate_predictions(pred, gt)
        k = min(timing_frames, len(te["image"]))
        r["ms_per_frame"], r["cpu_ms_per_frame"] = time_end_to_end(m, path, te["image"][:k], te["pressure_kpa"][:k])
        r["fps"] = 1000.0 / r["ms_per_frame"]
        r["fps_cpu"] = 1000.0 / max(r["cpu_ms_per_frame"], 1e-6)
        results[m] = r
    return results


def template_baseline(te: dict, geo) -> dict[str, float]:
    """Metrics of predicting the undeformed reference state (no contact, zero force): how hard the set is.

    The reference state is the rest template inflated by the reference pressure (what a net that sees no
    deformation would output)."""
    from vtrack.dome.metrics import evaluate_predictions, set_ground_truth

    n = len(te["image"])
    infl = geo.reference_inflation_mm(np.asarray(te["pressure_kpa"], np.float64))[:, None, None]
    pred = {
        "coarse": geo.coarse_rest * (1 + infl / geo.cfg.radius_mm),
        "dense": geo.dense_rest * (1 + infl / geo.cfg.radius_mm),
        "contact": np.zeros((n, geo.cfg.n_coarse)),
        "force": np.zeros((n, 3)),
    }
    gt = set_ground_truth(te, geo.dense_rest)
    return evaluate_predictions(pred, gt)


def pressure_probe(method: str = "gnn", weights_dir: Path | None = None, ridge: float = 10.0) -> dict[str, float]:
    """How much of the internal pressure (kPa) a trained encoder already reads from the image alone.

    Ridge regression from the encoder's pooled features (global feature + mean decoder hidden state) to P,
    fitted on the training set, scored on the held-out set. A small error means the image shows the pressure
    (with a reference frame at P = 0, inflation moves the markers), and a force head gains little from being
    told P; with the reference at the operating pressure only the stiffening of the shell still shows it
    (measured 0.50 kPa for the shipped GNN vs 0.22 kPa with a P = 0 reference; predicting the mean 2.60). Returns
    ``{"mae_kpa", "baseline_mae_kpa"}`` (baseline = predicting the mean).
    """
    import torch

    from vtrack.dome.bundle import bundle_train_config, load_bundle, read_bundle
    from vtrack.dome.bundle import weights_dir as wdir
    from vtrack.dome.model import DomeGeometry
    from vtrack.dome.train import Batcher, force_features, load_sets

    path = Path(weights_dir or wdir()) / f"{method}.pt"
    tc = bundle_train_config(read_bundle(path))
    model, _, cfg, _ = load_bundle(path, with_heads=False)
    geo = DomeGeometry(cfg)
    tr, te = load_sets(tc, cfg)

    def feats(data: dict, n: int, seed: int) -> np.ndarray:
        o = force_features(model, Batcher(method, data, geo, f"{n}-{seed}-{cfg.to_dict()}"))
        return torch.cat([o["glob"], o["hidden"].mean(1)], -1).numpy().astype(np.float64)

    xtr, xte = feats(tr, tc.n_train, tc.seed), feats(te, tc.n_test, tc.test_seed)
    ytr, yte = np.asarray(tr["pressure_kpa"], np.float64), np.asarray(te["pressure_kpa"], np.float64)
    mu, sd = xtr.mean(0), xtr.std(0) + 1e-6
    a, b = (xtr - mu) / sd, (xte - mu) / sd
    w = np.linalg.solve(a.T @ a + ridge * np.eye(a.shape[1]), a.T @ (ytr - ytr.mean()))
    pred = b @ w + ytr.mean()
    return {"mae_kpa": float(np.abs(pred - yte).mean()), "baseline_mae_kpa": float(np.abs(yte - ytr.mean()).mean())}


#: JSON keys of the force ablation (Table S6) -> (bundle, prediction key); the decoder-feature heads of the
#: previous design are extra rows
FORCE_SETTINGS = {
    "gnn_patch_with_p": ("gnn", "force"),
    "gnn_patch_no_p": ("gnn", "force_nop"),
    "cnn_with_p": ("cnn", "force"),
    "cnn_no_p": ("cnn", "force_nop"),
    "gnn_patch_plain_with_p": ("gnn", "force_plain_p"),
    "gnn_patch_plain_no_p": ("gnn", "force_plain_nop"),
    "gnn_decoder_head_with_p": ("gnn", "force_legacy_p"),
    "gnn_decoder_head_no_p": ("gnn", "force_legacy_nop"),
    "cnn_decoder_head_with_p": ("cnn", "force_legacy_p"),
    "cnn_decoder_head_no_p": ("cnn", "force_legacy_nop"),
}


def force_table(results: dict[str, dict[str, float]]) -> dict[str, dict[str, float]]:
    """Table S6 layout from :func:`evaluate` results: per setting ``mae``, ``rmse``, ``mae_fx/fy/fz`` (N)."""
    out: dict[str, dict[str, float]] = {}
    for name, (method, key) in FORCE_SETTINGS.items():
        r = results.get(method, {})
        if f"{key}_mae" not in r:
            continue
        out[name] = {
            "mae": r[f"{key}_mae"],
            "rmse": r[f"{key}_rmse"],
            "mae_fx": r[f"{key}_mae_x"],
            "mae_fy": r[f"{key}_mae_y"],
            "mae_fz": r[f"{key}_mae_z"],
        }
    return out


def marker_eval(n_sim: int = 100, seed: int = 777, tactip: bool = True) -> dict:
    """Marker detection (S4): U-Net vs classic (Otsu + k-means) on held-out simulated frames (training-style
    lighting/blur/noise/occlusion, ``hard``; and the simulator's own rendering, ``plain``) and, when the shared
    data is present, on the real TacTip frames. ``unet`` / ``classic`` hold the held-out ``hard`` numbers."""
    from vtrack.dome.segment import MarkerSegmenter, evaluate_simulated, evaluate_tactip
    from vtrack.paths import shared_data_dir

    seg = MarkerSegmenter()
    hard = evaluate_simulated(seg, n_sim, seed, hard=True)
    plain = evaluate_simulated(seg, n_sim, seed + 1, hard=False)
    out: dict = {k: hard[k] for k in ("unet", "classic")}
    out["plain"] = plain
    root = shared_data_dir() / "tactip_frames"
    if tactip and root.exists():
        out["tactip"] = evaluate_tactip(seg, root)
    return out
