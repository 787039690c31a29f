"""``vtrack bench generate_downstream``: what generated tactile images do for downstream models (issue #24,
the ControlTac paper's Tables 2, 3 and 8 at CPU scale). Every model is trained for a FIXED number of optimiser
steps (not wall time), one torch thread, so the rows do not depend on the machine's load.

Rows:
- ``classify``: object classification of SIMULATED YCB surface patches (six shared meshes, independent optical
  model; :mod:`vtrack.tactile.generate.classify`) by a small CNN and a small ViT from scratch, trained on a few
  labelled presses per object with no / geometric / geometric + colour / generated augmentation; accuracy on
  held-out presses (other spots of the same objects), means over seeds (each seed draws its own references);
- ``pose real``: contact-centre (x, y) regression on the REAL shared GelSight ball presses (balls have no
  angle): a CNN on a small real budget with / without augmentation generated from one reference press, against
  the contact centroid (no training); held-out presses = the generator's held-out half;
- ``force diag``: why depth (force) regression gets worse with generated images: the real-only regressor's
  depth reading of generated images against the depth they were generated for (the generator's depth response
  seen by a model of the real sensor), and the mixing-ratio / target-depth variants of the augmentation.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

from vtrack.bench.harness import BenchTable

log = logging.getLogger(__name__)


# ----------------------------------------------------------------------------------------------- classification
def classify_study(
    quick: bool = False,
    steps: int = 500,
    seeds: int = 2,
    refs_per_class: int = 4,
    n_aug: int = 40,
    n_test_per_class: int = 40,
    n_large_per_class: int = 50,
) -> list[dict]:
    """YCB-patch object classification with geometric / colour / generated augmentation (paper Table 3
    analogue, SIMULATED). Per seed: ``refs_per_class`` labelled presses per object (the "real" budget, drawn
    anew per seed), ``n_aug`` augmented images per reference for each augmentation, ``steps`` AdamW steps of
    32 for every model; test = ``n_test_per_class`` other presses per object from the same sensor unit. A
    CNN trained on ``n_large_per_class`` real presses per object (no augmentation) is the large-budget
    reference row."""
    import torch

    from vtrack.tactile.generate import classify as cl
    from vtrack.tactile.generate.generator import TactileGenerator
    from vtrack.tactile.sensors import default_background

    if quick:
        steps, seeds, n_aug, n_test_per_class, n_large_per_class = 400, 1, 10, 12, 0
    bg = default_background("gelsight", cl.W, cl.H)
    test = cl.cached_patch_set(n_test_per_class, seed=202)
    Xte, yte = cl.to_input(test.images, bg), test.labels
    nc = len(test.classes)
    gen = TactileGenerator(threads=0)
    acc: dict[tuple[str, str], list[float]] = {}
    for s in range(seeds):
        ref = cl.cached_patch_set(refs_per_class, seed=101 + s)
        Xr, yr = cl.to_input(ref.images, bg), ref.labels
        sets = {"none": (Xr, yr)}
        for kind in cl.AUGMENTATIONS[1:]:
            t0 = time.perf_counter()
            Xa = cl.augment_set(kind, ref.images, ref.masks, ref.depths, bg, n_aug, seed=s, generator=gen)
            log.info("classify: %s set of %d in %.1f s", kind, len(Xa), time.perf_counter() - t0)
            sets[kind] = (np.concatenate([Xr, Xa]), np.concatenate([yr, np.repeat(yr, n_aug)]))
        for arch in ("cnn", "vit"):
            for kind, (X, y) in sets.items():
                torch.manual_seed(s)
                net = cl.train_classifier(arch, X, y, nc, steps, seed=s)
                a = cl.accuracy(net, Xte, yte)
                acc.setdefault((arch, kind), []).append(a)
                log.info("classify seed %d %s %s: %.3f", s, arch, kind, a)
    rows = []
    names = {"none": "no augmentation", "G": "geometric (G)", "G+C": "geometric + colour (G+C)", "Gen": "generated"}
    for (arch, kind), v in acc.items():
        rows.append(
            {
                "method": f"{arch.upper() if arch == 'cnn' else 'ViT'} from scratch, {names[kind]}",
                "train": f"{refs_per_class} presses/object" + ("" if kind == "none" else f" + {n_aug} {kind} each"),
                "accuracy": float(np.mean(v)),
                "accuracy_std": float(np.std(v)),
                "seeds": len(v),
            }
        )
    if n_large_per_class:
        big = cl.cached_patch_set(n_large_per_class, seed=303)
        Xb = cl.to_input(big.images, bg)
        for arch in ("cnn", "vit"):
            net = cl.train_classifier(arch, Xb, big.labels, nc, steps, seed=0)
            rows.append(
                {
                    "method": f"{arch.upper() if arch == 'cnn' else 'ViT'} from scratch, large real budget",
                    "train": f"{n_large_per_class} presses/object, no augmentation",
                    "accuracy": cl.accuracy(net, Xte, yte),
                    "accuracy_std": 0.0,
                    "seeds": 1,
                }
            )
    for r in rows:
        r["test"] = (
            f"{len(yte)} held-out simulated presses ({n_test_per_class}/object, {nc} objects), chance {1 / nc:.3f}"
        )
        r["steps"] = steps
    return rows


# ----------------------------------------------------------------------------------------------- real pose
def real_pose_study(
    quick: bool = False,
    press_dir: str | Path | None = None,
    steps: int = 800,
    seeds: int = 2,
    budgets: tuple[int, ...] = (6, 24),
    n_gen: int = 240,
    head: str = "flat",
    sets: tuple[str, ...] = ("real only", "real + shifted", "real + generated"),
) -> list[dict]:
    """Contact-centre regression on REAL GelSight ball presses (paper Table 2 analogue where labels allow: the
    balls give x, y, no angle). Train pool = the generator's 24 training presses (even indices), test = the 24
    held-out ones (odd; never seen by the generator). Per budget ``k`` and seed: ``k`` training presses drawn
    at random; rows ``real only``; ``+ shifted`` (each real press's colour change translated to random centres,
    label moved with it: geometric augmentation, no network); ``+ generated`` (``n_gen`` images generated from
    ONE of the ``k`` presses to random centres and depths, two-stage generator, label = the requested centre);
    and the detected contact's centroid (no training). Errors: mean |x|, |y| and Euclidean px at 640x480.
    ``head``: the pose CNN's head (:data:`vtrack.bench.generate.POSE_HEADS`); ``sets``: the CNN rows to train."""
    import cv2
    import torch

    from vtrack.bench.generate import POSE_HEADS, _press_depth
    from vtrack.paths import shared_data_dir
    from vtrack.tactile.generate import data as gd
    from vtrack.tactile.generate.generator import TactileGenerator
    from vtrack.tactile.generate.train import REAL_HOLDOUT
    from vtrack.tactile.pressset import load_press_set

    root = Path(press_dir) if press_dir is not None else shared_data_dir() / "gelsight_ball_presses"
    ps = load_press_set(root)
    train, test = ps.split(REAL_HOLDOUT)
    bg = ps.background()
    H, W = bg.shape[:2]
    bgf = bg.astype(np.float32)
    if quick:
        steps, seeds, n_gen, budgets = 400, 1, 60, budgets[:1]

    def feats(deltas: list[np.ndarray]) -> np.ndarray:
        small = np.stack([cv2.resize(d, (80, 60), interpolation=cv2.INTER_AREA) for d in deltas])
        small = small.transpose(0, 3, 1, 2) / 32.0
        yy, xx = np.meshgrid(np.linspace(-1, 1, 60), np.linspace(-1, 1, 80), indexing="ij")
        coords = np.broadcast_to(np.stack([xx, yy])[None], (len(small), 2, 60, 80))
        return np.ascontiguousarray(np.concatenate([small, coords], 1), np.float32)

    def tgt(xy: np.ndarray) -> np.ndarray:
        return np.stack([xy[:, 0] / W * 2 - 1, xy[:, 1] / H * 2 - 1], 1).astype(np.float32)

    def errs(xy_pred: np.ndarray, xy_true: np.ndarray) -> dict[str, float]:
        d = xy_pred - xy_true
        return {
            "x_err_px": float(np.mean(np.abs(d[:, 0]))),
            "y_err_px": float(np.mean(np.abs(d[:, 1]))),
            "xy_err_px": float(np.mean(np.hypot(d[:, 0], d[:, 1]))),
        }

    def depth(p) -> float:
        return _press_depth(ps, p)

    deltas_tr = [ps.image(p).astype(np.float32) - bgf for p in train]
    xy_tr = np.array([p.center_xy_px for p in train], np.float32)
    Xte = feats([ps.image(p).astype(np.float32) - bgf for p in test])
    xy_te = np.array([p.center_xy_px for p in test], np.float32)
    lo = xy_tr.min(0)
    hi = xy_tr.max(0)
    dlo, dhi = min(depth(p) for p in train), max(depth(p) for p in train)
    rows = []

    def centroids(presses: list) -> np.ndarray:
        out = []
        for p in presses:
            q = gd.mask_pose(gd.detect_contact(ps.image(p), bg))
            out.append((q.x, q.y))
        return np.array(out)

    cen = centroids(test)
    cen_tr = centroids(train)
    rows.append(
        {"method": "centroid of the detected contact", "train": "none", "seeds": 1} | errs(np.array(cen), xy_te)
    )
    gen = TactileGenerator(threads=0)
    res: dict[str, list[dict]] = {}
    for k in budgets:
        for s in range(seeds):
            rng = np.random.default_rng(1000 * k + s)
            pick = rng.choice(len(train), size=k, replace=False)
            Xk, Yk = feats([deltas_tr[i] for i in pick]), tgt(xy_tr[pick])
            # the centroid's constant offset (LED shading makes one side of the rim stronger), estimated on the
            # k labelled presses
            off = (cen_tr[pick] - xy_tr[pick]).mean(0)
            res.setdefault(f"{k}|centroid - offset|centroid minus its mean offset on {k} real", []).append(
                errs(cen - off, xy_te)
            )
            # geometric: every picked press translated (whole colour change, zero fill) to random centres
            per = max(1, n_gen // k)
            sh_d, sh_xy = [], []
            for i in pick:
                for _ in range(per):
                    c = rng.uniform(lo, hi)
                    M = np.float32([[1, 0, c[0] - xy_tr[i, 0]], [0, 1, c[1] - xy_tr[i, 1]]])
                    sh_d.append(gd.warp(deltas_tr[i], M))
                    sh_xy.append(c)
            # generated: n_gen targets from ONE reference (the first picked press), random centre and depth
            r = train[int(pick[0])]
            ref = ps.image(r)
            m = gd.disc_mask((H, W), r.center_xy_px, r.contact_radius_px)
            g_xy = rng.uniform(lo, hi, size=(n_gen, 2))
            reqs = [
                gen.prepare(
                    ref,
                    bg,
                    ref_depth_mm=depth(r),
                    target_depth_mm=float(rng.uniform(dlo, dhi)),
                    target_pose=gd.Pose(float(c[0]), float(c[1])),
                    ref_mask=m,
                )
                for c in g_xy
            ]
            g_d = [im.astype(np.float32) - bgf for im in gen.generate_many(reqs, bg)]
            train_sets = {
                "real only": (Xk, Yk, f"{k} real"),
                "real + shifted": (
                    np.concatenate([Xk, feats(sh_d)]),
                    np.concatenate([Yk, tgt(np.array(sh_xy))]),
                    f"{k} real + {len(sh_d)} translated copies of them",
                ),
                "real + generated": (
                    np.concatenate([Xk, feats(g_d)]),
                    np.concatenate([Yk, tgt(g_xy)]),
                    f"{k} real + {n_gen} generated from 1 of them",
                ),
            }
            for name, (X, Y, desc) in train_sets.items():
                if name not in sets:
                    continue
                net = _train_pose(X, Y, steps, seed=s, pose_net=POSE_HEADS[head])
                with torch.inference_mode():
                    p = net(torch.from_numpy(Xte)).numpy()
                xy = np.stack([(p[:, 0] + 1) / 2 * W, (p[:, 1] + 1) / 2 * H], 1)
                res.setdefault(f"{k}|{name}|{desc}", []).append(errs(xy, xy_te))
                log.info("real pose k=%d seed %d %s: %.1f px", k, s, name, res[f"{k}|{name}|{desc}"][-1]["xy_err_px"])
    for key, v in res.items():
        k, name, desc = key.split("|")
        row = {kk: float(np.mean([e[kk] for e in v])) for kk in v[0]}
        row["xy_err_std_px"] = float(np.std([e["xy_err_px"] for e in v]))
        method = name if name.startswith("centroid") else f"CNN {name}" + (f" ({head} head)" if head != "flat" else "")
        train_desc = desc if name.startswith("centroid") else f"{desc}, {steps} steps"
        rows.append({"method": method, "train": train_desc, "seeds": len(v)} | row)
    for r in rows:
        r["test"] = f"{len(test)} held-out real presses (640x480 px; labels are integer px)"
    return rows


def _train_pose(X: np.ndarray, Y: np.ndarray, steps: int, seed: int, pose_net):
    """The pose CNN of :mod:`vtrack.bench.generate` with 2 outputs (x, y), Adam 2e-3, ``steps`` steps of 32."""
    import torch

    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    net = pose_net(n_out=2)
    opt = torch.optim.Adam(net.parameters(), lr=2e-3)
    Xt, Yt = torch.from_numpy(X), torch.from_numpy(Y)
    for _ in range(steps):
        idx = torch.from_numpy(rng.integers(0, len(Xt), 32))
        loss = ((net(Xt[idx]) - Yt[idx]) ** 2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    return net.eval()


# ----------------------------------------------------------------------------------------------- force diagnosis
def force_diagnosis(
    quick: bool = False, press_dir: str | Path | None = None, steps: int = 800, seeds: int = 3, n_per_ref: int = 20
) -> list[dict]:
    """Why generated augmentation hurts depth (force) regression on the real presses (see
    :func:`vtrack.bench.generate.force_study` for the set-up: 24 real training presses, 24 held-out).

    1. Depth response: the real-only regressor (trained on the 24 real presses) reads the depth of (a) the
       held-out real presses and (b) images generated from the training presses for the held-out presses'
       centres and depths; the least-squares slope of read against labelled depth and the mean bias say
       whether a generated "1.4 mm" looks like a real 1.4 mm press to a model of the real sensor.
    2. Fixes, same ``steps`` and seeds as the force study: fraction of generated images per batch (0.5, 0.25,
       0.1); targets at the real training presses' own depths and centres (every ordered pair of training
       presses, i.e. no depth outside what the sensor showed); and pseudo-labels (the generated images
       relabelled by the real-only regressor, i.e. trusting the image over the requested depth)."""
    import torch

    from vtrack.bench.generate import _depth_features, _press_depth, _train_depth_cnn
    from vtrack.paths import shared_data_dir
    from vtrack.tactile.generate import data as gd
    from vtrack.tactile.generate.generator import TactileGenerator
    from vtrack.tactile.generate.train import REAL_HOLDOUT
    from vtrack.tactile.pressset import load_press_set

    root = Path(press_dir) if press_dir is not None else shared_data_dir() / "gelsight_ball_presses"
    ps = load_press_set(root)
    train, test = ps.split(REAL_HOLDOUT)
    bg = ps.background()
    H, W = bg.shape[:2]
    if quick:
        steps, seeds, n_per_ref = 300, 1, 6

    def depth(p) -> float:
        return _press_depth(ps, p)

    def feats(imgs: list[np.ndarray]) -> np.ndarray:
        return _depth_features(imgs, bg)

    Xtr = feats([ps.image(p) for p in train])
    Ytr = np.array([depth(p) for p in train], np.float32)
    Xte = feats([ps.image(p) for p in test])
    Yte = np.array([depth(p) for p in test], np.float32)
    lo, hi = float(Ytr.min()), float(Ytr.max())
    cx = [p.center_xy_px[0] for p in train]
    cy = [p.center_xy_px[1] for p in train]
    gen = TactileGenerator(threads=0)
    rng = np.random.default_rng(11)

    def make(ref_p, targets: list[tuple[float, float, float]]) -> list[np.ndarray]:
        ref = ps.image(ref_p)
        m = gd.disc_mask((H, W), ref_p.center_xy_px, ref_p.contact_radius_px)
        reqs = [
            gen.prepare(ref, bg, ref_depth_mm=depth(ref_p), target_depth_mm=d, target_pose=gd.Pose(x, y), ref_mask=m)
            for x, y, d in targets
        ]
        return gen.generate_many(reqs, bg)

    # the force study's generated set: random centre in the real range, random depth in the training range
    g_img, g_d = [], []
    for p in train:
        t = [
            (float(rng.uniform(min(cx), max(cx))), float(rng.uniform(min(cy), max(cy))), float(rng.uniform(lo, hi)))
            for _ in range(n_per_ref)
        ]
        g_img += make(p, t)
        g_d += [d for *_, d in t]
    Xg, Yg = feats(g_img), np.array(g_d, np.float32)
    # at the real training presses' own centres and depths (every ordered pair of distinct training presses)
    p_img, p_d = [], []
    for i, p in enumerate(train):
        others = [q for j, q in enumerate(train) if j != i]
        t = [(q.center_xy_px[0], q.center_xy_px[1], depth(q)) for q in others]
        p_img += make(p, t)
        p_d += [d for *_, d in t]
    Xp, Yp = feats(p_img), np.array(p_d, np.float32)
    # for the response check: each held-out press generated from a training reference (cycled)
    h_img = []
    for k, q in enumerate(test):
        h_img += make(train[k % len(train)], [(q.center_xy_px[0], q.center_xy_px[1], depth(q))])
    Xh = feats(h_img)

    def mae(pred: np.ndarray) -> float:
        return float(np.mean(np.abs(pred - Yte)))

    def fit(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
        A = np.stack([x - x.mean(), np.ones_like(x)], 1)
        c, *_ = np.linalg.lstsq(A, y, rcond=None)
        return float(c[0]), float(np.mean(y - x))

    rows: list[dict] = []
    real_nets = []
    resp = {"real": [], "gen": [], "gen_train": []}
    for s in range(seeds):
        net = _train_depth_cnn((Xtr, Ytr), None, steps, seed=s)
        real_nets.append(net)
        with torch.inference_mode():
            resp["real"].append(net(torch.from_numpy(Xte)).numpy())
            resp["gen"].append(net(torch.from_numpy(Xh)).numpy())
            resp["gen_train"].append(net(torch.from_numpy(Xg)).numpy())
    for key, x, label in (
        ("real", Yte, "held-out REAL presses"),
        ("gen", Yte, "images GENERATED for the held-out presses (centre, depth)"),
        ("gen_train", Yg, "the force study's generated training images (random centre, depth)"),
    ):
        read = np.mean(resp[key], 0)
        slope, bias = fit(x, read)
        rows.append(
            {
                "method": f"depth response: real-only CNN reads {label}",
                "train": f"{len(train)} real, {steps} steps",
                "seeds": seeds,
                "slope": slope,
                "bias_mm": bias,
                "read_std_mm": float(np.std(read - x)),
                "depth_mae_mm": float(np.mean(np.abs(read - x))),
            }
        )
    # pseudo-labels: what the real-only regressors read in the generated images
    with torch.inference_mode():
        Yg_pseudo = np.mean([n(torch.from_numpy(Xg)).numpy() for n in real_nets], 0).astype(np.float32)
    with torch.inference_mode():
        per_real = [mae(n(torch.from_numpy(Xte)).numpy()) for n in real_nets]
    rows.append(
        {
            "method": "depth CNN, real only",
            "train": f"{len(train)} real, {steps} steps",
            "seeds": seeds,
            "depth_mae_mm": float(np.mean(per_real)),
            "depth_mae_std_mm": float(np.std(per_real)),
        }
    )
    variants = [
        ("real + generated, 50 % of each batch", (Xg, Yg), 0.5),
        ("real + generated, 25 %", (Xg, Yg), 0.25),
        ("real + generated, 10 %", (Xg, Yg), 0.1),
        ("real + generated at the training presses' centres and depths, 50 %", (Xp, Yp), 0.5),
        ("real + generated, pseudo-labelled by the real-only CNN, 50 %", (Xg, Yg_pseudo), 0.5),
    ]
    for name, extra, frac in variants:
        per = []
        for s in range(seeds):
            net = _train_depth_cnn((Xtr, Ytr), extra, steps, seed=s, extra_frac=frac)
            with torch.inference_mode():
                per.append(mae(net(torch.from_numpy(Xte)).numpy()))
        n_extra = len(extra[1])
        rows.append(
            {
                "method": f"depth CNN, {name}",
                "train": f"{len(train)} real + {n_extra} generated, {steps} steps",
                "seeds": seeds,
                "depth_mae_mm": float(np.mean(per)),
                "depth_mae_std_mm": float(np.std(per)),
            }
        )
        log.info("force diag %s: %.3f mm", name, rows[-1]["depth_mae_mm"])
    for r in rows:
        r["test"] = f"{len(test)} held-out real presses, depth {Yte.min():.2f}-{Yte.max():.2f} mm"
    return rows


def build_table(classify_rows: list[dict], pose_rows: list[dict], force_rows: list[dict]) -> BenchTable:
    """The stage's table from the rows of :func:`classify_study`, :func:`real_pose_study` and
    :func:`force_diagnosis` (any may be empty: the parts can run in separate processes)."""
    table = BenchTable(stage="generate_downstream", error_key="error", time_key="ms")
    for r in classify_rows:
        table.add(
            method=f"classify: {r['method']}",
            setting=f"SIMULATED YCB patches; train {r['train']}; test {r['test']}; {r['steps']} steps; "
            f"{r['seeds']} seed(s)",
            ms=0.0,
            error=1.0 - r["accuracy"],
            accuracy=r["accuracy"],
            accuracy_std=r["accuracy_std"],
        )
    for r in pose_rows:
        table.add(
            method=f"pose real: {r['method']}",
            setting=f"REAL ball presses; train {r['train']}; test {r['test']}; {r['seeds']} seed(s)",
            ms=0.0,
            error=r["xy_err_px"],
            x_err_px=r["x_err_px"],
            y_err_px=r["y_err_px"],
            xy_err_px=r["xy_err_px"],
            xy_err_std_px=r.get("xy_err_std_px", 0.0),
        )
    for r in force_rows:
        extra = {k: r[k] for k in ("slope", "bias_mm", "read_std_mm", "depth_mae_std_mm") if k in r}
        table.add(
            method=f"force diag: {r['method']}",
            setting=f"REAL presses; train {r['train']}; test {r['test']}; {r['seeds']} seed(s)",
            ms=0.0,
            error=r["depth_mae_mm"],
            depth_mae_mm=r["depth_mae_mm"],
            **extra,
        )
    table.notes += NOTES
    return table


NOTES = [
    "`error` mixes units by part: 1 - accuracy (classify), mean Euclidean centre error in px at 640x480 "
    "(pose real), depth MAE in mm (force diag); no timing is measured (ms = 0), so the Pareto plot means "
    "nothing here.",
    "Every model trains for a fixed number of optimiser steps with one torch thread (results do not depend "
    "on machine load).",
    "classify rows are SIMULATED (shared YCB meshes, ray cast by the simulator, rendered by the independent "
    "optical model, unit seed 4242, which the generator never saw); pose real and force diag rows are the "
    "REAL shared GelSight ball presses (train = the generator's even-index half, test = the odd-index half).",
    "Command: `vtrack --threads 1 bench generate_downstream` (`VTRACK_BENCH_GENDOWN_PARTS=classify,pose,force` "
    "picks parts; `--quick` for a smoke run).",
]


def run(quick: bool = False, press_dir: str | Path | None = None) -> BenchTable:
    import os

    parts = os.environ.get("VTRACK_BENCH_GENDOWN_PARTS", "classify,pose,force").split(",")
    return build_table(
        classify_study(quick) if "classify" in parts else [],
        real_pose_study(quick, press_dir) if "pose" in parts else [],
        force_diagnosis(quick, press_dir) if "force" in parts else [],
    )
