"""Training: two-phase reconstruction training (coarse, then fine) and force heads, for GNN and CNN.

Losses (our reading of S13-S17): contact BCE on the coarse template (S13); L2 position loss on contact
points (S14) and on non-contact points (S15), on the coarse template (phase 1) and the dense template
(phase 2); Laplacian loss (S16, uniform Laplacian of the dense kNN graph, predicted vs GT) and
edge-length loss (S17, kNN edge lengths predicted vs GT). Phase 2 trains the fine stage with the encoder
at a tenth of the learning rate. Force heads are trained last on the frozen reconstruction net, once
with the internal pressure (FiLM) and once without.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from vtrack.dome.bundle import (
    TrainConfig,
    build_model,
    bundle_train_config,
    load_bundle,
    read_bundle,
    save_bundle,
    weights_dir,
)
from vtrack.dome.model import DomeConfig, DomeGeometry, knn_np


def load_sets(tc: TrainConfig, cfg: DomeConfig, progress: bool = False) -> tuple[dict, dict]:
    from vtrack.dome.simulate import make_dataset

    return (
        make_dataset(tc.n_train, tc.seed, cfg, progress=progress),
        make_dataset(tc.n_test, tc.test_seed, cfg, progress=progress),
    )


class Batcher:
    """Builds model inputs and targets for index sets of one dataset."""

    def __init__(self, kind: str, data: dict, geo: DomeGeometry, cache_key: str | None) -> None:
        import torch

        from vtrack.dome.features import prepare_graphs

        self.kind, self.data, self.geo = kind, data, geo
        self.graphs = prepare_graphs(data, geo, cache_key) if kind == "gnn" else None
        t = lambda k, dt=torch.float32: torch.as_tensor(np.asarray(data[k]), dtype=dt)  # noqa: E731
        self.coarse, self.dense = t("coarse_mm"), t("dense_mm")
        self.contact, self.contact_d = t("contact_coarse"), t("contact_dense")
        self.force, self.pressure = t("force_n"), t("pressure_kpa")
        self.ref_inflation = torch.as_tensor(geo.reference_inflation_mm(data["pressure_kpa"]), dtype=torch.float32)
        refs = np.asarray(data["reference_image"])
        if (refs.ndim == 3) != geo.cfg.reference_at_pressure:
            from vtrack.errors import InputError

            raise InputError(
                "dataset reference frames do not match the model's reference protocol",
                field="reference_image",
                expected="(n, S, S), one per pressure" if geo.cfg.reference_at_pressure else "(S, S)",
                got=str(refs.shape),
            )

        self._patches: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.coarse)

    def patches(self) -> np.ndarray:
        """Marker-centred [image, reference] patches (all nodes, 2, P, P) uint8 for the patch force net."""
        if self._patches is None:
            from vtrack.dome.force import PATCH, centers_from_x, marker_patches

            G, refs = self.graphs, np.asarray(self.data["reference_image"])
            out = np.zeros((len(G["x"]), 2, PATCH, PATCH), np.uint8)
            S = self.geo.cfg.image_size
            for i in range(len(self)):
                a, b = G["node_off"][i], G["node_off"][i + 1]
                ref = refs[i] if refs.ndim == 3 else refs
                out[a:b] = marker_patches(self.data["image"][i], ref, centers_from_x(G["x"][a:b], S))
            self._patches = out
        return self._patches

    def inputs(self, idx: np.ndarray, patches: bool = False) -> dict:
        from vtrack.dome.features import collate_graphs, image_batch, slice_graph

        if self.kind == "gnn":
            batch = collate_graphs([slice_graph(self.graphs, int(i)) for i in idx])
            if patches:
                import torch

                P, off = self.patches(), self.graphs["node_off"]
                pt = np.concatenate([P[off[int(i)] : off[int(i) + 1]] for i in idx])
                batch["patches"] = torch.from_numpy(pt).float() / 255.0
        else:
            refs = self.data["reference_image"]
            batch = image_batch(self.data["image"][idx], refs[idx] if refs.ndim == 3 else refs)
        batch["ref_inflation_mm"] = self.ref_inflation[np.asarray(idx)]
        return batch

    def targets(self, idx: np.ndarray) -> dict:
        i = np.asarray(idx)
        return {
            "coarse": self.coarse[i],
            "dense": self.dense[i],
            "contact": self.contact[i],
            "contact_dense": self.contact_d[i],
            "force": self.force[i],
            "pressure": self.pressure[i],
        }


def _dense_graph(geo: DomeGeometry, k: int = 6):
    import torch

    nbr, _ = knn_np(geo.dense_rest, geo.dense_rest, k + 1)
    return torch.as_tensor(nbr[:, 1:])


def recon_loss_paper(out: dict, tg: dict, nbr, phase: int, rest_coarse=None) -> tuple:
    """FusionTouch's losses (S9, S13-S17), all L1: phase 1 = contact-region offset loss (S9, mean abs error per
    coordinate over contact points of the coarse template) + the contact BCE of the mask estimator; phase 2 adds
    L_contact + L_nc (S14-S15: per-coordinate L1 on contact / non-contact dense vertices), the Laplacian term
    (S16, L1; as the difference of predicted and GT uniform Laplacians - the Laplacian of a sphere is not zero,
    so the bare S16 term would pull the dome flat) and the edge-length term (S17, L1, edges of the dense kNN
    graph, lengths against the GT mesh). Weights: lambda_c = 1, lambda_n = 1, lambda_l = lambda_e = 1."""
    import torch
    import torch.nn.functional as F

    c = tg["contact"]
    bce = F.binary_cross_entropy_with_logits(out["contact_logit"], c, pos_weight=torch.tensor(4.0))

    def region_l1(pred, gt, mask):
        e = (pred - gt).abs().sum(-1) / 3.0
        con = (e * mask).sum() / mask.sum().clamp_min(1.0)
        non = (e * (1 - mask)).sum() / (1 - mask).sum().clamp_min(1.0)
        return con, non

    lc, lnc = region_l1(out["coarse"], tg["coarse"], c)
    # S9 supervises only the contact region; the non-contact coarse offsets get a weak L1 so the ungated
    # free-surface branch of our decoder (x = t + g d_c + (1 - g) d_f) is still trained
    loss = bce + lc + 0.25 * lnc
    parts = {"bce": bce.item(), "coarse": (lc + lnc).item()}
    if phase == 2:
        d, g = out["dense"], tg["dense"]
        dc, dnc = region_l1(d, g, tg["contact_dense"])
        lap = ((d - d[:, nbr].mean(2)) - (g - g[:, nbr].mean(2))).abs().sum(-1).mean() / 3.0
        el = ((d.unsqueeze(2) - d[:, nbr]).norm(dim=-1) - (g.unsqueeze(2) - g[:, nbr]).norm(dim=-1)).abs().mean()
        loss = loss + dc + dnc + lap + el
        parts.update(dense=(dc + dnc).item(), lap=lap.item(), edge=el.item())
    return loss, parts


def recon_loss(out: dict, tg: dict, nbr, phase: int, still_l1: float = 0.0, mode: str = "mix") -> tuple:
    """Reconstruction loss; ``mode="paper"`` -> :func:`recon_loss_paper`."""
    import torch
    import torch.nn.functional as F

    if mode == "paper":
        return recon_loss_paper(out, tg, nbr, phase)
    c = tg["contact"]
    bce = F.binary_cross_entropy_with_logits(out["contact_logit"], c, pos_weight=torch.tensor(4.0))

    def region_l2(pred, gt, mask):
        e = ((pred - gt) ** 2).sum(-1)
        con = (e * mask).sum() / mask.sum().clamp_min(1.0)
        non = (e * (1 - mask)).sum() / (1 - mask).sum().clamp_min(1.0)
        if still_l1 > 0:  # sqrt with a 1e-6 mm^2 floor: finite gradient at zero error
            non = non + still_l1 / 4.0 * ((e + 1e-6).sqrt() * (1 - mask)).sum() / (1 - mask).sum().clamp_min(1.0)
        return con, non

    lc, lnc = region_l2(out["coarse"], tg["coarse"], c)
    loss = bce + lc + 4.0 * lnc
    parts = {"bce": bce.item(), "coarse": (lc + lnc).item()}
    if phase == 2:
        d, g = out["dense"], tg["dense"]
        dc, dnc = region_l2(d, g, tg["contact_dense"])
        lap = ((d - d[:, nbr].mean(2)) - (g - g[:, nbr].mean(2))).pow(2).sum(-1).mean()
        el = ((d.unsqueeze(2) - d[:, nbr]).norm(dim=-1) - (g.unsqueeze(2) - g[:, nbr]).norm(dim=-1)).pow(2).mean()
        loss = loss + dc + 4.0 * dnc + 2.0 * lap + 2.0 * el
        parts.update(dense=(dc + dnc).item(), lap=lap.item(), edge=el.item())
    return loss, parts


def train_recon(kind: str, train: Batcher, tc: TrainConfig, log=print):
    """Two-phase training of a reconstruction net; returns the model (eval mode)."""
    import torch

    torch.manual_seed(tc.seed)
    model = build_model(kind, train.geo, tc.hidden, tc.gnn_k, tc.gnn_layers, tc.gnn_edge_strain)
    nbr = _dense_graph(train.geo)
    rng = np.random.default_rng(tc.seed)
    n = len(train)
    for phase, epochs in ((1, tc.epochs_coarse), (2, tc.epochs_fine)):
        if phase == 1:
            params = [p for nm, p in model.named_parameters() if not nm.startswith(("decoder.edge", "decoder.fine"))]
            opt = torch.optim.Adam(params, lr=tc.lr)
        else:
            fine = [p for nm, p in model.named_parameters() if nm.startswith(("decoder.edge", "decoder.fine"))]
            rest = [p for nm, p in model.named_parameters() if not nm.startswith(("decoder.edge", "decoder.fine"))]
            opt = torch.optim.Adam([{"params": fine, "lr": tc.lr}, {"params": rest, "lr": tc.lr * 0.1}])
        steps = max(1, epochs * (n // tc.batch))
        sched = torch.optim.lr_scheduler.OneCycleLR(
            opt, max_lr=[g["lr"] for g in opt.param_groups], total_steps=steps, pct_start=0.15
        )
        model.train()
        t0 = time.time()
        step = 0
        for ep in range(epochs):
            perm = rng.permutation(n)
            agg: dict[str, float] = {}
            for b in range(n // tc.batch):
                idx = perm[b * tc.batch : (b + 1) * tc.batch]
                out = model(train.inputs(idx), coarse_only=phase == 1)
                loss, parts = recon_loss(out, train.targets(idx), nbr, phase, tc.still_l1, tc.recon_loss)
                opt.zero_grad()
                loss.backward()
                torch.nn.utils.clip_grad_norm_(model.parameters(), 5.0)
                opt.step()
                if step < steps - 1:
                    sched.step()
                step += 1
                for k, v in parts.items():
                    agg[k] = agg.get(k, 0.0) + v / (n // tc.batch)
            log(
                f"[{kind}] phase {phase} epoch {ep + 1}/{epochs} "
                + " ".join(f"{k}={v:.4f}" for k, v in agg.items())
                + f" ({time.time() - t0:.0f}s)"
            )
    model.eval()
    return model


def force_features(model, train: Batcher) -> dict:
    """Frozen reconstruction-net outputs the force heads read, for the whole training set (computed once)."""
    import torch

    feats = []
    with torch.no_grad():
        for b in range(0, len(train), 128):
            idx = np.arange(b, min(len(train), b + 128))
            o = model(train.inputs(idx), coarse_only=True)
            feats.append({k: o[k] for k in ("hidden", "disp_coarse", "contact_logit", "glob")})
    return {k: torch.cat([f[k] for f in feats]) for k in feats[0]}


def train_force(
    model,
    train: Batcher,
    tc: TrainConfig,
    use_pressure: bool,
    log=print,
    init=None,
    epochs: int | None = None,
    feats: dict | None = None,
):
    """Train a force head on the frozen reconstruction net; ``init`` (a ForceHead) is the starting point."""
    import torch

    from vtrack.dome.nets import ForceHead

    torch.manual_seed(tc.seed + 1)
    head = ForceHead(train.geo, tc.hidden, 2 * tc.hidden, use_pressure=use_pressure)
    if init is not None:
        head.load_state_dict(init.state_dict())
    epochs = tc.epochs_force if epochs is None else epochs
    n = len(train)
    cat = feats if feats is not None else force_features(model, train)
    opt = torch.optim.Adam(head.parameters(), lr=tc.lr)
    steps = max(1, epochs * (n // tc.batch))
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=tc.lr, total_steps=steps, pct_start=0.15)
    rng = np.random.default_rng(tc.seed + 2)
    rest = model.decoder.coarse_rest
    step = 0
    head.train()
    for ep in range(epochs):
        perm = rng.permutation(n)
        tot = 0.0
        for b in range(n // tc.batch):
            idx = torch.as_tensor(perm[b * tc.batch : (b + 1) * tc.batch])
            pred = head({k: v[idx] for k, v in cat.items()}, train.pressure[idx], rest)
            loss = torch.nn.functional.smooth_l1_loss(pred, train.force[idx], beta=0.1)
            opt.zero_grad()
            loss.backward()
            opt.step()
            if step < steps - 1:
                sched.step()
            step += 1
            tot += loss.item() / (n // tc.batch)
        if ep == epochs - 1 or ep % 5 == 0:
            log(f"[force p={use_pressure}] epoch {ep + 1}/{epochs} loss={tot:.4f}")
    head.eval()
    return head


def train_force_heads(model, train: Batcher, tc: TrainConfig, log=print, feats: dict | None = None) -> dict:
    """The two force heads, "p" (pressure FiLM) and "nop" (P = 0), with the same budget from one shared start.

    A head is trained without pressure for ``epochs_force // 2`` epochs; it is then continued for the
    remaining epochs twice, once without P and once with P fed to the FiLM (same weights, same batches;
    the only difference is the pressure path). Why: heads trained separately from
    scratch ended up to 10 % apart in training loss from optimisation noise alone (measured: a CNN head with P
    at 0.433 vs 0.396 without), which swamps the effect of P that the with/without comparison measures.
    """
    feats = feats if feats is not None else force_features(model, train)
    first = max(1, tc.epochs_force // 2)
    rest = max(1, tc.epochs_force - first)
    base = train_force(model, train, tc, False, log, epochs=first, feats=feats)
    return {
        "p": train_force(model, train, tc, True, log, init=base, epochs=rest, feats=feats),
        "nop": train_force(model, train, tc, False, log, init=base, epochs=rest, feats=feats),
    }


def fit_contact_calibration(model, train: Batcher, feats: dict | None = None) -> tuple[float, float]:
    """Platt scaling of the contact logit on the training set: (a, b) minimising the mean squared error of
    ``sigmoid(a * logit + b)`` against the GT mask (the Brier score, i.e. what ``contact_l2`` measures).
    ``feats`` are the net's :func:`force_features` on ``train`` when already computed.

    Why: the contact BCE weights contact points 4x (recall matters for the contact gate), which shifts the
    raw probabilities of the ~98 % non-contact points upwards; the reported probability should be calibrated.
    """
    logits = (feats if feats is not None else force_features(model, train))["contact_logit"]
    return platt_fit(logits.flatten(), train.contact.flatten())


def platt_fit(z, y) -> tuple[float, float]:
    """(a, b) minimising ``mean((sigmoid(a z + b) - y)^2)`` for logits ``z`` and 0/1 labels ``y`` (torch, 1-D);
    (1, 0) when there is nothing to fit or the fit degenerates (non-finite or a <= 0)."""
    import torch

    z, y = torch.as_tensor(z, dtype=torch.float32).flatten(), torch.as_tensor(y, dtype=torch.float32).flatten()
    if z.numel() == 0 or not bool(torch.isfinite(z).all()):
        return 1.0, 0.0
    ab = torch.tensor([1.0, 0.0], requires_grad=True)
    opt = torch.optim.LBFGS([ab], lr=0.5, max_iter=100, line_search_fn="strong_wolfe")

    def closure():
        opt.zero_grad()
        loss = (torch.sigmoid(ab[0] * z + ab[1]) - y).pow(2).mean()
        loss.backward()
        return loss

    opt.step(closure)
    a, b = (float(v) for v in ab.detach())
    if not (np.isfinite(a) and np.isfinite(b)) or a <= 0:  # degenerate fit: keep the raw probabilities
        return 1.0, 0.0
    return a, b


def calibrate_bundle(path: Path, tc: TrainConfig | None = None) -> tuple[float, float]:
    """Fit the contact calibration of a saved bundle on its training set and store it in the bundle."""
    import torch

    b = read_bundle(path)
    tc = tc or bundle_train_config(b)
    torch.set_num_threads(tc.threads)
    model, _, cfg, _ = load_bundle(path, with_heads=False)
    tr, _ = load_sets(tc, cfg)
    btr = Batcher(b["kind"], tr, DomeGeometry(cfg), f"{tc.n_train}-{tc.seed}-{cfg.to_dict()}")
    b["contact_calib"] = list(fit_contact_calibration(model, btr))
    torch.save(b, path)
    return tuple(b["contact_calib"])


def retrain_force(path: Path, tc: TrainConfig | None = None, log=print) -> dict:
    """Retrain only the two force heads of a saved bundle (same budget for every method); re-save it."""
    import torch

    b = read_bundle(path)
    tc = tc or bundle_train_config(b)
    torch.set_num_threads(tc.threads)
    model, _, cfg, info = load_bundle(path, with_heads=False)
    geo = DomeGeometry(cfg)
    tr, _ = load_sets(tc, cfg)
    btr = Batcher(b["kind"], tr, geo, f"{tc.n_train}-{tc.seed}-{cfg.to_dict()}")
    heads = train_force_heads(model, btr, tc, log)
    save_bundle(path, b["kind"], model, heads, cfg, tc, info)  # keeps the calibration (load_bundle set it)
    return info


def train_spec_force(
    model,
    kind: str,
    train: Batcher,
    tc: TrainConfig,
    log=print,
    feats: dict | None = None,
    keys: tuple[str, ...] = ("legacy", "p", "nop", "plain_p", "plain_nop"),
    gnn_arch: str = "patch_graph",
) -> dict:
    """Force nets as FusionTouch specifies them (S18-S23, :mod:`vtrack.dome.force`), with and without pressure,
    on the frozen reconstruction net: ``patch_graph`` for the GNN, ``cnn_film`` for the CNN; plus today's
    decoder-feature heads (:func:`train_force_heads`) as ``legacy_p`` / ``legacy_nop`` and, for the GNN, the net
    exactly as S18-S20 (``patch_graph_plain``) as ``plain_p`` / ``plain_nop``. ``keys`` picks which (so they can
    be trained in parallel processes); ``gnn_arch``: the main GNN net's architecture."""
    import torch

    from vtrack.dome.force import build_force, indentation_sums, train_force_net

    heads = {}
    if "legacy" in keys:
        heads.update({f"legacy_{k}": h for k, h in train_force_heads(model, train, tc, log, feats).items()})
    if not any(k in keys for k in ("p", "nop", "plain_p", "plain_nop")):
        return heads
    arch = gnn_arch if kind == "gnn" else "cnn_film"

    def frozen(key: str):
        with torch.no_grad():
            outs = [
                model(train.inputs(np.arange(b, min(len(train), b + 128))), coarse_only=True)
                for b in range(0, len(train), 128)
            ]
            return torch.cat([indentation_sums(o) if key == "indent" else o[key] for o in outs])

    if arch == "cnn_film":
        fmap = frozen("fmap")

        def batch_fn(idx):
            i = torch.as_tensor(np.asarray(idx))
            return fmap[i], train.pressure[i], train.force[i]
    else:
        train.patches()
        node_h = frozen("node_h")  # per-marker encoder features of the reconstruction GNN, all nodes
        indent = frozen("indent")  # (n, 2) indentation-volume proxies of the reconstructed surfaces
        off = train.graphs["node_off"]

        def batch_fn(idx):
            i = np.asarray(idx)
            inp = train.inputs(i, patches=True)
            inp["node_h"] = torch.cat([node_h[off[j] : off[j + 1]] for j in i])
            inp["indent"] = indent[torch.as_tensor(i)]
            return inp, train.pressure[i], train.force[i]

    todo = [(k, arch, k == "p") for k in ("p", "nop") if k in keys]
    if kind == "gnn" and arch == "patch_graph":  # the net exactly as S18-S20, ablation rows
        todo += [(k, "patch_graph_plain", k == "plain_p") for k in ("plain_p", "plain_nop") if k in keys]
    for key, arch_k, use_p in todo:
        net = build_force(arch_k, train.geo.cfg.pressure_max_kpa, use_p, tc.hidden)
        heads[key], info = train_force_net(
            net,
            batch_fn,
            len(train),
            epochs=tc.epochs_force_net,
            batch=tc.batch,
            lr=tc.lr,
            seed=tc.seed,
            log=log,
            name=f"{arch_k} p={use_p}",
        )
        log(f"[{arch_k} p={use_p}] best validation loss {info['best_val_loss']:.4f} at epoch {info['best_epoch']}")
    return heads


def retrain_spec_force(path: Path, tc: TrainConfig | None = None, log=print) -> dict:
    """Retrain all force nets of a saved bundle (:func:`train_spec_force`) and re-save it (format version 3)."""
    import torch

    b = read_bundle(path)
    tc = tc or bundle_train_config(b)
    torch.set_num_threads(tc.threads)
    model, _, cfg, info = load_bundle(path, with_heads=False)
    tr, _ = load_sets(tc, cfg)
    btr = Batcher(b["kind"], tr, DomeGeometry(cfg), f"{tc.n_train}-{tc.seed}-{cfg.to_dict()}")
    heads = train_spec_force(model, b["kind"], btr, tc, log)
    save_bundle(path, b["kind"], model, heads, cfg, tc, info)
    return heads


def predict(model, heads: dict, batcher: Batcher, batch: int = 128) -> dict[str, np.ndarray]:
    """Run a model (and force heads) over a whole dataset."""
    import torch

    names = {k: {"p": "force", "nop": "force_nop"}.get(k, f"force_{k}") for k in heads}
    patches = any(getattr(h, "needs_patches", False) for h in heads.values())
    outs: dict[str, list] = {}
    with torch.no_grad():
        for b in range(0, len(batcher), batch):
            idx = np.arange(b, min(len(batcher), b + batch))
            inp = batcher.inputs(idx, patches=patches)
            o = model(inp)
            outs.setdefault("coarse", []).append(o["coarse"].numpy())
            outs.setdefault("dense", []).append(o["dense"].numpy())
            outs.setdefault("contact", []).append(model.decoder.contact_prob(o["contact_logit"]).numpy())
            for key, h in heads.items():
                outs.setdefault(names[key], []).append(h.run(o, inp, batcher.pressure[idx]).numpy())
    return {k: np.concatenate(v) for k, v in outs.items()}


def train_all(
    tc: TrainConfig | None = None,
    cfg: DomeConfig | None = None,
    out_dir: Path | None = None,
    kinds: tuple[str, ...] = ("gnn", "cnn"),
    log=print,
) -> dict[str, dict]:
    """The full reproducible training: simulate (cached), train GNN and CNN with the same budget, save, eval."""
    import torch

    from vtrack.dome.metrics import evaluate_predictions, set_ground_truth

    tc = tc or TrainConfig()
    cfg = cfg or DomeConfig()
    torch.set_num_threads(tc.threads)
    out_dir = out_dir or weights_dir()
    geo = DomeGeometry(cfg)
    tr, te = load_sets(tc, cfg, progress=True)
    results = {}
    for kind in kinds:
        t0 = time.time()
        btr = Batcher(kind, tr, geo, f"{tc.n_train}-{tc.seed}-{cfg.to_dict()}")
        bte = Batcher(kind, te, geo, f"{tc.n_test}-{tc.test_seed}-{cfg.to_dict()}")
        model = train_recon(kind, btr, tc, log)
        feats = force_features(model, btr)  # frozen net outputs, shared by the force heads and the calibration
        heads = train_spec_force(model, kind, btr, tc, log, feats)
        model.decoder.contact_calib = fit_contact_calibration(model, btr, feats)
        secs = time.time() - t0
        pred = predict(model, heads, bte)
        gt = set_ground_truth(te, geo.dense_rest)
        m = evaluate_predictions(pred, gt)
        m["train_seconds"] = secs
        log(f"[{kind}] test: " + " ".join(f"{k}={v:.4f}" for k, v in m.items()))
        save_bundle(out_dir / f"{kind}.pt", kind, model, heads, cfg, tc, {"test": m})
        results[kind] = m
    return results


#: DomeConfig fields a bundle's reconstruction weights do not depend on once the reference frame is captured at
#: the operating pressure: the inflation is then common to the frame and its reference, and the nets predict the
#: displacement from that inflated no-contact state (the decoder adds the calibrated inflation itself)
RETARGETABLE_FIELDS = ("inflation_mm_per_kpa",)


def retarget_bundle(
    src: Path,
    out: Path,
    cfg: DomeConfig | None = None,
    tc: TrainConfig | None = None,
    keys: tuple[str, ...] = ("legacy", "p", "nop", "plain_p", "plain_nop"),
    log=print,
) -> dict:
    """Keep the reconstruction weights of bundle ``src``, move it to the sensor config ``cfg`` (default: today's
    ``DomeConfig()``) and train the force nets ``keys`` (:func:`train_spec_force`) on that config's simulated
    presses; refit the contact calibration on them; write ``out`` (only the heads trained here).

    Only :data:`RETARGETABLE_FIELDS` may differ between the two configs (anything else changes what the
    reconstruction net sees): InputError otherwise. Several calls with disjoint ``keys`` (parallel processes)
    are combined by :func:`merge_bundles`."""
    import torch

    from vtrack.errors import InputError

    b = read_bundle(src)
    tc = tc or bundle_train_config(b)
    torch.set_num_threads(tc.threads)
    model, _, cfg0, _ = load_bundle(src, with_heads=False)
    cfg = cfg or DomeConfig()
    d0, d1 = cfg0.to_dict(), cfg.to_dict()
    bad = [k for k in d1 if k not in RETARGETABLE_FIELDS and d0.get(k) != d1[k]]
    if bad:
        raise InputError("reconstruction weights do not transfer to this sensor config", path=src, field=",".join(bad))
    model = build_model(b["kind"], DomeGeometry(cfg), tc.hidden, tc.gnn_k, tc.gnn_layers, tc.gnn_edge_strain)
    model.load_state_dict(load_bundle(src, with_heads=False)[0].state_dict())
    model.eval()
    geo = DomeGeometry(cfg)
    tr, _ = load_sets(tc, cfg, progress=True)
    btr = Batcher(b["kind"], tr, geo, f"{tc.n_train}-{tc.seed}-{cfg.to_dict()}")
    feats = force_features(model, btr)
    model.decoder.contact_calib = fit_contact_calibration(model, btr, feats)
    heads = train_spec_force(model, b["kind"], btr, tc, log, feats, keys=keys)
    info = {"retargeted_from": {"cfg": d0, "changed": {k: (d0.get(k), d1[k]) for k in RETARGETABLE_FIELDS}}}
    save_bundle(Path(out), b["kind"], model, heads, cfg, tc, info)
    return info


def merge_bundles(parts: list[Path], out: Path, evaluate_test: bool = True) -> dict:
    """One bundle from bundles that share the reconstruction net and config but hold different force heads
    (e.g. :func:`retarget_bundle` run in parallel processes with disjoint keys); with ``evaluate_test`` the
    held-out metrics go to ``info["test"]``."""
    import torch

    from vtrack.errors import InputError

    blobs = [read_bundle(p) for p in parts]
    base = dict(blobs[0])
    base["force_archs"] = dict(base.get("force_archs", {}))
    for p, bl in zip(parts[1:], blobs[1:], strict=True):
        if bl["cfg"] != base["cfg"] or bl["kind"] != base["kind"]:
            raise InputError("bundles to merge differ in sensor config or kind", path=p, field="cfg")
        same = all(torch.equal(bl["recon"][k], v) for k, v in base["recon"].items())
        if not same:
            raise InputError("bundles to merge have different reconstruction weights", path=p, field="recon")
        for k, arch in bl.get("force_archs", {}).items():
            base[f"force_{k}"] = bl[f"force_{k}"]
            base["force_archs"][k] = arch
    base["force_arch"] = base["force_archs"].get("p", base.get("force_arch", "decoder_film"))
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    torch.save(base, out)
    if evaluate_test:
        from vtrack.dome.metrics import evaluate_predictions, set_ground_truth

        model, heads, cfg, _ = load_bundle(Path(out))
        tc = bundle_train_config(base)
        _, te = load_sets(tc, cfg)
        geo = DomeGeometry(cfg)
        bte = Batcher(base["kind"], te, geo, f"{tc.n_test}-{tc.test_seed}-{cfg.to_dict()}")
        base["info"] = {
            **base.get("info", {}),
            "test": evaluate_predictions(predict(model, heads, bte), set_ground_truth(te, geo.dense_rest)),
        }
        torch.save(base, out)
    return base.get("info", {})
