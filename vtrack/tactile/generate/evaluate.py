"""``vtrack tactile generate-eval``: generated vs real images on a labelled real press set.

Protocol (issue #24): one held-out press is the reference; every other held-out press is generated from
the reference, the target's labelled contact centre (position control: the reference footprint moved there)
and its labelled contact radius (depth ``d = R - sqrt(R^2 - a^2)`` through the ball geometry). Each output
is compared with the real image on the contact crop (+-2 labelled contact radii, as ``vtrack bench simreal``)
by MSE (grey levels^2, all channels), SSIM (Gaussian window, sigma 1.5 px) and PSNR (dB), and on the full
frame by MSE and SSIM; means over the presses. Beside three baselines computed the same way:
``background`` (the no-contact frame), ``copy`` (the reference unchanged) and ``shift`` (the reference's
contact patch, +-1 equivalent radius around its footprint, moved to the target centre). An extra row
``shift_denoised`` (the smoothed patch moved, no network) separates the gain of the smoothing from the
network's.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError

METRICS = ("crop_mse", "crop_ssim", "crop_psnr", "full_mse", "full_ssim")


def image_scores(out: np.ndarray, real: np.ndarray, crop: tuple[slice, slice]) -> dict[str, float]:
    """Crop and full-frame MSE / SSIM (and crop PSNR) of ``out`` against ``real`` (uint8 BGR)."""
    from vtrack.bench.simreal import ssim

    o, r = out.astype(np.float32), real.astype(np.float32)
    cm = float(((o[crop] - r[crop]) ** 2).mean())
    return {
        "crop_mse": cm,
        "crop_ssim": ssim(o[crop], r[crop]),
        "crop_psnr": 10.0 * math.log10(255.0**2 / max(cm, 1e-10)),
        "full_mse": float(((o - r) ** 2).mean()),
        "full_ssim": ssim(o, r),
    }


def generate_eval(
    press_dir: str | Path,
    *,
    weights: str | Path | None = None,
    holdout: str | None = None,
    reference: str | None = None,
    modes: tuple[str, ...] | None = None,
    max_presses: int = 0,
    threads: int = 0,
    perturb: tuple[float, float] = (0.0, 1.0),
) -> dict[str, Any]:
    """Score the generator (``generator`` = ``modes[0]``; further modes as extra keys) and the baselines.

    Args:
        press_dir: labelled press set (labels.csv + meta or a shipped preset).
        weights: generator weights (default: the shipped ones).
        holdout: presses to evaluate (default: the weights' real hold-out, i.e. never trained on).
        reference: file name of the reference press (default: the first evaluated press).
        modes: generator modes to score (default: two-stage, stage 1, and every baseline the weights hold:
            hybrid, separate, flow1/2/4/8).
        max_presses: > 0 keeps that many targets (quick runs).
        perturb: (dx px, scale): the target pose moved ``dx`` px along +x and the reference footprint
            scaled about its centre (mask-robustness study; (0, 1) = none).
    """
    from vtrack.bench.simreal import _crop_box
    from vtrack.sim.presses import press_depth_mm
    from vtrack.tactile.generate import data as gd
    from vtrack.tactile.generate.generator import FLOW_STEPS, TactileGenerator
    from vtrack.tactile.pressset import load_press_set

    ps = load_press_set(press_dir)
    if modes is None:
        avail = TactileGenerator(weights, threads=threads).available
        modes = ("two_stage", "stage1")
        modes += ("hybrid",) * ("hybrid" in avail) + ("separate",) * ("position" in avail)
        modes += tuple(f"flow{k}" for k in FLOW_STEPS) * ("flow" in avail)
        modes += tuple(f"flowx{k}" for k in FLOW_STEPS) * ("flowx" in avail)
    gens = {m: TactileGenerator(weights, mode=m, threads=threads) for m in modes}
    first = next(iter(gens.values()))
    if holdout is None:
        holdout = first.meta.get("data", {}).get("real_holdout", "every:2:1")
    presses = ps.presses if holdout == "all" else ps.split(holdout)[1]
    if reference is not None:
        ref = next((p for p in ps.presses if p.file == reference), None)
        if ref is None:
            raise InputError("reference press not in labels.csv", path=ps.root, field="reference", got=reference)
    else:
        if not presses:
            raise InputError("no presses to evaluate", path=ps.root, field="holdout", got=holdout)
        ref = presses[0]
    targets = [p for p in presses if p.file != ref.file]
    if max_presses > 0:
        targets = targets[:max_presses]
    if not targets:
        raise InputError("no target presses besides the reference", path=ps.root, field="holdout", got=holdout)
    bg = ps.background()
    H, W = bg.shape[:2]
    ref_img = ps.image(ref)
    ref_mask = gd.disc_mask((H, W), ref.center_xy_px, ref.contact_radius_px * perturb[1])
    ref_d = press_depth_mm(ps.ball_radius_mm, ref.contact_radius_px * ps.mm_per_px)
    shift = TactileGenerator(mode="shift")
    rows: dict[str, list[dict[str, float]]] = {k: [] for k in ("background", "copy", "shift", "shift_denoised", *modes)}
    ms: dict[str, float] = {}
    per_press = []
    kws = [
        {
            "ref_depth_mm": ref_d,
            "target_depth_mm": press_depth_mm(ps.ball_radius_mm, t.contact_radius_px * ps.mm_per_px),
            "target_pose": gd.Pose(t.center_xy_px[0] + perturb[0], t.center_xy_px[1], 0.0),
            "ref_mask": ref_mask,
        }
        for t in targets
    ]
    zero = np.zeros((gd.CROP_PX, gd.CROP_PX, 3), np.float32)
    outs: dict[str, list[np.ndarray]] = {}
    for m, g in gens.items():
        t0 = time.perf_counter()
        outs[m] = g.generate_many([g.prepare(ref_img, bg, **kw) for kw in kws], bg)
        ms[m] = (time.perf_counter() - t0) * 1e3 / len(targets)
    outs["shift"] = shift.generate_many([shift.prepare(ref_img, bg, **kw) for kw in kws], bg)
    sd = TactileGenerator(mode="shift_denoised")
    outs["shift_denoised"] = [sd.compose(sd.prepare(ref_img, bg, **kw), bg, zero) for kw in kws]
    for k, t in enumerate(targets):
        real = ps.image(t)
        crop = _crop_box(t, (H, W), 1.0, 2.0)
        rec = {"file": t.file}
        for name, img in (
            ("background", bg),
            ("copy", ref_img),
            *((m, outs[m][k]) for m in ("shift", "shift_denoised", *modes)),
        ):
            s = image_scores(img, real, crop)
            rows[name].append(s)
            rec[name] = s
        per_press.append(rec)

    def mean(rs: list[dict[str, float]]) -> dict[str, float]:
        return {k: float(np.mean([r[k] for r in rs])) for k in METRICS}

    res: dict[str, Any] = {"generator": mean(rows[modes[0]]) | {"mode": modes[0]}}
    for name in ("shift", "copy", "background", "shift_denoised"):
        res[name] = mean(rows[name])
    for m in modes[1:]:
        res[m] = mean(rows[m]) | {"ms_per_image": ms[m]}
    res |= {
        "n": len(targets),
        "ms_per_image": ms[modes[0]],
        "modes": list(modes),
        "press_set": str(ps.root),
        "reference": ref.file,
        "holdout": holdout,
        # presses of this set the weights were trained on: scores over them are not held-out numbers
        "trained_on_targets": _trained_on(first.meta, ps.root, [t.file for t in targets]),
        "weights": str(first.path),
        "crop": "+-2 labelled contact radii around the labelled centre",
        "presses": per_press,
    }
    return res


def _trained_on(meta: dict, root, files: list[str]) -> int:
    """How many of ``files`` (of the press set at ``root``) the weights' training used (0 for another set)."""
    from pathlib import Path

    data = meta.get("data", {}) if isinstance(meta, dict) else {}
    trained = data.get("press_set")
    # the same set by path, or by folder name (the weights may have been trained on another machine's copy)
    if not trained or (Path(trained).resolve() != Path(root).resolve() and Path(trained).name != Path(root).name):
        return 0
    return len(set(files) & set(data.get("real_train", [])))
