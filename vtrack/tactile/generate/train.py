"""Training of the tactile generator (``vtrack tactile generate-train``).

Data (see :mod:`vtrack.tactile.generate.data`):
- simulated presses of spheres (radius 1.5, 2, 3, 4 mm), a lying cylinder, a cross and a T at known depths,
  rendered by the independent optical model on the real GelSight background (320x240, 0.059 mm/px), two
  jittered sensor units;
- the TRAINING half of the real GelSight ball presses (even indices; the odd ones are held out for
  ``generate-eval`` and never seen here), depth from the labelled contact radius through the ball geometry.

Stages (the paper's recipe at CPU scale):
1. force/depth control: :class:`~.model.UNet` on "force data": every simulated same-site pair (one pose,
   two depths) plus the real training pairs (reference shifted onto the target, two depths); no position
   input.
2. position control: :class:`~.model.ControlBranch` on the frozen stage-1 net, on less data ("position
   data": a sample of simulated pairs across poses plus the real training pairs).
Baseline: :class:`~.model.Hybrid` from scratch on the position data only (the paper's hybrid model).

Loss: mean squared colour-change error (grey levels / 64) in the target crop, weighted 5x on its inner disc;
half of every batch is real pairs.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.tactile.generate import data as gd

#: Hold-out of the real press set: odd indices are evaluation only.
REAL_HOLDOUT = "every:2:1"


@dataclass
class TrainConfig:
    """Training budget and sizes (seconds are wall-clock per stage on the caller's threads)."""

    stage1_seconds: float = 360.0
    stage2_seconds: float = 200.0
    hybrid_seconds: float = 200.0
    batch: int = 16
    lr: float = 2e-3
    channels: tuple[int, int, int] = (12, 24, 32)
    sim_units: int = 2
    sim_poses: int = 8
    sim_depths: int = 4
    stage1_sim_pairs: int = 1500
    stage2_sim_pairs: int = 600
    contact_weight: float = 4.0
    seed: int = 0
    threads: int = 2
    train_hybrid: bool = True
    #: extra baselines (:data:`EXTRAS`): "separate" (a position-only model after stage 1), "flow" (few-step
    #: rectified-flow stage 1, velocity prediction) and "flowx" (the same, predicting the clean target); not in
    #: the default run, which keeps ``generate-train`` within 15 minutes
    extras: tuple[str, ...] = ()
    position_seconds: float = 200.0
    #: position-only pairs: same indenter and unit, different poses, depths within this (mm)
    position_max_dd_mm: float = 0.1
    flow_seconds: float = 360.0
    #: > 0 caps the flow's optimiser steps (to match stage 1's step count for a per-compute comparison)
    flow_max_steps: int = 0
    #: > 0 caps the position model's steps (to match the hybrid's, also trained from scratch)
    position_max_steps: int = 0
    #: extra "stage2" (with ``update``): retrain the control branch on the file's frozen stage 1 for this many
    #: steps (0 = the hybrid's steps in the file: a step-matched comparison), at ``stage2_lr`` (0 = ``lr``)
    stage2_max_steps: int = 0
    stage2_lr: float = 0.0
    log: list = field(default_factory=list)


#: Extra baselines :func:`train` can add (``extras``), each stored under its own key in the weights.
EXTRAS = ("separate", "flow", "flowx", "stage2")


def _pairs(
    bank: gd.PressBank, rng: np.random.Generator, n_cross_sim: int, max_sim_s1: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """(stage-1 pairs, stage-2 pairs) as (K, 2) index arrays (reference, target)."""
    s1, s2 = [], []
    sim = np.flatnonzero(~bank.real)
    real = np.flatnonzero(bank.real)
    for site in np.unique(bank.site[sim]):
        idx = sim[bank.site[sim] == site]
        s1 += [(i, j) for i in idx for j in idx if i != j]
    real_pairs = [(i, j) for i in real for j in real if i != j]
    if max_sim_s1 and len(s1) > max_sim_s1:
        s1 = [s1[k] for k in rng.choice(len(s1), max_sim_s1, replace=False)]
    s1 += real_pairs
    cross = []
    for g in np.unique(bank.group[sim]):
        idx = sim[bank.group[sim] == g]
        for _ in range(max(1, n_cross_sim // max(1, len(np.unique(bank.group[sim]))))):
            i, j = rng.choice(idx, 2, replace=False)
            cross.append((i, j))
    s2 = cross + real_pairs
    return np.array(s1, int), np.array(s2, int)


def _position_pairs(bank: gd.PressBank, max_dd_mm: float) -> np.ndarray:
    """(K, 2) pairs for the separate position-only model: within a group (indenter, unit), different sites
    (poses), depths within ``max_dd_mm`` (the paper's position data: same force, another position). Real
    presses are all one group, each its own site, so the real pairs are those of near-equal depth."""
    out = []
    for g in np.unique(bank.group):
        idx = np.flatnonzero(bank.group == g)
        for i in idx:
            for j in idx:
                if bank.site[i] != bank.site[j] and abs(bank.depth[i] - bank.depth[j]) <= max_dd_mm:
                    out.append((i, j))
    return np.array(out, int).reshape(-1, 2)


def _precompute(bank: gd.PressBank, pairs: np.ndarray, contact_weight: float) -> dict[str, Any]:
    """Network inputs/targets of all ``pairs`` once (float16; the crops are small), plus the loss weights."""
    import torch

    xs, ys, cs, ps = [], [], [], []
    for k in range(0, len(pairs), 256):
        a = gd.pair_arrays(bank, pairs[k : k + 256])
        xs.append(a["x"].astype(np.float16))
        ys.append((a["target"] - a["x"][:, :3]).astype(np.float16))
        cs.append(a["cond"])
        ps.append(a["pose"])
    # the crop is +-2.2 footprint radii: weight the inner disc (contact, rim and shadow) more
    r = np.hypot(*np.meshgrid(np.linspace(-1, 1, gd.CROP_PX), np.linspace(-1, 1, gd.CROP_PX)))
    w = 1.0 + contact_weight * (r <= 0.7).astype(np.float32)
    return {
        "x": torch.from_numpy(np.concatenate(xs)),
        "y": torch.from_numpy(np.concatenate(ys)),
        "cond": torch.from_numpy(np.concatenate(cs)),
        "pose": torch.from_numpy(np.concatenate(ps)),
        "w": torch.from_numpy(w[None, None]),
        "real": torch.from_numpy(bank.real[pairs[:, 1]]),
    }


def _fit(
    net,
    params,
    data: dict[str, Any],
    seconds: float,
    cfg: TrainConfig,
    rng,
    name: str,
    max_steps: int = 0,
    lr: float = 0.0,
) -> dict[str, float]:
    """Adam with cosine decay over a wall-clock budget (or ``max_steps`` > 0 steps, whichever ends first; the
    decay then follows the steps); half of every batch from real pairs (when any). A net with a ``loss``
    method (the flow) computes its own loss. ``lr`` > 0 overrides ``cfg.lr``."""
    import torch

    net.to(memory_format=torch.channels_last)  # ~2x faster small convolutions on CPU
    lr = lr if lr > 0 else cfg.lr
    opt = torch.optim.Adam(params, lr=lr)
    real = np.flatnonzero(data["real"].numpy())
    sim = np.flatnonzero(~data["real"].numpy())
    t0 = time.perf_counter()
    step, losses = 0, []
    while True:
        el = time.perf_counter() - t0
        if el >= seconds or (max_steps > 0 and step >= max_steps):
            break
        frac = max(el / seconds, step / max_steps if max_steps > 0 else 0.0)
        for g in opt.param_groups:
            g["lr"] = lr * 0.5 * (1 + np.cos(np.pi * min(1.0, frac)))
        nr = cfg.batch // 2 if len(real) and len(sim) else (cfg.batch if len(real) else 0)
        idx = np.concatenate(
            [rng.choice(real, nr), rng.choice(sim, cfg.batch - nr)] if len(sim) else [rng.choice(real, nr)]
        )
        ti = torch.from_numpy(idx)
        x = data["x"][ti].float().contiguous(memory_format=torch.channels_last)
        y = data["y"][ti].float()
        if hasattr(net, "loss"):
            loss = net.loss(x, data["cond"][ti], y, data["w"])
        else:
            pred = net(x, data["cond"][ti], data["pose"][ti])
            loss = (data["w"] * (pred - y) ** 2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
        step += 1
    out = {"stage": name, "steps": step, "seconds": round(time.perf_counter() - t0, 1), "lr": lr}
    out["loss_last50"] = float(np.mean(losses[-50:])) if losses else float("nan")
    cfg.log.append(out)
    return out


def build_bank(cfg: TrainConfig, press_dir: str | Path | None = None) -> tuple[gd.PressBank, dict]:
    """Simulated + real-training bank, and a description of it."""
    import cv2

    from vtrack.paths import shared_data_dir
    from vtrack.tactile.pressset import load_press_set

    root = Path(press_dir) if press_dir is not None else shared_data_dir() / "gelsight_ball_presses"
    ps = load_press_set(root)
    train, test = ps.split(REAL_HOLDOUT)
    bg = ps.background()
    H, W = bg.shape[:2]
    bg_sim = cv2.resize(bg, (W // 2, H // 2), interpolation=cv2.INTER_AREA)
    t0 = time.perf_counter()
    sim = gd.sim_bank(
        bg_sim, ps.mm_per_px * 2, units=cfg.sim_units, poses=cfg.sim_poses, depths=cfg.sim_depths, seed=cfg.seed
    )
    sim_s = time.perf_counter() - t0
    real = gd.real_bank(ps, train)
    info = {
        "press_set": str(root),
        "real_train": [p.file for p in train],
        "real_held_out": [p.file for p in test],
        "real_holdout": REAL_HOLDOUT,
        "sim_presses": len(sim),
        "sim_render_seconds": round(sim_s, 1),
        "indenters": list(gd.INDENTERS),
    }
    return gd.PressBank.concat([sim, real]), info


def train(
    cfg: TrainConfig | None = None,
    out: str | Path | None = None,
    press_dir: str | Path | None = None,
    update: str | Path | None = None,
) -> Path:
    """Train stage 1, stage 2 (and the hybrid baseline, and ``cfg.extras``) and save the weights (``.pt``, a
    few hundred kB).

    With ``update`` (an existing weights file) only ``cfg.extras`` are trained (on a bank rebuilt with the
    file's own data settings and seed) and added to a copy of that file's networks, so the baselines can be
    added without retraining (and changing) the shipped models.
    """
    import torch

    from vtrack.tactile.generate.model import ControlBranch, Flow, Hybrid, Position, Stage1, TwoStage, UNet

    cfg = cfg or TrainConfig()
    bad = [e for e in cfg.extras if e not in EXTRAS]
    if bad:
        from vtrack.errors import InputError

        raise InputError("unknown extra baseline", field="extras", expected=" | ".join(EXTRAS), got=",".join(bad))
    torch.set_num_threads(max(1, cfg.threads))
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    old: dict[str, Any] | None = None
    if update is not None:
        old = torch.load(Path(update), map_location="cpu", weights_only=True)
        om = old["meta"]
        for k in ("sim_units", "sim_poses", "sim_depths", "stage1_sim_pairs", "stage2_sim_pairs", "seed"):
            setattr(cfg, k, om[k])
        cfg.channels = tuple(om["channels"])
        cfg.log = list(om.get("log", []))
        # per-compute comparisons: by default an extra gets the optimiser steps of its counterpart in the file
        # (the flow those of stage 1, the position model those of the hybrid, both trained from scratch)
        done = {r["stage"]: r["steps"] for r in cfg.log}
        cfg.flow_max_steps = cfg.flow_max_steps or done.get("stage1", 0)
        cfg.position_max_steps = cfg.position_max_steps or done.get("hybrid", 0)
        cfg.stage2_max_steps = cfg.stage2_max_steps or done.get("hybrid", 0)
        if press_dir is None and om.get("data", {}).get("press_set"):
            press_dir = om["data"]["press_set"]
    bank, info = build_bank(cfg, press_dir)
    s1, s2 = _pairs(bank, rng, cfg.stage2_sim_pairs, cfg.stage1_sim_pairs)
    info |= {"stage1_pairs": len(s1), "stage2_pairs": len(s2)}

    t0 = time.perf_counter()
    d1 = _precompute(bank, s1, cfg.contact_weight)
    d2 = _precompute(bank, s2, cfg.contact_weight) if old is None or "stage2" in cfg.extras else None
    info["pair_seconds"] = round(time.perf_counter() - t0, 1)
    if old is None:
        base = UNet(ch=cfg.channels)
        _fit(Stage1(base), base.parameters(), d1, cfg.stage1_seconds, cfg, rng, "stage1")
        for p in base.parameters():
            p.requires_grad_(False)
        two = TwoStage(base, ControlBranch(base))
        _fit(two, two.control.parameters(), d2, cfg.stage2_seconds, cfg, rng, "stage2")
        state: dict[str, Any] = {"base": base.state_dict(), "control": two.control.state_dict()}
        if cfg.train_hybrid:
            hyb = Hybrid(cfg.channels)
            _fit(hyb, hyb.parameters(), d2, cfg.hybrid_seconds, cfg, rng, "hybrid")
            state["hybrid"] = hyb.state_dict()
    else:
        state = {k: v for k, v in old.items() if k != "meta"}
        info = old["meta"]["data"] | {k: v for k, v in info.items() if k.endswith("_pairs")}
    if "stage2" in cfg.extras and old is not None:
        # a new control branch on the file's frozen stage 1 (replaces the file's branch; stage 1 is unchanged);
        # the replaced branch's log entry is kept, renamed
        cfg.log = [r | {"stage": "stage2 (replaced)"} if r["stage"] == "stage2" else r for r in cfg.log]
        base = UNet(ch=cfg.channels)
        base.load_state_dict({n: t.float() for n, t in old["base"].items()})
        for p in base.parameters():
            p.requires_grad_(False)
        two = TwoStage(base, ControlBranch(base))
        _fit(
            two,
            two.control.parameters(),
            d2,
            cfg.stage2_seconds,
            cfg,
            rng,
            "stage2",
            max_steps=cfg.stage2_max_steps,
            lr=cfg.stage2_lr,
        )
        state["control"] = two.control.state_dict()
    if "separate" in cfg.extras:
        sp = _position_pairs(bank, cfg.position_max_dd_mm)
        info["position_pairs"] = len(sp)
        info["position_real_pairs"] = int(bank.real[sp[:, 1]].sum())
        pos = Position(cfg.channels)
        _fit(
            pos,
            pos.parameters(),
            _precompute(bank, sp, cfg.contact_weight),
            cfg.position_seconds,
            cfg,
            rng,
            "position",
            max_steps=cfg.position_max_steps,
        )
        state["position"] = pos.state_dict()
    if "flow" in cfg.extras:
        sigma = float(d1["y"].float().std())
        flow = Flow(cfg.channels, sigma=sigma)
        _fit(flow, flow.parameters(), d1, cfg.flow_seconds, cfg, rng, "flow", max_steps=cfg.flow_max_steps)
        state["flow"] = flow.state_dict()
    if "flowx" in cfg.extras:  # the same flow, predicting the clean correction (x0 / DDIM-style)
        flowx = Flow(cfg.channels, sigma=float(d1["y"].float().std()), predict="target")
        _fit(flowx, flowx.parameters(), d1, cfg.flow_seconds, cfg, rng, "flowx", max_steps=cfg.flow_max_steps)
        state["flowx"] = flowx.state_dict()
    meta = {k: v for k, v in asdict(cfg).items() if k != "log"} | {"log": cfg.log, "data": info}
    if old is not None:  # keep the budgets the shipped nets were trained with
        meta = old["meta"] | {k: meta[k] for k in meta if k not in old["meta"] or k in ("log", "data")}
        meta["extras"] = tuple(sorted(set(old["meta"].get("extras", ())) | set(cfg.extras)))
    meta["crop_px"], meta["crop_k"] = gd.CROP_PX, gd.CROP_K
    meta["delta_scale"] = gd.DELTA_SCALE
    state["meta"] = meta
    from vtrack.io.jsonio import atomic_torch_save
    from vtrack.tactile.generate import default_weights_path

    path = Path(out) if out is not None else default_weights_path()
    # half precision halves the shipped file; the nets run in float32
    state = {k: ({n: t.half() for n, t in v.items()} if k != "meta" else v) for k, v in state.items()}
    return atomic_torch_save(path, state)
