"""Neural SDF mapping on CPU, pure torch: multi-resolution dense feature grid + small MLP.

The SDF lives in the OBJECT frame (metres). Model::

    sdf(x) = |x - c| - r0  +  s * MLP([grid_1(u), ..., grid_L(u), 2u - 1])

with ``u`` the position normalised to the cubic bounds, ``grid_l`` dense trilinear feature grids of
growing resolution (hand-written trilinear interpolation so that the eikonal term can be
differentiated twice; ``F.grid_sample`` has no double backward in 3-D), a softplus MLP, and a
sphere prior (radius ``r0`` = 0.45 x half-extent) that gives a sane sign before any data arrives. Offline the
prior is built from the observations (:attr:`NeuralSDFConfig.prior`, default ``symmetric``: their convex hull
united with a detected surface of revolution, :mod:`vtrack.fusion.symmetry`).

Losses (iSDF / NeuralFeels style), SDF residuals divided by ``sdf_scale``:

- surface: ``|sdf(p)|`` on observed points, weighted by confidence; touch points weighted by
  ``touch_weight`` and drawn as a fixed fraction of the batch (modality balance);
- normal: ``1 - cos(grad sdf(p), n)`` where the normal is known;
- along-normal: ``sdf(p + d n) = d`` for small offsets (tighter inside, thin objects);
- free space along camera rays (vision): samples in the truncation band get the projected distance
  ``s |cos|``; samples farther out must stay positive and within the ray bound (``0 < sdf <= s``);
- eikonal: ``(|grad sdf| - 1)^2`` on uniform and near-surface samples.

Online use (SLAM mapper / streaming): ``integrate(...)`` adds a frame to the replay buffer, and
``step(n_iters=None, time_budget_ms=...)`` trains with half of each batch from the newest frames and
half replayed from every frame kept (bounded buffer). Offline: ``fit(observations, n_iters)``.
Queries: ``query(points_obj) -> (sdf, grad)`` in batches; meshes by marching cubes (pyvista /
VTK ``contour``; scikit-image and PyMCubes are not installed). open3d is never imported here.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from vtrack.errors import InputError
from vtrack.fusion.cloud import TOUCH, VISION


def _torch():
    import torch

    return torch


#: Offline training iterations, the one default of ``vtrack reconstruct`` and the API: on the speed/accuracy front
#: of ``vtrack bench fusion`` (docs/benchmarks/fusion.md, soup can, vision+touch: F@5 mm 0.904 at 400, 0.904 at
#: 300, 0.902 at 600 iterations).
OFFLINE_ITERS = 400

#: Narrow-band mesh extraction (:meth:`NeuralSDFReconstructor.sdf_grid`): coarse grid step in fine cells, and the
#: bound on ``|grad sdf|`` the band assumes (the band is this many coarse cell diagonals wide).
BAND_COARSEN = 4
BAND_LIPSCHITZ = 2.0

#: Shape priors of the neural SDF (:attr:`NeuralSDFConfig.prior`).
PRIORS = ("sphere", "hull", "blend", "symmetric")


class _SDFNet:
    """Dense multires grid + MLP (built lazily so importing this module does not import torch)."""

    def __init__(self, resolutions: list[int], features: int, hidden: int, seed: int) -> None:
        torch = _torch()
        nn = torch.nn
        g = torch.Generator().manual_seed(seed)
        self.res = list(resolutions)
        self.tables = nn.ParameterList(
            [nn.Parameter((torch.rand(((r + 1) ** 3, features), generator=g) * 2 - 1) * 1e-4) for r in self.res]
        )
        d_in = features * len(self.res) + 3
        with torch.random.fork_rng(devices=[]):  # seeded MLP init, global RNG left untouched
            torch.manual_seed(seed)
            self.mlp = nn.Sequential(
                nn.Linear(d_in, hidden),
                nn.Softplus(beta=100),
                nn.Linear(hidden, hidden),
                nn.Softplus(beta=100),
                nn.Linear(hidden, 1),
            )
        with torch.no_grad():
            self.mlp[-1].weight.mul_(0.01)
            self.mlp[-1].bias.zero_()
        corners = torch.tensor([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
        self.corners = corners  # (8, 3)

    def parameters(self) -> list:
        return list(self.tables.parameters()) + list(self.mlp.parameters())

    def features(self, u):
        """u (N, 3) in [0, 1] -> concatenated trilinear features (N, L*C)."""
        feats = [trilinear(table, r, u, self.corners) for r, table in zip(self.res, self.tables, strict=True)]
        return _torch().cat(feats, 1)

    def state_dict(self) -> dict:
        return {"tables": [t.detach().clone() for t in self.tables], "mlp": self.mlp.state_dict()}


def trilinear(table, r: int, u, corners):
    """Trilinear interpolation of a dense ``(r + 1)^3 x C`` table at u (N, 3) in [0, 1] -> (N, C), written by hand
    so that it has a double backward (the eikonal term)."""
    torch = _torch()
    g = u * r
    i0 = torch.clamp(torch.floor(g.detach()), 0, r - 1)
    f = g - i0  # (N, 3) in [0, 1]; carries the gradient w.r.t. u
    ii = i0.long()[:, None, :] + corners[None]  # (N, 8, 3)
    R = r + 1
    idx = (ii[..., 0] * R + ii[..., 1]) * R + ii[..., 2]
    # corner weights as an outer product (cheaper than prod(), esp. its double backward)
    wx = torch.stack([1 - f[:, 0], f[:, 0]], 1)
    wy = torch.stack([1 - f[:, 1], f[:, 1]], 1)
    wz = torch.stack([1 - f[:, 2], f[:, 2]], 1)
    w = (wx[:, :, None, None] * wy[:, None, :, None] * wz[:, None, None, :]).reshape(-1, 8)
    return (table[idx] * w[..., None]).sum(1)


@dataclass
class NeuralSDFConfig:
    """Options of :class:`NeuralSDFReconstructor` and their defaults (the one place they are set; the offline
    iteration count is :data:`OFFLINE_ITERS`).

    extent: half-size (m) of the online default box. cell_mm: target finest grid cell (mm); the finest
    resolution is clipped to ``max_res``. levels: number of grid levels (resolutions geometric from 8 to the
    finest). features, hidden: feature channels per level, MLP width. lr: Adam learning rate. batch: surface
    samples per iteration (other terms scale with it). touch_weight: per-point weight of touch relative to
    vision; touch_fraction: share of the surface batch drawn from touch points when there are any. trunc:
    truncation band (m) for the ray samples. normal_offset: max along-normal offset (m). sdf_scale (m),
    eikonal_weight, normal_weight, free_weight: loss terms. mesh_cell_mm: marching-cubes cell (mm).
    max_points: replay-buffer capacity (points). keep_largest: keep the mesh's largest component. seed: RNG.
    prior (offline :meth:`~NeuralSDFReconstructor.fit`; online it is always the sphere): ``sphere`` (radius 0.45 x
    the box half-size at its centre), ``hull`` (signed distance to the convex hull of the observed points: an
    unobserved side spans the observed parts instead of sagging towards the centre), ``blend`` (their mean) or
    ``symmetric`` (default: the hull united with the surface of revolution of :mod:`vtrack.fusion.symmetry` when
    the observations are one, e.g. a ball or a can: their unseen side is the revolved seen profile, not a flat cut);
    hull_cluster_mm: the hull is built from the 26-connected clusters of this cell size holding >= 2 % of the
    points (stray points dropped). hull_weight, hull_margin (m): optional loss ``sdf <= hull SDF + margin``
    deeper than the margin inside the hull (0 = off).
    carve (offline :meth:`~NeuralSDFReconstructor.fit` only): space carving from the cameras' free-space images
    (:mod:`vtrack.fusion.carve`); carve_cell_mm voxel (mm), carve_margin (m) in front of the free depth,
    carve_votes frames that must see a voxel empty; carve_band (m): carved voxels within this distance of the
    uncarved region are sampled each iteration with the loss ``relu(bound - sdf)`` (weight carve_weight);
    carve_crop: the mesh is cut to the carved hull grown by one cell. mesh_band: narrow-band mesh extraction
    (:meth:`~NeuralSDFReconstructor.sdf_grid`: exact network queries only near the surface). sections (prior
    ``symmetric`` only, when no surface of revolution is found): unite the hull with the elliptic cross-sections of
    an elongated cloud (:mod:`vtrack.fusion.sections`: the unseen back of a banana or a bottle); sections_grow: their
    ``consistent_grow`` (0 = short seen arcs never trusted).
    prior_weight, prior_far_mm (offline, ``symmetric`` prior with elliptic sections): loss ``|sdf - prior|`` on
    uniform samples within the truncation band of the prior's surface where the sections extend the hull, weighted
    from 0 at ``prior_far_mm`` to 1 at twice that distance from every observed point: where nothing was seen the
    shape stays the sections' (the residual network, fitted near the data, would otherwise carry its corrections
    across the unseen back and thin it). 0 = off.
    """

    extent: float = 0.12
    cell_mm: float = 2.5
    levels: int = 4
    max_res: int = 64
    features: int = 2
    hidden: int = 64
    lr: float = 4e-3
    batch: int = 512
    touch_weight: float = 3.0
    touch_fraction: float = 0.35
    trunc: float = 0.01
    normal_offset: float = 0.004
    sdf_scale: float = 0.005
    eikonal_weight: float = 0.05
    normal_weight: float = 0.1
    free_weight: float = 0.5
    mesh_cell_mm: float = 1.5
    max_points: int = 300_000
    keep_largest: bool = True
    seed: int = 0
    prior: str = "symmetric"
    hull_weight: float = 0.0
    hull_cluster_mm: float = 4.0
    hull_margin: float = 0.004
    carve: bool = False
    carve_cell_mm: float = 2.0
    carve_margin: float = 0.003
    carve_votes: int = 2
    carve_band: float = 0.02
    carve_weight: float = 1.0
    carve_crop: bool = True
    mesh_band: bool = True
    sections: bool = True
    sections_grow: float = 2.5
    box: bool = True
    box_free_max: float = 0.5
    prior_weight: float = 1.0
    prior_far_mm: float = 6.0


class NeuralSDFReconstructor:
    """Neural SDF mapper in the object frame (metres); see the module docstring.

    Args:
        bounds: ((xmin, ymin, zmin), (xmax, ymax, zmax)) object-frame box, m. If None it is taken from
            the data: all observations in :meth:`fit`, or the first integrated frame's centroid +-
            ``extent`` online.
        config: options (:class:`NeuralSDFConfig`); ``opts`` override single fields of it by name
            (``NeuralSDFReconstructor(batch=256)``); an unknown name raises :class:`InputError`.
        threads: torch threads (None = leave as is).
    """

    def __init__(
        self, bounds: Any = None, *, config: NeuralSDFConfig | None = None, threads: int | None = None, **opts: Any
    ) -> None:
        from vtrack.config import build_config

        self.config = build_config(NeuralSDFConfig, opts, "neural SDF", base=config)
        if self.config.prior not in PRIORS:
            raise InputError(
                "unknown neural SDF prior", field="prior", expected=" | ".join(PRIORS), got=self.config.prior
            )
        for name in ("prior_weight", "sections_grow", "prior_far_mm"):
            v = getattr(self.config, name)
            if not (np.isfinite(v) and v >= 0 and (v > 0 or name != "prior_far_mm")):
                raise InputError(
                    "bad neural SDF option", field=name, expected="a finite number >= 0 (> 0 for prior_far_mm)", got=v
                )
        self.opts = asdict(self.config)
        seed = self.config.seed
        if threads:
            _torch().set_num_threads(int(threads))
        self.net: _SDFNet | None = None
        self.lo: np.ndarray | None = None
        self.size: float = 0.0
        self._buf: dict[str, np.ndarray] = {
            "p": np.zeros((0, 3), np.float32),
            "n": np.zeros((0, 3), np.float32),
            "o": np.zeros((0, 3), np.float32),
            "w": np.zeros(0, np.float32),
            "m": np.zeros(0, np.int8),
            "frame": np.zeros(0, np.int64),
        }
        self._frame = 0
        self._recent_from = 0  # buffer index where points not yet trained on start
        self._rng = np.random.default_rng(seed)
        self.iterations = 0
        self.train_seconds = 0.0
        self.last_loss: dict[str, float] = {}
        self._carve: Any = None  # vtrack.fusion.carve.CarveGrid once fit() carved the box
        self._hull_prior: Any = None  # ((r + 1)^3, 1) torch table of the convex-hull prior over the box
        self._hull_res = 0
        self._obs_dist: Any = None  # ((r + 1)^3, 1) torch table: distance (m) to the observations where the
        # sections make the prior, 0 elsewhere (prior_weight)
        self.revolution: Any = None  # vtrack.fusion.symmetry.Revolution found by the symmetric prior, if any
        self.sections: Any = None  # vtrack.fusion.sections.Sections found by the symmetric prior, if any
        self.box: Any = None  # vtrack.fusion.boxprior.Box found by the symmetric prior, if any
        self.box_free = float("nan")  # share of the volume the accepted box adds that the cameras saw empty
        self._carve_idx: np.ndarray | None = None
        self.carve_seconds = 0.0
        if bounds is not None:
            self.set_bounds(bounds)

    @classmethod
    def from_scene(cls, scene: Any = None, **opts: Any) -> NeuralSDFReconstructor:
        """Registry entry point (``reconstruction.neural_sdf``); the scene carries nothing needed yet."""
        return cls(**opts)

    # -- setup -------------------------------------------------------------------------------
    def set_bounds(self, bounds: Any) -> None:
        """Fix the object-frame cubic box (m) and build the network (only once)."""
        b = np.asarray(bounds, np.float64).reshape(2, 3)
        if not np.all(np.isfinite(b)) or np.any(b[1] <= b[0]):
            raise InputError("invalid bounds", field="bounds", expected="finite min < max", got=b.tolist())
        if self.net is not None:
            return
        c = 0.5 * (b[0] + b[1])
        half = 0.5 * float(np.max(b[1] - b[0]))
        self.lo = c - half
        self.size = 2 * half
        o = self.opts
        finest = int(np.clip(math.ceil(self.size / (o["cell_mm"] * 1e-3)), 16, o["max_res"]))
        L = max(1, int(o["levels"]))
        res = sorted({int(round(8 * (finest / 8) ** (i / max(L - 1, 1)))) for i in range(L)})
        torch = _torch()
        self.net = _SDFNet(res, o["features"], o["hidden"], o["seed"])
        self._center = torch.tensor(c, dtype=torch.float32)
        self._r0 = 0.45 * half
        self._opt = torch.optim.Adam(self.net.parameters(), lr=o["lr"], foreach=True)
        self.resolutions = res

    @staticmethod
    def bounds_from_points(points: np.ndarray, margin: float = 0.15, pad: float = 0.01) -> np.ndarray:
        """Robust cube around points (far outliers dropped, 0.2 / 99.8 percentiles, +``margin``, +``pad`` m)."""
        P = np.asarray(points, np.float64).reshape(-1, 3)
        P = P[np.isfinite(P).all(1)]
        if len(P) == 0:
            raise InputError(
                "no finite points to size the reconstruction volume", field="points", expected="> 0 points"
            )
        # Far outliers first (beyond 8x the median distance to the median point), then percentiles.
        d = np.linalg.norm(P - np.median(P, axis=0), axis=1)
        P = P[d <= max(8.0 * float(np.median(d)), 1e-3)]
        lo, hi = np.percentile(P, 0.2, axis=0), np.percentile(P, 99.8, axis=0)
        c = 0.5 * (lo + hi)
        half = 0.5 * float(np.max(hi - lo)) * (1 + margin) + pad
        return np.stack([c - half, c + half])

    # -- data --------------------------------------------------------------------------------
    def integrate(
        self,
        points: np.ndarray,
        normals: np.ndarray | None = None,
        modality: int = VISION,
        *,
        origin: np.ndarray | None = None,
        confidence: np.ndarray | float | None = None,
    ) -> int:
        """Add one frame of object-frame surface points (m) to the replay buffer.

        Args:
            points: (N, 3) surface points in the object frame.
            normals: (N, 3) outward normals (zero rows = unknown) or None.
            modality: 0 vision / 1 touch (scalar or (N,)).
            origin: (3,) viewpoint in the object frame for free-space rays (vision); None = no rays.
            confidence: (N,) or scalar in [0, 1].

        Returns the number of points kept (non-finite rows and points far outside the box dropped).
        """
        P = np.asarray(points, np.float64).reshape(-1, 3)
        n = len(P)
        N = np.zeros((n, 3)) if normals is None else np.asarray(normals, np.float64).reshape(n, 3)
        mod = np.broadcast_to(np.asarray(modality, np.int8), (n,))
        conf = np.ones(n) if confidence is None else np.broadcast_to(np.asarray(confidence, np.float64), (n,))
        ok = np.isfinite(P).all(1)
        N = np.where(np.isfinite(N).all(1, keepdims=True), N, 0.0)
        ln = np.linalg.norm(N, axis=1, keepdims=True)
        N = np.where(ln > 1e-6, N / np.maximum(ln, 1e-12), 0.0)
        conf = np.nan_to_num(np.clip(conf, 0.0, 1.0), nan=0.0)
        ok &= conf > 0
        if not ok.any():
            self._frame += 1
            return 0
        if self.net is None:
            e = self.opts["extent"]
            c = np.median(P[ok], axis=0)
            self.set_bounds(np.stack([c - e, c + e]))
        # Points outside the box (outliers, other objects) cannot be represented: drop them.
        u = (P - self.lo) / self.size
        ok &= np.all((u > 0.0) & (u < 1.0), axis=1)
        o = np.full((n, 3), np.nan) if origin is None else np.broadcast_to(np.asarray(origin, np.float64), (n, 3))
        if origin is not None and not np.all(np.isfinite(origin)):
            o = np.full((n, 3), np.nan)
        w = conf * np.where(mod == TOUCH, self.opts["touch_weight"], 1.0)
        k = int(ok.sum())
        add = {"p": P[ok], "n": N[ok], "o": o[ok], "w": w[ok], "m": mod[ok], "frame": np.full(k, self._frame)}
        for key, v in add.items():
            self._buf[key] = np.concatenate([self._buf[key], v.astype(self._buf[key].dtype)])
        self._frame += 1
        self._trim()
        return k

    def integrate_observation(self, obs: Any) -> int:
        """Add a :class:`vtrack.fusion.observations.Observation` (vision rays from its viewpoint)."""
        origin = obs.origin if obs.modality == VISION else None
        return self.integrate(obs.points, obs.normals, obs.modality, origin=origin, confidence=obs.confidence)

    def _trim(self) -> None:
        cap = int(self.opts["max_points"])
        n = len(self._buf["p"])
        if n <= cap:
            return
        # Keep every touch point and the newest frame; randomly thin older vision points.
        old = np.nonzero((self._buf["m"] == VISION) & (np.arange(n) < self._recent_from))[0]
        drop_n = min(len(old), n - cap + cap // 10)
        drop = self._rng.choice(old, drop_n, replace=False) if drop_n > 0 else np.zeros(0, np.int64)
        keep = np.ones(n, bool)
        keep[drop] = False
        self._recent_from -= int(np.sum(drop < self._recent_from))
        for key in self._buf:
            self._buf[key] = self._buf[key][keep]

    @property
    def n_points(self) -> int:
        return len(self._buf["p"])

    # -- model -------------------------------------------------------------------------------
    def _sdf_t(self, x):
        """sdf (N,) for object-frame points x (N, 3) float32 tensor (m)."""
        torch = _torch()
        u = ((x - torch.as_tensor(self.lo, dtype=x.dtype)) / self.size).clamp(0.0, 1.0)
        h = torch.cat([self.net.features(u), u * 2 - 1], dim=1)
        prior = torch.linalg.norm(x - self._center, dim=1) - self._r0
        if self._hull_prior is not None and self.opts["prior"] in ("hull", "symmetric"):
            prior = self._hull_t(u)
        elif self._hull_prior is not None and self.opts["prior"] == "blend":
            prior = 0.5 * (prior + self._hull_t(u))
        return prior + self.net.mlp(h)[:, 0] * (0.5 * self.size)

    def _hull_t(self, u):
        """Signed distance (N,) m to the convex hull of the observations at box coordinates u (N, 3) in [0, 1]."""
        return trilinear(self._hull_prior, self._hull_res, u, self.net.corners)[:, 0]

    def _pools(self) -> tuple[np.ndarray, np.ndarray]:
        """Sorted buffer indices of touch and vision points (cached until the buffer changes)."""
        n = self.n_points
        if getattr(self, "_pool_n", -1) != n or getattr(self, "_pool_frame", -1) != self._frame:
            m = self._buf["m"]
            self._pool_cache = (np.nonzero(m == TOUCH)[0], np.nonzero(m != TOUCH)[0])
            self._pool_n, self._pool_frame = n, self._frame
        return self._pool_cache

    def _sample(self) -> dict[str, np.ndarray] | None:
        n = self.n_points
        if n == 0:
            return None
        B = int(self.opts["batch"])
        touch, vis = self._pools()
        n_t = int(round(B * self.opts["touch_fraction"])) if len(vis) else B
        n_t = n_t if len(touch) else 0
        n_v = B - n_t if len(vis) else 0
        picks = []
        for pool, k in ((touch, n_t), (vis, n_v)):
            if k <= 0 or len(pool) == 0:
                continue
            # Buffer indices grow with time, so the newest (not yet trained) points are a suffix.
            rp = pool[np.searchsorted(pool, self._recent_from) :]
            if 0 < len(rp) < len(pool):
                half = k // 2
                picks.append(self._rng.choice(rp, half))
                picks.append(self._rng.choice(pool, k - half))
            else:
                picks.append(self._rng.choice(pool, k))
        idx = np.concatenate(picks)
        return {k: v[idx] for k, v in self._buf.items()}

    def step(self, n_iters: int | None = None, time_budget_ms: float | None = None) -> int:
        """Train for ``n_iters`` iterations, or as many as fit in ``time_budget_ms`` (at least one).

        Returns the number of iterations done (0 when there is no data).
        """
        if self.n_points == 0 or self.net is None:
            return 0
        torch = _torch()
        t0 = time.perf_counter()
        done = 0
        limit = n_iters if n_iters is not None else (1 if time_budget_ms is None else 10**9)
        per_iter = None
        while done < limit:
            ti = time.perf_counter()
            self._iteration(torch)
            done += 1
            per_iter = (
                time.perf_counter() - ti if per_iter is None else 0.7 * per_iter + 0.3 * (time.perf_counter() - ti)
            )
            if time_budget_ms is not None:
                elapsed = (time.perf_counter() - t0) * 1e3
                if elapsed + per_iter * 1e3 > time_budget_ms:
                    break
        self._recent_from = self.n_points
        self.train_seconds += time.perf_counter() - t0
        return done

    def _iteration(self, torch) -> None:
        o = self.opts
        s = self._sample()
        if s is None:
            return
        rng = self._rng
        B = len(s["p"])
        P, Nn, W = s["p"], s["n"], s["w"]
        has_n = np.linalg.norm(Nn, axis=1) > 0.5
        # along-normal offsets: tighter inside (thin objects), full range outside
        d = rng.uniform(-0.6 * o["normal_offset"], o["normal_offset"], B).astype(np.float32)
        Xn = P + d[:, None] * Nn
        # ray samples (vision with a viewpoint)
        has_o = np.isfinite(s["o"]).all(1)
        ray_tgt_lo = np.zeros(0, np.float32)
        ray_tgt_hi = np.zeros(0, np.float32)
        Xr = np.zeros((0, 3), np.float32)
        if has_o.any():
            pr, orr = P[has_o], s["o"][has_o]
            v = orr - pr
            dist = np.linalg.norm(v, axis=1)
            u = v / np.maximum(dist[:, None], 1e-9)
            cos = np.where(has_n[has_o], np.abs(np.einsum("ij,ij->i", u, Nn[has_o])), 1.0)
            cos = np.maximum(cos, 0.2)
            nb = len(pr)
            near = rng.uniform(0.0, o["trunc"], nb)
            far = rng.uniform(o["trunc"], np.maximum(np.minimum(dist * 0.9, 0.3), o["trunc"] * 1.01), nb)
            sdist = np.concatenate([near, far]).astype(np.float32)
            uu = np.concatenate([u, u])
            cc = np.concatenate([cos, cos])
            Xr = np.concatenate([pr, pr]) + sdist[:, None] * uu
            ray_tgt_lo = np.minimum(sdist * cc, o["trunc"]).astype(np.float32)
            ray_tgt_hi = sdist
            is_near = np.concatenate([np.ones(nb, bool), np.zeros(nb, bool)])
        Xe = (self.lo + self.size * rng.random((B // 2, 3))).astype(np.float32)
        Xc, lb_c = self._carve_samples(B // 2 if self._carve_idx is not None else 0)
        use_hull = self._hull_prior is not None and o["hull_weight"] > 0
        Xh = (self.lo + self.size * rng.random((B // 2 if use_hull else 0, 3))).astype(np.float32)
        # Points that need the spatial gradient (normal + eikonal terms): surface and uniform samples.
        x = torch.from_numpy(np.concatenate([P, Xe]).astype(np.float32)).requires_grad_(True)
        f = self._sdf_t(x)
        (g,) = torch.autograd.grad(f.sum(), x, create_graph=True)
        # Value-only points: along-normal offsets and ray samples.
        fv = self._sdf_t(torch.from_numpy(np.concatenate([Xn, Xr, Xc, Xh]).astype(np.float32)))
        sc = o["sdf_scale"]
        wt = torch.from_numpy(W.astype(np.float32))
        i0 = B
        l_surf = (wt * f[:i0].abs()).mean() / sc
        hn = torch.from_numpy(has_n)
        nt = torch.from_numpy(Nn.astype(np.float32))
        cosg = torch.nn.functional.cosine_similarity(g[:i0], nt, dim=1, eps=1e-6)
        l_norm = (wt * hn * (1 - cosg)).sum() / max(1, int(has_n.sum()))
        l_off = (wt * hn * (fv[:B] - torch.from_numpy(d)).abs()).sum() / max(1, int(has_n.sum())) / sc
        l_free = torch.zeros(())
        l_carve = torch.zeros(())
        i_c = B + len(Xr)
        if len(Xc):
            l_carve = torch.relu(torch.from_numpy(lb_c) - fv[i_c : i_c + len(Xc)]).mean() / sc
        l_hull = torch.zeros(())
        if len(Xh):
            # inside the convex hull of the observations the object is solid: sdf <= the hull's (negative) SDF
            with torch.no_grad():
                xh = torch.from_numpy(Xh)
                hv = self._hull_t(((xh - torch.as_tensor(self.lo, dtype=xh.dtype)) / self.size).clamp(0.0, 1.0))
            m = o["hull_margin"]  # the hull's vertices are the noisiest outermost points: bound only deeper in
            inside = hv < -m
            if bool(inside.any()):
                l_hull = torch.relu(fv[i_c + len(Xc) :] - (hv + m))[inside].mean() / sc
        if len(Xr):
            fr = fv[B : B + len(Xr)]
            lo_t, hi_t = torch.from_numpy(ray_tgt_lo), torch.from_numpy(ray_tgt_hi)
            nm = torch.from_numpy(is_near)
            near_l = (fr - lo_t).abs()
            far_l = torch.relu(lo_t - fr) + torch.relu(fr - hi_t)
            l_free = torch.where(nm, near_l, far_l).mean() / sc
        l_prior = torch.zeros(())
        if o["prior_weight"] > 0 and self._obs_dist is not None:
            # far from every observation the surface is the prior's (see NeuralSDFConfig.prior_weight)
            with torch.no_grad():
                ue = ((x[B:] - torch.as_tensor(self.lo, dtype=x.dtype)) / self.size).clamp(0.0, 1.0)
                pe = self._hull_t(ue)
                far = 1e-3 * o["prior_far_mm"]
                dist = trilinear(self._obs_dist, self._hull_res, ue, self.net.corners)[:, 0]
                we = ((dist - far) / far).clamp(0.0, 1.0) * (pe.abs() < o["trunc"])
            if bool((we > 0).any()):
                l_prior = (we * (f[B:] - pe).abs()).sum() / we.sum().clamp(min=1.0) / sc
        gn = torch.linalg.norm(g, dim=1)
        l_eik = ((gn - 1) ** 2).mean()
        loss = (
            l_surf
            + o["normal_weight"] * l_norm
            + l_off
            + o["free_weight"] * l_free
            + o["eikonal_weight"] * l_eik
            + o["carve_weight"] * l_carve
            + o["hull_weight"] * l_hull
            + o["prior_weight"] * l_prior
        )
        if not torch.isfinite(loss):
            # Never let a bad batch poison the model: skip it.
            self._opt.zero_grad(set_to_none=True)
            return
        self._opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(self.net.parameters(), 10.0)
        self._opt.step()
        self.iterations += 1
        self.last_loss = {
            k: float(v.detach())
            for k, v in (
                ("total", loss),
                ("surface", l_surf),
                ("normal", l_norm),
                ("offset", l_off),
                ("free", l_free),
                ("eikonal", l_eik),
                ("carve", l_carve),
                ("hull", l_hull),
                ("prior", l_prior),
            )
        }

    def set_hull_prior(
        self, points: np.ndarray, normals: np.ndarray | None = None, observations: list | None = None
    ) -> bool:
        """Use the convex hull of ``points`` (object frame, m) as the SDF prior instead of the sphere: where
        nothing was observed the surface spans the observed parts (flat caps, no shrinking towards the
        centre). With ``prior="symmetric"`` a surface of revolution detected in the points
        (:func:`vtrack.fusion.symmetry.fit_revolution`; ``normals`` (N, 3) orient its normals) is added to the
        hull (union): the unseen side of a ball or a can is completed by revolving the seen profile; failing that,
        a face-aligned box (:func:`vtrack.fusion.boxprior.fit_box`) when the cameras of ``observations`` saw at
        most ``box_free_max`` of the volume it adds to the hull empty; failing that, elliptic sections.
        Returns False (sphere kept) when the points span no volume."""
        from scipy.spatial import ConvexHull, QhullError

        P = np.asarray(points, np.float64).reshape(-1, 3)
        Nrm = np.zeros_like(P) if normals is None else np.asarray(normals, np.float64).reshape(-1, 3)
        fin = np.isfinite(P).all(1)
        P, Nrm = P[fin], Nrm[fin]
        self.revolution = None
        self.sections = None
        self.box = None
        if len(P) < 4:
            return False
        keep = largest_cluster(P, self.opts["hull_cluster_mm"] * 1e-3, return_mask=True)
        P, Nrm = P[keep], Nrm[keep]
        # voxel-thin the points first (qhull time, and duplicates)
        _, first = np.unique(np.floor((P - P.min(0)) / 2e-3).astype(np.int64), axis=0, return_index=True)
        if len(first) < 4:
            return False
        try:
            eq = ConvexHull(P[first]).equations  # (F, 4): n . x + d <= 0 inside, n unit outward
        except (QhullError, ValueError):
            return False
        # the hull's SDF (max over facets of the plane distance: exact inside, a lower bound outside) on a
        # dense grid over the box, interpolated like the feature grids (cheaper than the facets per sample)
        r = int(np.clip(math.ceil(self.size / (self.opts["cell_mm"] * 1e-3)), 16, 64))
        ax = self.lo[0] + np.arange(r + 1) * (self.size / r), self.lo[1] + np.arange(r + 1) * (self.size / r)
        ax = (*ax, self.lo[2] + np.arange(r + 1) * (self.size / r))
        X, Y, Z = np.meshgrid(*ax, indexing="ij")
        G = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
        val = np.full(len(G), -np.inf, np.float32)
        G32, eq32 = G.astype(np.float32), eq.astype(np.float32)
        for a in range(0, len(eq), 128):
            np.maximum(val, (G32 @ eq32[a : a + 128, :3].T + eq32[a : a + 128, 3]).max(1), out=val)
        sections_add = None  # grid nodes where the sections extend the hull (held by prior_weight)
        if self.opts["prior"] == "symmetric":
            from vtrack.fusion.symmetry import fit_revolution

            self.revolution = fit_revolution(P[first], Nrm[first], seed=self.opts["seed"])
            if self.revolution is not None:
                np.minimum(val, self.revolution.sdf(G).astype(np.float32), out=val)
            if self.revolution is None and self.opts["box"]:
                from vtrack.fusion.boxprior import fit_box

                # normals by local PCA of the 2 mm-thinned cloud: the fused ones are too noisy for plane families
                box = fit_box(P[first], seed=self.opts["seed"]) if observations else None
                if box is not None:
                    bv = box.sdf(G).astype(np.float32)
                    # the box may fill only space nobody saw: the volume it adds to the hull (a cell deep)
                    # must not have been seen empty (free-space votes of >= 2 frames, like the carving)
                    cell = self.size / r
                    add = np.nonzero((bv < -cell) & (val > cell))[0]
                    if len(add):
                        from vtrack.fusion.carve import free_votes

                        pick = add[
                            np.random.default_rng(self.opts["seed"]).choice(
                                len(add), min(len(add), 4000), replace=False
                            )
                        ]
                        free = float(np.mean(free_votes(observations, G[pick]) >= 2))
                        if free <= self.opts["box_free_max"]:
                            self.box = box
                            self.box_free = free
                            np.minimum(val, bv, out=val)
            if self.revolution is None and self.box is None and self.opts["sections"]:
                from vtrack.fusion.sections import fit_sections

                self.sections = fit_sections(P, consistent_grow=self.opts["sections_grow"])
                if self.sections is not None:
                    sv = self.sections.sdf(G).astype(np.float32)
                    sections_add = sv < val - 1e-4
                    np.minimum(val, sv, out=val)
        torch = _torch()
        self._hull_prior = torch.tensor(val[:, None], dtype=torch.float32)
        self._hull_res = r
        self._obs_dist = None
        if self.opts["prior_weight"] > 0 and sections_add is not None:
            from scipy.spatial import cKDTree

            # distance (m) from each grid node to the nearest observed point, capped (only "far" matters)
            cap = 2e-3 * self.opts["prior_far_mm"]
            dist = np.minimum(cKDTree(P[first]).query(G, distance_upper_bound=cap)[0], cap)
            # only where the sections (not the hull) make the prior: the hull over-fills concave unseen parts (a
            # banana's inner curve), which the data must stay free to carve; revolution and box completions lost
            # F@5 when held like this (soup can, mug, potted meat can; docs/benchmarks/sections_hold.md)
            dist = np.where(sections_add, dist, 0.0)
            self._obs_dist = torch.tensor(dist[:, None], dtype=torch.float32)
        return True

    def set_carving(self, observations: list) -> None:
        """Carve the box with the observations' free-space images (:func:`vtrack.fusion.carve.carve`); the
        observed surface points in the buffer are protected. No free-space evidence: carving stays off."""
        from vtrack.fusion.carve import carve

        o = self.opts
        self._carve = carve(
            observations,
            self.lo,
            self.size,
            cell=o["carve_cell_mm"] * 1e-3,
            margin=o["carve_margin"],
            min_votes=o["carve_votes"],
            protect=self._buf["p"],
        )
        self._carve_idx = None
        if self._carve is not None:
            b = self._carve.bound
            idx = np.argwhere(np.isfinite(b) & (b <= o["carve_band"]))
            self._carve_idx = idx if len(idx) else None

    def _carve_samples(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """``k`` points jittered within carved voxels of the band and their SDF lower bounds (m)."""
        cg, idx = self._carve, self._carve_idx
        if cg is None or idx is None or k <= 0:
            return np.zeros((0, 3), np.float32), np.zeros(0, np.float32)
        pick = idx[self._rng.integers(0, len(idx), k)]
        # jitter within +-half a cell: the bound already leaves one cell of slack
        x = cg.centres(pick) + (self._rng.random((k, 3)) - 0.5) * cg.cell
        lb = cg.bound[pick[:, 0], pick[:, 1], pick[:, 2]]
        return x.astype(np.float32), lb.astype(np.float32)

    # -- offline -----------------------------------------------------------------------------
    def fit(
        self,
        observations: list,
        n_iters: int = OFFLINE_ITERS,
        time_budget_s: float | None = None,
        lr_decay: bool = True,
    ) -> dict[str, Any]:
        """Offline: integrate every observation, size the box from all points, train ``n_iters``
        (default :data:`OFFLINE_ITERS`)."""
        obs = [o for o in observations if len(o)]
        if self.net is None:
            allp = np.concatenate([o.points for o in obs]) if obs else np.zeros((0, 3))
            if len(allp) == 0:
                return {"iterations": 0, "points": 0, "seconds": 0.0}
            self.set_bounds(self.bounds_from_points(allp))
        for ob in obs:
            self.integrate_observation(ob)
        self._recent_from = self.n_points  # offline: uniform replay
        hull_based = self.opts["prior"] in ("hull", "blend", "symmetric") or self.opts["hull_weight"] > 0
        if hull_based and self.iterations == 0:
            self.set_hull_prior(self._buf["p"], self._buf["n"], observations=obs)
        t_c = time.perf_counter()
        if self.opts["carve"]:
            self.set_carving(obs)
        self.carve_seconds = time.perf_counter() - t_c
        t0 = time.perf_counter()
        torch = _torch()
        sched = (
            torch.optim.lr_scheduler.CosineAnnealingLR(self._opt, T_max=max(1, n_iters), eta_min=self.opts["lr"] * 0.1)
            if lr_decay
            else None
        )
        it = 0
        while it < n_iters:
            self.step(1)
            if sched is not None:
                sched.step()
            it += 1
            if time_budget_s is not None and time.perf_counter() - t0 > time_budget_s:
                break
        return {"iterations": it, "points": self.n_points, "seconds": time.perf_counter() - t0}

    # -- queries -----------------------------------------------------------------------------
    def query(
        self, points_obj: np.ndarray, batch: int = 65536, with_grad: bool = True
    ) -> tuple[np.ndarray, np.ndarray]:
        """SDF (N,) in m and its gradient (N, 3) at object-frame points (N, 3), in batches.

        Non-finite query points get sdf = +trunc and a zero gradient (never NaN).
        """
        torch = _torch()
        P = np.asarray(points_obj, np.float64).reshape(-1, 3)
        n = len(P)
        sdf = np.full(n, self.opts["trunc"], np.float64)
        grad = np.zeros((n, 3), np.float64)
        if n == 0 or self.net is None:
            return sdf, grad
        ok = np.isfinite(P).all(1)
        idx = np.nonzero(ok)[0]
        for a in range(0, len(idx), batch):
            sel = idx[a : a + batch]
            x = torch.from_numpy(P[sel].astype(np.float32))
            if with_grad:
                x.requires_grad_(True)
                f = self._sdf_t(x)
                (g,) = torch.autograd.grad(f.sum(), x)
                grad[sel] = g.numpy()
                sdf[sel] = f.detach().numpy()
            else:
                with torch.no_grad():
                    sdf[sel] = self._sdf_t(x).numpy()
        np.nan_to_num(sdf, copy=False, nan=self.opts["trunc"], posinf=1.0, neginf=-1.0)
        np.nan_to_num(grad, copy=False, nan=0.0, posinf=0.0, neginf=0.0)
        return sdf, grad

    def sdf_grid(self, cell_mm: float | None = None, band: bool | None = None) -> tuple[np.ndarray, np.ndarray, float]:
        """SDF sampled on a regular grid over the bounds: (values (nx, ny, nz), origin (3,), spacing m).

        ``band`` (default :attr:`NeuralSDFConfig.mesh_band`): evaluate the network exactly only near the zero level
        set. A grid :data:`BAND_COARSEN` times coarser is queried first and trilinearly upsampled; the fine nodes
        whose upsampled value lies within ``BAND_LIPSCHITZ`` coarse cell diagonals of zero are queried exactly, the
        others keep the upsampled value, whose sign is that of the exact SDF as long as ``|grad sdf| <=
        BAND_LIPSCHITZ`` (the eikonal term keeps it near 1). Same mesh, a fraction of the queries (a long
        object's 256^3 grid was most of a reconstruction's time)."""
        if self.net is None:
            raise InputError("the neural SDF has no data yet", field="integrate")
        cell = (cell_mm or self.opts["mesh_cell_mm"]) * 1e-3
        n = int(np.clip(math.ceil(self.size / cell) + 1, 16, 256))
        h = self.size / (n - 1)
        use_band = self.opts["mesh_band"] if band is None else band
        if not use_band or n < 4 * BAND_COARSEN:
            return self._sdf_nodes(np.arange(n), n, h).reshape(n, n, n), self.lo.copy(), h
        from scipy.ndimage import map_coordinates

        k = BAND_COARSEN
        nc = (n - 1) // k + 1  # coarse nodes every k fine nodes (the last fine nodes may lie past the coarse grid)
        coarse = self._sdf_nodes(np.arange(nc) * k, n, h).reshape(nc, nc, nc)
        # upsampled coarse values at every fine node (nodes past the last coarse node: nearest, order 1 clamps)
        f = np.minimum(np.arange(n) / k, nc - 1)
        I, J, K = np.meshgrid(f, f, f, indexing="ij")
        vol = map_coordinates(coarse, [I.ravel(), J.ravel(), K.ravel()], order=1, mode="nearest").reshape(n, n, n)
        del I, J, K
        near = np.abs(vol) <= BAND_LIPSCHITZ * math.sqrt(3.0) * k * h
        idx = np.argwhere(near)
        if len(idx):
            pts = self.lo + idx * h
            vol[near] = self.query(pts, with_grad=False)[0]
        return vol, self.lo.copy(), h

    def _sdf_nodes(self, ticks: np.ndarray, n: int, h: float) -> np.ndarray:
        """SDF (len(ticks)^3,) at the nodes ``lo + (i, j, k) * h`` for i, j, k in ``ticks`` (C order)."""
        ax = [self.lo[a] + ticks * h for a in range(3)]
        X, Y, Z = np.meshgrid(*ax, indexing="ij")
        pts = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
        return self.query(pts, with_grad=False)[0]

    def extract_mesh(self, cell_mm: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Zero level set by marching cubes (VTK via pyvista): vertices (V, 3) m, faces (F, 3)."""
        if self.net is None:
            return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
        vol, origin, h = self.sdf_grid(cell_mm)
        cg = self._carve
        if cg is not None and self.opts["carve_crop"]:
            # cut away surface in carved space: intersection with the carved hull grown by one cell
            n = vol.shape[0]
            ax = origin[0] + np.arange(n) * h, origin[1] + np.arange(n) * h, origin[2] + np.arange(n) * h
            X, Y, Z = np.meshgrid(*ax, indexing="ij")
            hull = cg.sample(np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)).reshape(vol.shape)
            vol = np.maximum(vol, hull)
        return marching_cubes(vol, origin, h, keep_largest=self.opts["keep_largest"])

    def state_dict(self) -> dict[str, Any]:
        return {
            "opts": self.opts,
            "lo": self.lo,
            "size": self.size,
            "net": None if self.net is None else self.net.state_dict(),
        }


def largest_cluster(points: np.ndarray, voxel: float, min_share: float = 0.02, return_mask: bool = False) -> np.ndarray:
    """The points (N, 3) of the 26-connected clusters of ``voxel``-sized occupied cells (m) that hold at least
    ``min_share`` of the points: drops the few stray points (a segmentation leak on a finger, a wrong contact)
    that would blow up a convex hull, and keeps every substantial part of a sparsely sampled object.
    ``return_mask``: the (N,) boolean mask of the kept points instead."""
    from scipy import ndimage

    P = np.asarray(points, np.float64).reshape(-1, 3)
    if len(P) == 0 or voxel <= 0:
        return np.ones(len(P), bool) if return_mask else P
    ijk = np.floor((P - P.min(0)) / voxel).astype(np.int64)
    occ = np.zeros(ijk.max(0) + 1, bool)
    occ[tuple(ijk.T)] = True
    lab, n = ndimage.label(occ, structure=np.ones((3, 3, 3)))
    if n <= 1:
        return np.ones(len(P), bool) if return_mask else P
    pl = lab[tuple(ijk.T)]
    share = np.bincount(pl, minlength=n + 1) / len(P)
    keep = share[pl] >= min_share
    return keep if return_mask else P[keep]


def marching_cubes(
    volume: np.ndarray, origin: np.ndarray, spacing: float, level: float = 0.0, keep_largest: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Triangle mesh of ``volume == level`` (volume indexed [i, j, k] = x, y, z) with pyvista/VTK."""
    import pyvista as pv

    V = np.asarray(volume, np.float64)
    if V.min() > level or V.max() < level:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    grid = pv.ImageData(dimensions=V.shape, spacing=(spacing,) * 3, origin=tuple(np.asarray(origin, float)))
    grid.point_data["sdf"] = V.ravel(order="F")
    mesh = grid.contour([level], scalars="sdf")
    if mesh.n_points == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    if keep_largest:
        mesh = mesh.connectivity(extraction_mode="largest")
    mesh = mesh.triangulate()
    faces = np.asarray(mesh.faces).reshape(-1, 4)[:, 1:].astype(np.int64)
    return np.asarray(mesh.points, np.float64), faces
