"""``vtrack bench dome``: GNN vs CNN dome reconstruction, with/without pressure for force, ms per frame.

Operating points: the fine-stage output resolution (dense template subsets of 256 / 512 / 1024 vertices;
the fine stage is evaluated only at those vertices, GT is the same subset). The no-deformation template
is added as a reference row (how much of each metric comes for free on this test set).
"""

from __future__ import annotations

import numpy as np

from vtrack.bench.harness import BenchTable


def run(quick: bool = False) -> BenchTable:
    import torch

    from vtrack.dome.bundle import load_bundle
    from vtrack.dome.evaluate import template_baseline, time_end_to_end
    from vtrack.dome.metrics import evaluate_predictions
    from vtrack.dome.model import DomeGeometry
    from vtrack.dome.reconstruct import default_weights
    from vtrack.dome.simulate import make_dataset
    from vtrack.dome.train import Batcher, predict

    torch.set_num_threads(1)
    n_test = 40 if quick else 300
    n_time = 10 if quick else 40
    table = BenchTable(stage="dome", error_key="cd_fine", time_key="ms")
    te = None
    for method in ("gnn", "cnn"):
        path = default_weights(method)
        model, heads, cfg, _ = load_bundle(path)
        geo = DomeGeometry(cfg)
        if te is None:
            te = make_dataset(n_test, 12345, cfg)
            tb = template_baseline(te, geo)
            table.add(
                method="template",
                setting="no deformation",
                ms=0.0,
                n_dense=cfg.n_dense,
                **{k: round(v, 4) for k, v in tb.items() if not k.startswith("force")},
                force_mae=round(tb["force_mae"], 4),
                force_mae_nop=round(tb["force_mae"], 4),
            )
        bte = Batcher(method, te, geo, f"{n_test}-12345-{cfg.to_dict()}")
        for n_dense in (256, 512, cfg.n_dense):
            sub = np.linspace(0, cfg.n_dense - 1, n_dense).round().astype(int)
            model.decoder.set_dense(geo.dense_rest[sub])
            pred = predict(model, heads, bte)
            gt = {
                "coarse": te["coarse_mm"],
                "dense": te["dense_mm"][:, sub],
                "contact": te["contact_coarse"],
                "force": te["force_n"],
                "dense_rest": geo.dense_rest[sub],
            }
            m = evaluate_predictions(pred, gt)
            ms, cpu_ms = time_end_to_end(
                method, path, te["image"][:n_time], te["pressure_kpa"][:n_time], geo.dense_rest[sub]
            )
            table.add(
                method=method,
                setting=f"fine {n_dense} pts",
                ms=round(ms, 2),
                cpu_ms=round(cpu_ms, 2),
                n_dense=n_dense,
                **{k: round(v, 4) for k, v in m.items() if not k.startswith("force")},
                force_mae=round(m["force_mae"], 4),
                force_mae_nop=round(m["force_nop_mae"], 4),
            )
        model.decoder.set_dense(geo.dense_rest)
    table.notes += [
        f"Held-out simulated test set: {n_test} presses (seed 12345), lengths in mm, force in N. "
        "`force_mae` uses the shipped force net with the pressure input (GNN: GNN + marker patches, CNN: FiLM "
        "on the feature map; FusionTouch S18-S23, `vtrack.dome.force`), `force_mae_nop` the same net trained "
        "without pressure.",
        "ms = median wall time per frame of `DomeReconstructor.reconstruct`, one frame at a time, every thread pool "
        "(torch, OpenCV, BLAS) at 1 thread: input checks -> marker extraction -> Delaunay graph -> GNN (or image -> "
        "CNN) -> dense surface + force -> marker-match validity check. On a machine shared with other jobs "
        "wall times are noisy upper bounds; `cpu_ms` is the process CPU time per frame (what one free core needs).",
        "`template` = predicting the no-contact reference state (the rest dome inflated by the known "
        "pressure): ~80 % of the dome does not move, so whole-surface metrics (CD, HD95, F-scores) start low "
        "and only `vertex_err_moved` shows the contact region.",
        "Command: `vtrack bench dome`" + (" --quick" if quick else ""),
    ]
    return table
