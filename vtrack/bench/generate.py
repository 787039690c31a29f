"""``vtrack bench generate``: controllable tactile generation (issue #24) on real held-out GelSight presses.

Rows:
- ``generate-eval`` of the shipped weights on the held-out half of the shared real press set (odd indices,
  never trained on): the two-stage generator, stage 1 alone (force control only; the position is then the
  geometric move of the reference alone), the hybrid single-model baseline, and the ``shift``, ``copy`` and
  ``background`` baselines (see :mod:`vtrack.tactile.generate.evaluate`);
- mask-perturbation robustness (the paper's Table 6/7 analogue): the target mask translated by 2/4/6 px
  (full-resolution px, direction +x) or scaled by 0.8/1.2 before generation, two-stage model;
- throughput: images/s of 320x240 generation (prepare + network + compose, batches of 32) at 1 and 2 torch
  threads, on simulated 320x240 references.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from vtrack.bench.harness import BenchTable


def throughput(threads: int, n: int = 128, mode: str = "two_stage", batch: int = 32) -> float:
    """Generated 320x240 images per second (prepare + network + compose) with ``threads`` torch threads."""
    import torch

    from vtrack.sim.presses import ball_height
    from vtrack.sim.tactile_optics import OpticalModel
    from vtrack.tactile.generate import data as gd
    from vtrack.tactile.generate.generator import TactileGenerator
    from vtrack.tactile.sensors import default_background

    W, H, mpp = 320, 240, 0.059
    bg = default_background("gelsight", W, H)
    ref = OpticalModel.for_sensor("gelsight", seed=1).render(ball_height((H, W), (160, 120), 2.0, 0.8, mpp), mpp, bg)
    old = torch.get_num_threads()
    gen = TactileGenerator(mode=mode, threads=threads)
    rng = np.random.default_rng(0)
    ref_mask = gd.detect_contact(ref, bg)
    poses = [gd.Pose(float(rng.uniform(60, 260)), float(rng.uniform(60, 180)), 0.0) for _ in range(n)]
    depths = rng.uniform(0.3, 1.3, n)

    def run() -> None:
        reqs = [
            gen.prepare(ref, bg, ref_depth_mm=0.8, target_depth_mm=float(d), target_pose=p, ref_mask=ref_mask)
            for p, d in zip(poses, depths, strict=True)
        ]
        gen.generate_many(reqs, bg, batch=batch)

    run()  # warm-up
    t0 = time.perf_counter()
    run()
    dt = time.perf_counter() - t0
    torch.set_num_threads(old)
    return n / dt


def run(quick: bool = False, press_dir: str | Path | None = None) -> BenchTable:
    from vtrack.paths import shared_data_dir
    from vtrack.tactile.generate.evaluate import generate_eval

    root = Path(press_dir) if press_dir is not None else shared_data_dir() / "gelsight_ball_presses"
    table = BenchTable(stage="generate", error_key="crop_mse")
    maxp = 8 if quick else 0
    res = generate_eval(root, max_presses=maxp)
    names = {
        "generator": "two-stage (stage 1 + ControlNet branch)",
        "stage1": "stage 1 only (force control)",
        "hybrid": "hybrid single model",
        "shift": "shift baseline",
        "copy": "copy baseline",
        "background": "background baseline",
    }
    for key, label in names.items():
        r = res[key]
        ms = res["ms_per_image"] if key == "generator" else r.get("ms_per_image", 0.0)
        table.add(
            method=label,
            setting=f"{res['n']} held-out real presses from {res['reference']}",
            ms=ms,
            **{k: r[k] for k in ("crop_mse", "crop_ssim", "crop_psnr", "full_mse", "full_ssim")},
        )
    perturb = [(2, 1.0), (4, 1.0), (6, 1.0), (0, 0.8), (0, 1.2)] if not quick else [(4, 1.0)]
    for dx, sc in perturb:
        r = generate_eval(root, max_presses=maxp, modes=("two_stage",), perturb=(dx, sc))
        table.add(
            method="two-stage, perturbed mask",
            setting=f"mask shift {dx} px, scale {sc}",
            ms=r["ms_per_image"],
            **{k: r["generator"][k] for k in ("crop_mse", "crop_ssim", "crop_psnr", "full_mse", "full_ssim")},
        )
    for th in (1, 2):
        ips = throughput(th, n=64 if quick else 128)
        table.add(
            method="throughput 320x240", setting=f"{th} torch thread(s), batch 32", ms=1e3 / ips, images_per_s=ips
        )
    table.notes += [
        f"Real set {root.name}: reference {res['reference']}, targets = the other held-out (odd-index) presses; "
        "crop = +-2 labelled contact radii; MSE grey levels^2, SSIM Gaussian sigma 1.5 px; means over presses.",
        "Perturbed rows: the reference footprint is moved dx px (+x) off the labelled target centre / scaled "
        "about its centre before generation (paper Table 6/7 analogue; scoring crop unchanged).",
        "Throughput on simulated 320x240 GelSight references; the machine is shared (load varies), so ms are "
        "upper bounds.",
        "Command: `vtrack bench generate` (`--quick`: 8 targets, one perturbation).",
    ]
    return table
