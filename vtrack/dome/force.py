"""Pressure-conditioned force networks as FusionTouch specifies them (supplementary S18-S23).

- :class:`PatchGraphForce` ("GNN + patch encoder"): for every detected marker a 2-channel patch
  (current frame, reference frame; ``PATCH`` x ``PATCH`` px around the marker centre) goes through a small
  conv patch encoder; the patch feature is modulated by the internal pressure with FiLM,
  ``gamma(p) * BN(h) + beta(p)`` (S19); the node input is ``[FiLM(patch), node descriptor, phi_i]`` with the
  pressure-aware scalar ``phi_i = (p / p_max) * a~_i`` (S20, ``a~_i`` = normalised marker area, column 2 of the
  S5 descriptor); GINE message passing over the Delaunay marker graph (edge attributes incl. strain),
  mean + max pooling, MLP -> F (N, dome frame) (S18).
  The node descriptor is our 13-D GNN node input (S5 + reference-relative displacement/size change), the same
  the reconstruction GNN reads.
- :class:`CNNMapForce` ("CNN encoder"): the stride-16 feature map of the (frozen) reconstruction CNN,
  ``gamma(p) * BN(f) + beta(p)`` per channel, a conv layer, mean + max pooling, MLP -> F.
- Loss (S21-S23): ``lambda_mae * MAE + lambda_rmse * (RMSE + eps)`` over the three axes; the checkpoint with
  the lowest validation loss (10 % of the training set held out) is kept.

``use_pressure=False`` is the ablation: the nets get p = 0 (FiLM then reduces to a fixed BN affine and
``phi_i = 0``). Forces in N, pressure in kPa.
"""

from __future__ import annotations

import copy
import time

import numpy as np
import torch
from torch import nn

from vtrack.dome.markers import EDGE_DIM
from vtrack.dome.nets import NODE_IN, GraphEncoder, mlp

#: patch side (px) around each marker centre; ~1.1 rest-marker spacings at 160 px
PATCH = 9
#: force-net architectures stored in a bundle's ``force_arch``
ARCHS = ("decoder_film", "patch_graph", "patch_graph_plain", "cnn_film")


def centers_from_x(x: np.ndarray, image_size: int) -> np.ndarray:
    """Marker centres (n, 2) px back from the S5 descriptor columns ``x_rel, y_rel`` (square image)."""
    half = image_size / 2.0
    return np.asarray(x[:, :2], np.float64) * half + (image_size - 1) / 2.0


def marker_patches(image: np.ndarray, ref_image: np.ndarray, centers: np.ndarray, size: int = PATCH) -> np.ndarray:
    """(n, 2, size, size) uint8 patches of [image, reference] centred on the rounded marker centres (px);
    pixels beyond the border are 0."""
    r = size // 2
    stack = np.stack([np.asarray(image, np.uint8), np.asarray(ref_image, np.uint8)])
    pad = np.pad(stack, ((0, 0), (r, r), (r, r)))
    c = np.rint(np.nan_to_num(np.asarray(centers, np.float64).reshape(-1, 2))).astype(np.int64)
    H, W = stack.shape[1:]
    cx, cy = np.clip(c[:, 0], 0, W - 1) + r, np.clip(c[:, 1], 0, H - 1) + r
    off = np.arange(-r, size - r)
    yy = cy[:, None, None] + off[None, :, None]
    xx = cx[:, None, None] + off[None, None, :]
    return np.ascontiguousarray(pad[:, yy, xx].transpose(1, 0, 2, 3))


class FiLM(nn.Module):
    """``gamma(p) * BN(x) + beta(p)`` (S19); x is (N, C) or (N, C, H, W), p is (N, 1) in [0, 1].

    The generator's last layer starts at zero with gamma = 1 + output, so the modulation starts as plain
    batch normalisation and the pressure path is learned from a neutral start."""

    def __init__(self, channels: int, maps: bool = False) -> None:
        super().__init__()
        self.bn = nn.BatchNorm2d(channels, affine=False) if maps else nn.BatchNorm1d(channels, affine=False)
        self.gen = mlp(1, 32, 2 * channels)
        self.gamma0 = nn.Parameter(torch.ones(channels))
        self.beta0 = nn.Parameter(torch.zeros(channels))
        nn.init.zeros_(self.gen[-1].weight)
        nn.init.zeros_(self.gen[-1].bias)
        self.maps = maps

    def forward(self, x: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
        gb = self.gen(p)
        C = x.shape[1]
        g, b = self.gamma0 + gb[:, :C], self.beta0 + gb[:, C:]
        if self.maps:
            g, b = g[:, :, None, None], b[:, :, None, None]
        return g * self.bn(x) + b


class PatchGraphForce(nn.Module):
    """GNN + patch encoder force net (S18-S20); see the module docstring.

    ``plain=True`` is the net exactly as S18-S20 describe it (node input = FiLM(patch), descriptor, phi_i).
    ``plain=False`` (arch ``patch_graph``, shipped) adds two things: the frozen reconstruction GNN's per-marker
    encoder features in the node input (``node_h``), and a second FiLM by the pressure on the pooled graph
    feature concatenated with two indentation-volume proxies of the reconstructed surface
    (:func:`indentation_sums`) - the simulator's force is ``k_n(P)`` x indentation volume, a product the
    per-node FiLM alone had to learn through message passing and pooling."""

    needs_patches = True

    def __init__(
        self,
        p_max_kpa: float,
        use_pressure: bool = True,
        hidden: int = 48,
        layers: int = 3,
        node_in: int = NODE_IN,
        edge_dim: int = EDGE_DIM + 3,
        plain: bool = False,
        enc_dim: int = 64,
    ) -> None:
        super().__init__()
        self.p_max = float(p_max_kpa)
        self.use_pressure = use_pressure
        self.plain = plain
        self.arch = "patch_graph_plain" if plain else "patch_graph"
        self.enc_dim = 0 if plain else enc_dim
        self.patch = nn.Sequential(
            nn.Conv2d(2, 16, 3, 2, 1),
            nn.ReLU(),
            nn.Conv2d(16, 32, 3, 2, 1),
            nn.ReLU(),
            nn.Flatten(),
            nn.Linear(32 * ((PATCH + 3) // 4) ** 2, hidden),
        )
        self.film = FiLM(hidden)
        self.graph = GraphEncoder(hidden, layers, edge_dim, node_in=hidden + node_in + 1 + self.enc_dim)
        g_dim = 2 * hidden + (0 if plain else 2)
        if not plain:
            self.gfilm = FiLM(g_dim)
        self.head = mlp(g_dim, hidden, 3)

    def pressure_input(self, pressure_kpa: torch.Tensor) -> torch.Tensor:
        p = torch.as_tensor(pressure_kpa, dtype=torch.float32).reshape(-1, 1) / self.p_max
        return p if self.use_pressure else torch.zeros_like(p)

    def forward(
        self,
        batch: dict,
        pressure_kpa: torch.Tensor,
        node_h: torch.Tensor | None = None,
        indent: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """batch: collated marker graphs (``features.collate_graphs``) + ``patches`` (N, 2, P, P) in [0, 1];
        ``node_h`` (N, enc_dim): the reconstruction GNN's per-marker encoder features; ``indent`` (B, 2): the
        indentation-volume proxies (:func:`indentation_sums`); both zeros when None, unused when ``plain``."""
        p = self.pressure_input(pressure_kpa)
        B = int(batch["n_graphs"])
        pn = p[batch["batch"]]  # per node
        h = self.film(self.patch(batch["patches"]), pn)  # S19
        phi = pn * batch["x"][:, 2:3]  # S20: (p / p_max) * normalised marker area
        parts = [h, batch["x"], phi]
        if not self.plain:
            parts.append(node_h if node_h is not None else h.new_zeros(len(h), self.enc_dim))
        _, g = self.graph(torch.cat(parts, 1), batch["edge_index"], batch["edge_attr"], batch["batch"], B)
        if not self.plain:
            g = self.gfilm(torch.cat([g, indent if indent is not None else g.new_zeros(B, 2)], 1), p)
        return self.head(g)

    def run(self, out: dict, batch: dict, pressure_kpa: torch.Tensor) -> torch.Tensor:
        ind = indentation_sums(out) if not self.plain else None
        return self(batch, pressure_kpa, out.get("node_h"), ind)


def indentation_sums(out: dict) -> torch.Tensor:
    """(B, 2) indentation-volume proxies from the reconstruction net's coarse stage: the sums over the coarse
    template of the inward displacement (mm) from the reference state, contact-probability weighted and plain,
    / 10 (the same two sums the decoder-feature head ``nets.ForceHead`` reads)."""
    d = out["disp_coarse"]
    rest = out["coarse"] - d  # reference-state positions of the coarse template
    nrm = rest / rest.norm(dim=-1, keepdim=True).clamp_min(1e-9)
    ind = torch.relu(-(d * nrm).sum(-1))
    prob = torch.sigmoid(out["contact_logit"])
    return torch.stack([(ind * prob).sum(1), ind.sum(1)], 1) / 10.0


class CNNMapForce(nn.Module):
    """CNN-encoder force net: FiLM on the reconstruction CNN's stride-16 feature map (``out["fmap"]``)."""

    arch = "cnn_film"
    needs_patches = False

    def __init__(self, p_max_kpa: float, use_pressure: bool = True, in_ch: int = 64, hidden: int = 64) -> None:
        super().__init__()
        self.p_max = float(p_max_kpa)
        self.use_pressure = use_pressure
        self.film = FiLM(in_ch, maps=True)
        self.conv = nn.Sequential(nn.Conv2d(in_ch, hidden, 3, 1, 1), nn.ReLU())
        self.head = mlp(2 * hidden, hidden, 3)

    pressure_input = PatchGraphForce.pressure_input

    def forward(self, fmap: torch.Tensor, pressure_kpa: torch.Tensor) -> torch.Tensor:
        f = self.conv(self.film(fmap, self.pressure_input(pressure_kpa)))
        return self.head(torch.cat([f.mean((2, 3)), f.amax((2, 3))], 1))

    def run(self, out: dict, batch: dict, pressure_kpa: torch.Tensor) -> torch.Tensor:
        return self(out["fmap"], pressure_kpa)


def build_force(arch: str, p_max_kpa: float, use_pressure: bool, hidden: int = 64) -> nn.Module:
    """A fresh force net of ``arch`` (``patch_graph`` | ``cnn_film``; ``decoder_film`` = nets.ForceHead)."""
    if arch in ("patch_graph", "patch_graph_plain"):
        return PatchGraphForce(p_max_kpa, use_pressure, plain=arch == "patch_graph_plain")
    if arch == "cnn_film":
        return CNNMapForce(p_max_kpa, use_pressure, in_ch=hidden)
    raise ValueError(f"unknown force architecture {arch!r} ({' | '.join(ARCHS)})")


def force_loss(pred: torch.Tensor, target: torch.Tensor, w_mae: float = 1.0, w_rmse: float = 1.0, eps: float = 1e-6):
    """S21-S23: ``w_mae * mean|e| + w_rmse * (sqrt(mean e^2) + eps)`` over the batch and the three axes (N)."""
    e = pred - target
    return w_mae * e.abs().mean() + w_rmse * (torch.sqrt((e**2).mean() + 1e-12) + eps)


def train_force_net(
    head: nn.Module,
    batch_fn,
    n: int,
    *,
    epochs: int = 30,
    batch: int = 32,
    lr: float = 2e-3,
    seed: int = 0,
    val_frac: float = 0.1,
    log=print,
    name: str = "force",
) -> tuple[nn.Module, dict]:
    """Train ``head`` with the S21 loss. ``batch_fn(idx) -> (inputs, pressure (B,), force (B, 3))`` prepares a
    batch (:func:`head_call` feeds it to the net). Keeps the state with the lowest validation loss (``val_frac``
    of the ``n`` training samples, fixed by ``seed``). Returns (head in eval mode, {best_val_loss, best_epoch,
    epochs})."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    perm0 = rng.permutation(n)
    n_val = max(1, int(round(val_frac * n)))
    val, tr = perm0[:n_val], perm0[n_val:]
    opt = torch.optim.Adam(head.parameters(), lr=lr, weight_decay=1e-5)
    steps = max(1, epochs * max(1, len(tr) // batch))
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lr, total_steps=steps, pct_start=0.15)
    best, best_state, best_ep = np.inf, None, -1
    t0 = time.time()
    step = 0
    for ep in range(epochs):
        head.train()
        perm = rng.permutation(tr)
        tot = 0.0
        nb = max(1, len(tr) // batch)
        for b in range(nb):
            idx = perm[b * batch : (b + 1) * batch]
            inputs, p, f = batch_fn(idx)
            loss = force_loss(head_call(head, inputs, p), f)
            opt.zero_grad()
            loss.backward()
            nn.utils.clip_grad_norm_(head.parameters(), 5.0)
            opt.step()
            if step < steps - 1:
                sched.step()
            step += 1
            tot += loss.item() / nb
        head.eval()
        with torch.no_grad():
            vl = 0.0
            for b in range(0, len(val), 128):
                inputs, p, f = batch_fn(val[b : b + 128])
                vl += force_loss(head_call(head, inputs, p), f).item() * len(val[b : b + 128])
            vl /= len(val)
        if vl < best:
            best, best_state, best_ep = vl, copy.deepcopy(head.state_dict()), ep
        log(f"[{name}] epoch {ep + 1}/{epochs} train {tot:.4f} val {vl:.4f} ({time.time() - t0:.0f}s)")
    head.load_state_dict(best_state)
    head.eval()
    return head, {"best_val_loss": float(best), "best_epoch": int(best_ep + 1), "epochs": epochs}


def head_call(head: nn.Module, inputs, pressure: torch.Tensor) -> torch.Tensor:
    """Call a force net on the inputs its ``batch_fn`` prepared (graph batch dict, or a feature map)."""
    if isinstance(head, PatchGraphForce):
        return head(inputs, pressure, inputs.get("node_h"), inputs.get("indent"))
    if isinstance(head, CNNMapForce):
        return head(inputs, pressure)
    out, rest = inputs  # legacy decoder-feature head
    return head(out, pressure, rest)
