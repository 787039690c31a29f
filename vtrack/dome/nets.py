"""Networks (torch): marker-graph GNN and CNN encoders, shared coarse-to-fine decoder, force head.

Our reading of FusionTouch (supplementary eqs. S5-S23 are not available to us; see docs/dome.md):
- S6-S7 contact-mask estimator: encoder features are carried to each point of a 256-point coarse template
  (GNN: inverse-distance interpolation from the k nearest markers, back-projected onto the rest dome;
  CNN: bilinear sampling of the feature maps at the template point's pixel) and an MLP on
  ``[point feature, global feature, template position]`` gives a contact logit ``c_j``.
- S8-S9 coarse deformation with contact gate: two displacement heads, ``x_j = t_j + g_j d^c_j + (1 - g_j) d^f_j``
  with ``g_j = sigmoid(c_j)`` (contact and free-surface regimes deform differently).
- S10-S12 fine stage: EdgeConv over the fixed kNN graph of the coarse template (k = 8, kNN with
  ``torch.cdist`` + ``topk``), inverse-distance interpolation (k = 3) of features and coarse displacement to
  the dense template, and a bounded residual ``s * tanh(MLP)`` (s = 1 mm).
- S19-S20 force: patch encoder (16 fixed patches of the coarse template) with pressure FiLM
  ``h <- h (1 + gamma(P)) + beta(P)``, plus the graph encoder's global feature, regression head -> F (N).
All lengths inside the nets are mm; displacement outputs are scaled by ``DISP_SCALE_MM``.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from vtrack.dome.markers import EDGE_DIM, NODE_DIM
from vtrack.dome.model import DomeGeometry

DISP_SCALE_MM = 2.0
NODE_IN = NODE_DIM + 5  # S5 descriptor + [dx, dy, d_area, d_r, matched] vs the reference marker


def mlp(*dims: int, last_act: bool = False) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i in range(len(dims) - 1):
        layers.append(nn.Linear(dims[i], dims[i + 1]))
        if i < len(dims) - 2 or last_act:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


def knn_torch(a: torch.Tensor, b: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
    """k nearest rows of ``b`` (..., m, d) for each row of ``a`` (..., n, d): (idx, dist), plain torch."""
    d = torch.cdist(a, b)
    k = min(k, b.shape[-2])
    dist, idx = torch.topk(d, k, dim=-1, largest=False)
    return idx, dist


def idw_weights(dist: torch.Tensor, power: float = 2.0, eps: float = 1e-3) -> torch.Tensor:
    w = 1.0 / (dist + eps) ** power
    return w / w.sum(-1, keepdim=True).clamp_min(1e-12)


class DenseEdgeConv(nn.Module):
    """EdgeConv (Wang et al.) on a fixed graph given as neighbour indices (n, k), batched as (B, n, F).

    Message ``max_j ReLU(W1 x_i + W2 (x_j - x_i))`` followed by a linear layer + ReLU. The first layer is
    linear in ``[x_i, x_j - x_i]``, so it is applied per node before gathering neighbours (k times fewer
    matrix products than the textbook form; same function class as ``torch_geometric.nn.EdgeConv`` with a
    one-hidden-layer ``h_theta`` whose last layer is applied after the max).
    """

    def __init__(self, in_dim: int, out_dim: int) -> None:
        super().__init__()
        self.self_lin = nn.Linear(in_dim, out_dim)
        self.nbr_lin = nn.Linear(in_dim, out_dim, bias=False)
        self.out = nn.Linear(out_dim, out_dim)

    def forward(self, x: torch.Tensor, nbr: torch.Tensor) -> torch.Tensor:
        bj = self.nbr_lin(x)
        ai = self.self_lin(x) - bj  # W1 x_i - W2 x_i
        m = torch.relu(ai.unsqueeze(2) + bj[:, nbr]).amax(2)
        return torch.relu(self.out(m))


class CoarseToFineDecoder(nn.Module):
    """Contact mask + gated coarse deformation + EdgeConv fine stage (shared by GNN and CNN).

    Linear layers whose inputs are constant per sample (global feature) or per template point (rest
    position), or that are followed by a linear interpolation, are split so they are evaluated once
    (same function, much less CPU).
    """

    def __init__(
        self,
        geo: DomeGeometry,
        feat_dim: int = 64,
        glob_dim: int = 128,
        hidden: int = 48,
        s_mm: float = 1.0,
        k_graph: int = 8,
        k_interp: int = 3,
    ) -> None:
        super().__init__()
        self.R = geo.cfg.radius_mm
        self.s_mm = s_mm
        self.k_interp = k_interp
        self.hidden = hidden
        coarse = torch.tensor(geo.coarse_rest, dtype=torch.float32)
        self.register_buffer("coarse_rest", coarse)
        nbr, _ = knn_torch(coarse, coarse, k_graph + 1)
        self.register_buffer("coarse_nbr", nbr[:, 1:].contiguous())
        self.set_dense(geo.dense_rest)
        self.in_feat = nn.Linear(feat_dim, 2 * hidden)
        self.in_glob = nn.Linear(glob_dim, 2 * hidden, bias=False)
        self.in_pos = nn.Linear(3, 2 * hidden, bias=False)
        self.contact = mlp(hidden, hidden, 1)
        self.coarse_body = mlp(hidden, hidden, last_act=True)
        self.coarse_head = nn.Linear(hidden + 1, 6)
        self.edge1 = DenseEdgeConv(hidden + 3 + 1, hidden)
        self.edge2 = DenseEdgeConv(hidden, hidden)
        self.fine_in = nn.Linear(2 * hidden + 3, hidden)
        self.fine_pos = nn.Linear(3, hidden, bias=False)
        self.fine_out = mlp(hidden, hidden, 3)
        #: Platt scaling (a, b) of the contact logit for the reported probability, fitted on the training set
        #: after training (``train.fit_contact_calibration``); the gate of the coarse stage uses the raw logit
        self.contact_calib = (1.0, 0.0)

    def contact_prob(self, logit: torch.Tensor) -> torch.Tensor:
        """Calibrated contact probability of each coarse point from the contact logit."""
        a, b = self.contact_calib
        return torch.sigmoid(a * logit + b)

    def set_dense(self, dense_rest_mm: np.ndarray) -> None:
        """Use another dense template (rest positions, mm): recomputes the interpolation weights."""
        dense = torch.as_tensor(np.asarray(dense_rest_mm), dtype=torch.float32)
        idx, dist = knn_torch(dense, self.coarse_rest, self.k_interp)
        self.dense_rest = dense
        self.interp_idx = idx
        self.interp_w = idw_weights(dist / self.R)

    def forward(
        self,
        feat: torch.Tensor,
        glob: torch.Tensor,
        coarse_only: bool = False,
        ref_inflation_mm: torch.Tensor | None = None,
    ) -> dict[str, torch.Tensor]:
        """feat (B, 256, F) per coarse point, glob (B, G) -> contact logits, coarse and dense positions (mm).

        The nets predict displacements from the reference (no-contact) state; ``ref_inflation_mm`` (B,) is
        that state's radial inflation from the rest template (sensor calibration, ``DomeGeometry.
        reference_inflation_mm``), added to the output positions (``disp_coarse`` stays relative to the
        reference state, which is what the force head needs). ``coarse_only`` skips the fine stage."""
        a = self.in_feat(feat) + self.in_glob(glob).unsqueeze(1) + self.in_pos(self.coarse_rest / self.R)
        zc, zd = torch.relu(a).chunk(2, -1)
        logit = self.contact(zc).squeeze(-1)  # S6-S7
        gate = torch.sigmoid(logit).unsqueeze(-1)
        h = self.coarse_body(zd)
        d = self.coarse_head(torch.cat([h, gate], -1)) * DISP_SCALE_MM
        disp_c = gate * d[..., :3] + (1 - gate) * d[..., 3:]  # S8-S9: contact-gated deformation
        coarse = self.coarse_rest + disp_c
        infl = None if ref_inflation_mm is None else ref_inflation_mm.view(-1, 1, 1) / self.R
        if infl is not None:
            coarse = coarse + infl * self.coarse_rest
        if coarse_only:
            return {"contact_logit": logit, "coarse": coarse, "hidden": h, "disp_coarse": disp_c}
        # S10-S12: EdgeConv on the coarse graph, interpolate to the dense template, bounded residual
        e = self.edge1(torch.cat([h, disp_c / DISP_SCALE_MM, gate], -1), self.coarse_nbr)
        e = e + self.edge2(e, self.coarse_nbr)
        pre = torch.cat([self.fine_in(torch.cat([e, h, disp_c / DISP_SCALE_MM], -1)), disp_c], -1)
        q = (pre[:, self.interp_idx] * self.interp_w.unsqueeze(-1)).sum(2)  # inverse-distance interpolation
        dd = q[..., -3:]
        q = torch.relu(q[..., :-3] + self.fine_pos(self.dense_rest / self.R))
        dense = self.dense_rest + dd + self.s_mm * torch.tanh(self.fine_out(q))
        if infl is not None:
            dense = dense + infl * self.dense_rest
        return {"contact_logit": logit, "coarse": coarse, "dense": dense, "hidden": h, "disp_coarse": disp_c}


def gine(conv: nn.Module, x: torch.Tensor, edge_index: torch.Tensor, edge_attr: torch.Tensor) -> torch.Tensor:
    """``torch_geometric.nn.GINEConv.forward`` (sum aggregation, source -> target flow) with its own weights:
    ``nn((1 + eps) x_i + sum_{j -> i} ReLU(x_j + lin(e_ji)))``.

    Why not ``conv(x, edge_index, edge_attr)``: on one small graph (331 markers, 1860 edges) the generic
    ``propagate`` machinery (input inspection, ``scatter`` with an expanded index) cost ~0.35 ms of a layer's
    ~0.5 ms, and the encoders run six layers a frame within a 16 ms budget. Same function, same parameters,
    so bundles trained with either path load unchanged (outputs agree to float rounding, tested).
    """
    src, dst = edge_index[0], edge_index[1]
    msg = x.index_select(0, src)
    msg = torch.relu(msg + conv.lin(edge_attr) if conv.lin is not None else msg + edge_attr)
    agg = torch.zeros_like(x).index_add_(0, dst, msg)
    return conv.nn(agg + (1 + conv.eps) * x)


class GraphEncoder(nn.Module):
    """Marker-graph encoder: node MLP + GINE message passing with edge attributes (torch_geometric)."""

    def __init__(self, hidden: int = 64, layers: int = 3, edge_dim: int = EDGE_DIM, node_in: int = NODE_IN) -> None:
        super().__init__()
        from torch_geometric.nn import GINEConv

        self.inp = mlp(node_in, hidden, hidden)
        self.edge_dim = edge_dim
        self.convs = nn.ModuleList([GINEConv(mlp(hidden, hidden, hidden), edge_dim=edge_dim) for _ in range(layers)])
        self.hidden = hidden

    def forward(self, x, edge_index, edge_attr, batch, n_graphs: int) -> tuple[torch.Tensor, torch.Tensor]:
        h = self.inp(x)
        edge_attr = edge_attr[:, : self.edge_dim]  # graphs carry strain columns a model may not use
        for conv in self.convs:
            h = h + torch.relu(gine(conv, h, edge_index, edge_attr))
        F = h.shape[1]
        mean = torch.zeros(n_graphs, F).index_add_(0, batch, h)
        cnt = torch.zeros(n_graphs).index_add_(0, batch, torch.ones_like(batch, dtype=torch.float32))
        mean = mean / cnt.clamp_min(1).unsqueeze(-1)
        mx = torch.full((n_graphs, F), -1e4).scatter_reduce(0, batch.unsqueeze(-1).expand(-1, F), h, "amax")
        mx = torch.where(cnt.unsqueeze(-1) > 0, mx, torch.zeros_like(mx))
        return h, torch.cat([mean, mx], -1)


class DomeGNN(nn.Module):
    """Marker graph -> dense dome surface (mm), contact logits, features for the force head."""

    kind = "gnn"

    def __init__(
        self, geo: DomeGeometry, hidden: int = 64, layers: int = 3, k_markers: int = 4, edge_strain: bool = True
    ) -> None:
        super().__init__()
        from vtrack.dome.features import EDGE_REL_DIM

        self.encoder = GraphEncoder(hidden, layers, EDGE_DIM + (EDGE_REL_DIM if edge_strain else 0))
        self.decoder = CoarseToFineDecoder(geo, hidden, 2 * hidden)
        self.k = k_markers
        self.R_in = geo.cfg.inner_radius_mm

    def forward(self, batch: dict, coarse_only: bool = False) -> dict[str, torch.Tensor]:
        from torch_geometric.utils import to_dense_batch

        B = int(batch["n_graphs"])
        h, glob = self.encoder(batch["x"], batch["edge_index"], batch["edge_attr"], batch["batch"], B)
        hd, mask = to_dense_batch(h, batch["batch"], batch_size=B)
        pd, _ = to_dense_batch(batch["pos"], batch["batch"], batch_size=B)  # marker dirs on the rest dome
        if hd.shape[1] < self.k:  # fewer markers than neighbours (or none): pad with masked slots
            pad = self.k - hd.shape[1]
            hd = torch.cat([hd, hd.new_zeros(B, pad, hd.shape[2])], 1)
            pd = torch.cat([pd, pd.new_zeros(B, pad, 3)], 1)
            mask = torch.cat([mask, mask.new_zeros(B, pad)], 1)
        pd = torch.where(mask.unsqueeze(-1), pd, torch.full_like(pd, 10.0))  # padding far away
        tmpl = (self.decoder.coarse_rest / self.decoder.R).expand(B, -1, 3)
        idx, dist = knn_torch(tmpl, pd, self.k)
        w = idw_weights(dist) * torch.gather(mask.float(), 1, idx.flatten(1)).view_as(dist)
        w = w / w.sum(-1, keepdim=True).clamp_min(1e-6)
        feat = torch.gather(hd, 1, idx.flatten(1).unsqueeze(-1).expand(-1, -1, hd.shape[-1]))
        feat = (feat.view(B, idx.shape[1], self.k, -1) * w.unsqueeze(-1)).sum(2)
        out = self.decoder(feat, glob, coarse_only, batch.get("ref_inflation_mm"))
        out["glob"] = glob
        out["node_h"] = h  # per-marker encoder features, read by the GNN + patch force net (force.PatchGraphForce)
        return out


class DomeCNN(nn.Module):
    """CNN baseline on the raw image (+ reference image channel) with the same decoder."""

    kind = "cnn"

    def __init__(self, geo: DomeGeometry, hidden: int = 64) -> None:
        super().__init__()

        def block(i, o):
            return nn.Sequential(nn.Conv2d(i, o, 3, 2, 1), nn.ReLU(), nn.Conv2d(o, o, 3, 1, 1), nn.ReLU())

        self.b1 = nn.Sequential(nn.Conv2d(2, 16, 5, 2, 2), nn.ReLU())  # single conv at full resolution (CPU budget)
        self.b2, self.b3, self.b4 = block(16, 24), block(24, 48), block(48, hidden)
        self.proj = nn.Linear(48 + hidden, hidden)
        self.decoder = CoarseToFineDecoder(geo, hidden, 2 * hidden)
        uv = geo.project(geo.coarse_dirs * geo.cfg.inner_radius_mm)
        grid = (uv + 0.5) / geo.cfg.image_size * 2 - 1  # align_corners=False pixel centres
        self.register_buffer("grid", torch.tensor(grid, dtype=torch.float32).view(1, 1, -1, 2))

    def forward(self, batch: dict, coarse_only: bool = False) -> dict[str, torch.Tensor]:
        import torch.nn.functional as F

        img = batch["image"]  # (B, 2, S, S) in [0, 1]
        B = img.shape[0]
        f3 = self.b3(self.b2(self.b1(img)))
        f4 = self.b4(f3)
        g = self.grid.expand(B, -1, -1, -1)
        s3 = F.grid_sample(f3, g, align_corners=False).squeeze(2).transpose(1, 2)
        s4 = F.grid_sample(f4, g, align_corners=False).squeeze(2).transpose(1, 2)
        feat = torch.relu(self.proj(torch.cat([s3, s4], -1)))
        glob = torch.cat([f4.mean((2, 3)), f4.amax((2, 3))], -1)
        out = self.decoder(feat, glob, coarse_only, batch.get("ref_inflation_mm"))
        out["glob"] = glob
        out["fmap"] = f4  # stride-16 feature map, read by the CNN force net (force.CNNMapForce)
        return out


class ForceHead(nn.Module):
    """Force F (N, dome frame) from decoder features: patch encoder + pressure FiLM + global graph feature.

    Per coarse point: [decoder feature, coarse displacement, contact probability, inward indentation,
    position] -> point MLP -> mean over 16 fixed patches -> patch MLP -> FiLM by the pressure
    ``h (1 + gamma(P)) + beta(P)`` (S19-S20). Two global indentation sums (contact-weighted and plain, the
    Winkler "volume" proxies) are FiLM-modulated the same way, then [max, mean over patches, sums, graph
    feature] -> MLP -> F. ``use_pressure=False`` feeds P = 0 (the "without pressure" ablation).
    """

    def __init__(
        self,
        geo: DomeGeometry,
        hidden: int = 64,
        glob_dim: int = 128,
        n_patches: int = 16,
        use_pressure: bool = True,
        dec_hidden: int = 48,
    ) -> None:
        super().__init__()
        self.use_pressure = use_pressure
        self.p_max = geo.cfg.pressure_max_kpa
        self.R = geo.cfg.radius_mm
        from vtrack.dome.model import fibonacci_cap, knn_np

        seeds = fibonacci_cap(n_patches, geo.cfg.cap_deg)
        assign, _ = knn_np(geo.coarse_dirs, seeds, 1)
        onehot = np.zeros((n_patches, len(geo.coarse_dirs)), np.float32)
        onehot[assign[:, 0], np.arange(len(geo.coarse_dirs))] = 1
        onehot /= np.maximum(onehot.sum(1, keepdims=True), 1)
        self.register_buffer("pool", torch.tensor(onehot))
        self.point = mlp(dec_hidden + 3 + 1 + 1 + 3, hidden, hidden, last_act=True)
        self.patch = mlp(hidden, hidden, hidden, last_act=True)
        self.film = mlp(1, 32, 2 * hidden + 4)
        # FiLM starts as the identity (gamma = beta = 0): a randomly initialised modulation scales every
        # feature by a random P-dependent factor from the first step, which made the head with pressure
        # train worse than the one without
        nn.init.zeros_(self.film[-1].weight)
        nn.init.zeros_(self.film[-1].bias)
        self.head = mlp(2 * hidden + 2 + glob_dim, hidden, hidden, 3)
        self.hidden = hidden
        # not in the state dict (bundles predate it): the coarse template the decoder features live on
        self.register_buffer("coarse_rest", torch.tensor(geo.coarse_rest, dtype=torch.float32), persistent=False)

    arch = "decoder_film"
    needs_patches = False

    def run(self, out: dict[str, torch.Tensor], batch: dict, pressure_kpa: torch.Tensor) -> torch.Tensor:
        """Common force-net call (``force.PatchGraphForce.run``): reads only the decoder outputs."""
        return self(out, pressure_kpa, self.coarse_rest)

    def forward(self, out: dict[str, torch.Tensor], pressure_kpa: torch.Tensor, coarse_rest: torch.Tensor):
        B = out["hidden"].shape[0]
        nrm = coarse_rest / coarse_rest.norm(dim=-1, keepdim=True)
        ind = torch.relu(-(out["disp_coarse"] * nrm).sum(-1, keepdim=True))  # inward indentation, mm
        prob = torch.sigmoid(out["contact_logit"]).unsqueeze(-1)
        z = torch.cat(
            [out["hidden"], out["disp_coarse"] / DISP_SCALE_MM, prob, ind, (coarse_rest / self.R).expand(B, -1, 3)], -1
        )
        hp = self.patch(torch.einsum("pn,bnf->bpf", self.pool, self.point(z)))  # (B, P, H)
        sums = torch.cat([(ind * prob).sum(1), ind.sum(1)], -1) / 10.0  # (B, 2)
        p = pressure_kpa.view(B, 1) / self.p_max if self.use_pressure else torch.zeros(B, 1)
        H = self.hidden
        gb = self.film(p)  # S19-S20: FiLM by the internal pressure
        gamma, beta, g2, b2 = gb[:, :H], gb[:, H : 2 * H], gb[:, 2 * H : 2 * H + 2], gb[:, 2 * H + 2 :]
        hp = hp * (1 + gamma.unsqueeze(1)) + beta.unsqueeze(1)
        sums = sums * (1 + g2) + b2
        return self.head(torch.cat([hp.amax(1), hp.mean(1), sums, out["glob"]], -1))
