"""Global pose initialisation of a known object (no pose prior) and re-localisation after loss.

A user has the object mesh (object frame, metres) but not its pose. :func:`global_register`
returns ranked hypotheses of ``T_world_object`` for the **first** frame of ``frames`` from:

1. **Vision** (when the first ``n_frames`` frames hold >= ``min_vision_points`` finite points):
   the world-frame vision points are accumulated and voxel-downsampled; Open3D FPFH features of
   that cloud and of area-weighted model surface samples are matched by a seeded RANSAC on
   nearest-feature correspondences (Open3D's ``registration_ransac_based_on_feature_matching``
   is not repeatable even when seeded, isl-org/Open3D#7475; same edge-length check) run
   ``ransac_seeds`` times, and by ``registration_fgr_based_on_feature_matching``; principal-axis
   alignments (4 proper flips) are cheap extra starts, and the best two refined hypotheses are
   also tried turned by every 45 deg (``turns`` = 8) about each principal axis of the model:
   near-symmetric shapes fit a partial view almost as well turned (a mug's spin with the handle
   elsewhere, a box's flips; with 180 deg only, the mug's first pose was 4 mm ADD-S off in 5 of 6
   YCB trials, `vtrack bench globalreg`). Every start is
   refined by robust (Tukey) point-to-plane ICP
   of the scene onto the model (the scene is a partial view, so scene -> model is the direction
   in which every point has a true partner).
2. **Touch only** (few or no vision points, e.g. a hand hides the object): ``n_rotations``
   seeded uniform rotations; for each, the translation that puts the contacts on the surface is
   solved by a few Gauss-Newton steps on the SDF (all rotations batched), then the best are
   refined with point-to-plane ICP of contacts onto the model. **Limits**: 3-5 contacts seldom
   fix all 6 DoF (e.g. a parallel grasp on a can leaves rotation about the finger axis and the
   height free); the hypotheses are then "consistent with touch", not "the pose". The ranking
   uses contact distance, normal agreement and free-gel non-penetration only.

Verification (all hypotheses, both paths) uses an SDF of the mesh
(:meth:`~vtrack.tracking.sdf_grid.SDFGrid.from_arrays`, negative inside) in the object frame:

- vision fitness: fraction of vision points with ``|sdf| < inlier_dist``; RMSE of those (m);
- contact residual: median ``|sdf|`` of touch points (m);
- normal agreement: mean cosine between the measured outward normals (rotated to the object
  frame) and the SDF gradient direction, in [-1, 1];
- penetration: mean depth (m) by which free-gel points and touch points lie inside the object
  (beyond ``free_margin`` / ``contact_tolerance``).

With vision (the vision path) touch only vets gross inconsistency: ``sigma_touch_vision`` (3 mm) and no
normal term, because contacts from tactile images lie ~0.5 mm off the surface and their normals are
poor (see :class:`GlobalRegOptions`); the touch-only path keeps ``sigma_touch`` and the normals.

``score = (w_vision * fitness + w_touch * touch_term + w_free * free_term) / (active weights)``
with ``touch_term = mean(exp(-0.5 (sdf/sigma_touch)^2) * (0.5 + 0.5 max(0, cos)))`` and
``free_term`` the fraction of free points that do not penetrate. It lies in [0, 1]; 0 without data.

Symmetric objects (``symmetric=True``, e.g. a can): hypotheses that are equivalent under the
symmetry (ADD-S between them below ``distinct_frac * diameter``) are merged, keeping the best
scored, so the list holds only genuinely different poses (e.g. upside down). Without the flag,
hypotheses are compared with ADD and poses that differ by a rotation about an axis stay
separate; equivalent ones then score alike and are ranked by score, ties by vision fitness.

Determinism: all sampling uses numpy generators seeded from ``options.seed`` (FGR is
deterministic); the same inputs and seed give the same hypotheses.

Measured (``OMP_NUM_THREADS=1 .venv/bin/python data_tools/globalreg_bench.py --seeds 10``, one
synthetic view, 1 mm noise, 10 % outliers, 4 contacts): best-hypothesis success (< 5 mm) soup
can 10/10 (ADD-S), mustard 8/10 (ADD; 9/10 within the top 5), mug 6/10 (ADD; 8/10 top 5; the
handle is often hidden); median CPU time to first pose 0.53 / 0.90 / 0.67 s (incl. SDF and
features of the 16k-face mesh; pass the tracker's ``grid`` to save the SDF build).

Ground truth is never an input: the only inputs are the mesh and the observations.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from vtrack.errors import InputError
from vtrack.geometry import se3
from vtrack.tracking.frame import TrackingFrame, sanitize
from vtrack.tracking.sdf_grid import SDFGrid


@dataclass
class GlobalRegOptions:
    """Tuning of :func:`global_register` (metres, radians, seconds)."""

    seed: int = 0
    n_frames: int = 3  #: first frames whose observations are accumulated (object ~still)
    voxel: float | None = None  #: feature voxel, m; None: diameter / 22 clipped to [3, 8] mm
    n_model_points: int = 6000  #: model surface samples (features use the voxel-downsampled set)
    max_vision_points: int = 4000  #: per-frame budget after NaN removal
    min_vision_points: int = 30  #: below this (after downsampling) the touch-only path is used
    ransac_seeds: int = 3  #: RANSAC runs with different seeds
    ransac_max_iter: int = 6000  #: samples per RANSAC run
    use_fgr: bool = True
    use_pca: bool = True
    flips: int = 2  #: best distinct hypotheses also tried turned about the model's 3 principal axes
    #: turns per principal axis tried on those (2: 180 deg only; 8: every 45 deg). Near-symmetric shapes fit a
    #: partial view almost equally well turned: a mug's spin (handle), a box's flips, a ball's seams
    turns: int = 8
    icp_iterations: int = 25
    top_k: int = 5  #: hypotheses returned
    distinct_frac: float = 0.1  #: hypotheses closer than this * diameter (ADD / ADD-S) are merged
    sdf_voxel: float = 0.003  #: verification SDF grid spacing, m (ignored if a grid is given)
    inlier_dist: float = 0.004  #: |sdf| below this counts as a vision inlier, m
    sigma_vision: float = 0.0015  #: vision point-to-surface tolerance in the score, m
    max_score_points: int = 1500  #: vision points used by the fine ICP stage and the score
    sigma_touch: float = 0.001  #: contact-to-surface tolerance in the score, m
    #: weight of the normal agreement in the touch term, in [0, 1]: ``(1 - w) + w * max(0, cos)``
    touch_normal_weight: float = 0.5
    #: with vision (the vision path), touch only vets gross inconsistency: contacts read from tactile images lie
    #: ~0.5 mm off the surface (median at the true pose on the YCB sessions, also from GT height maps) and their
    #: normals are poor (mean cos 0.55-0.7 at the true pose), so at ``sigma_touch`` / with normals they preferred
    #: a box's flip or a mug's wrong spin over the pose the depth fits better (`vtrack bench globalreg`)
    sigma_touch_vision: float = 0.003
    touch_normal_weight_vision: float = 0.0
    contact_tolerance: float = 0.002  #: touch points deeper than this inside count as penetration, m
    free_margin: float = 0.001  #: free gel points deeper than this inside penetrate, m
    w_vision: float = 1.0
    w_touch: float = 1.0
    w_free: float = 0.5
    n_rotations: int = 3000  #: touch-only rotation samples
    touch_refine: int = 20  #: touch-only candidates refined with ICP
    #: world camera origin, m (default: ``frames[0].info['camera_origin']``); orients scene normals
    camera_position: tuple[float, float, float] | None = None

    @classmethod
    def from_dict(cls, opts: dict) -> GlobalRegOptions:
        from vtrack.config import checked_fields

        return cls(**checked_fields(cls, opts, "global registration"))


@dataclass
class PoseHypothesis:
    """One candidate ``T_world_object`` (4x4, metres) with its verification terms."""

    T_world_object: np.ndarray
    score: float  #: combined score in [0, 1], higher is better
    vision_fitness: float = float("nan")  #: fraction of vision points on the surface
    vision_rmse: float = float("nan")  #: RMSE of the inliers' |sdf|, m
    contact_residual: float = float("nan")  #: median |sdf| of touch points, m
    normal_agreement: float = float("nan")  #: mean cos(measured normal, SDF gradient)
    penetration: float = float("nan")  #: mean depth of free/touch points inside the object, m
    source: str = ""  #: ransac | fgr | pca | touch | prior
    n_vision: int = 0
    n_touch: int = 0
    n_free: int = 0
    info: dict = field(default_factory=dict)


# ---------------------------------------------------------------------------------------------
# Model preparation (once per mesh; the Relocaliser keeps it)
# ---------------------------------------------------------------------------------------------


@dataclass
class _Model:
    points: np.ndarray  # (N, 3) object-frame surface samples, m
    normals: np.ndarray  # (N, 3) outward unit normals
    centre: np.ndarray  # bounding-box centre, m
    diameter: float  # bounding-box diagonal, m
    voxel: float
    grid: SDFGrid
    pcd: object  # o3d PointCloud with normals (dense, for ICP)
    down: object  # voxel-downsampled PointCloud with normals
    fpfh: object
    eval_points: np.ndarray  # (200, 3) for hypothesis distances


def _check_mesh(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces)
    if V.ndim != 2 or V.shape[1] != 3 or len(V) < 4:
        raise InputError(
            "mesh vertices must be a (V, 3) array with V >= 4",
            field="vertices",
            expected="(V>=4, 3) metres",
            got=V.shape,
        )
    if not np.isfinite(V).all():
        raise InputError("mesh vertices contain NaN/Inf", field="vertices", expected="finite metres")
    if F.ndim != 2 or F.shape[1] != 3 or len(F) < 4 or F.dtype.kind not in "iu":
        raise InputError(
            "a closed mesh needs >= 4 integer triangles",
            field="faces",
            expected="(F>=4, 3) vertex indices",
            got=F.shape,
        )
    if F.min() < 0 or F.max() >= len(V):
        raise InputError(
            "face index out of range",
            field="faces",
            expected=f"indices in [0, {len(V)})",
            got=(int(F.min()), int(F.max())),
        )
    return V, F.astype(np.int64)


def _prepare_model(vertices: np.ndarray, faces: np.ndarray, opts: GlobalRegOptions, grid: SDFGrid | None) -> _Model:
    import open3d as o3d

    from vtrack.eval.reconstruction import sample_surface

    V, F = _check_mesh(vertices, faces)
    lo, hi = V.min(0), V.max(0)
    diameter = float(np.linalg.norm(hi - lo))
    if not diameter > 1e-4:
        raise InputError(
            "mesh is degenerate (extent below 0.1 mm)",
            field="vertices",
            expected="an object of some size, metres",
            got=diameter,
        )
    if grid is None:
        grid = SDFGrid.from_arrays(V, F, voxel=max(opts.sdf_voxel, diameter / 100.0), padding=0.01)
    P, N = sample_surface(V, F, opts.n_model_points, seed=opts.seed)
    if len(P) == 0:
        raise InputError("mesh has no area", field="faces", expected="triangles of non-zero area")
    # Face normals are outward only for consistently wound meshes (the YCB mug is not): flip by
    # the SDF gradient, which is outward by construction.
    _, g = grid.query(P)
    flip = np.einsum("ij,ij->i", N, g) < 0
    N[flip] *= -1
    voxel = float(opts.voxel) if opts.voxel else float(np.clip(diameter / 22.0, 0.003, 0.008))
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P))
    pcd.normals = o3d.utility.Vector3dVector(N)
    down = pcd.voxel_down_sample(voxel)
    nd = np.asarray(down.normals)
    down.normals = o3d.utility.Vector3dVector(nd / np.maximum(np.linalg.norm(nd, axis=1, keepdims=True), 1e-12))
    fpfh = o3d.pipelines.registration.compute_fpfh_feature(
        down, o3d.geometry.KDTreeSearchParamHybrid(radius=5.0 * voxel, max_nn=100)
    )
    return _Model(
        points=P,
        normals=N,
        centre=0.5 * (lo + hi),
        diameter=diameter,
        voxel=voxel,
        grid=grid,
        pcd=pcd,
        down=down,
        fpfh=fpfh,
        eval_points=P[:: max(1, len(P) // 200)][:200],
    )


# ---------------------------------------------------------------------------------------------
# Observations
# ---------------------------------------------------------------------------------------------


@dataclass
class _Obs:
    vision: np.ndarray
    touch: np.ndarray
    normals: np.ndarray  # (M, 3), NaN rows where unknown
    free: np.ndarray
    camera: np.ndarray | None = None  # world camera origin, m, when known


def _gather(frames: list[TrackingFrame], opts: GlobalRegOptions) -> _Obs:
    if not isinstance(frames, (list, tuple)):
        raise InputError(
            "frames must be a list of TrackingFrame",
            field="frames",
            expected="list[TrackingFrame]",
            got=type(frames).__name__,
        )
    use = list(frames)[: max(1, int(opts.n_frames))]
    V, P, N, Fr = [], [], [], []
    for i, fr in enumerate(use):
        if not isinstance(fr, TrackingFrame):
            raise InputError(
                "frames must hold TrackingFrame objects",
                field=f"frames[{i}]",
                expected="TrackingFrame",
                got=type(fr).__name__,
            )
        s = sanitize(fr, max_vision=opts.max_vision_points, max_touch=200, max_free=200, seed=opts.seed + i)
        V.append(s.vision_points)
        P.append(s.touch_points)
        N.append(s.touch_normals)
        Fr.append(s.free_points)
    cat = lambda xs: np.concatenate(xs) if xs else np.zeros((0, 3))  # noqa: E731
    cam = opts.camera_position
    if cam is None and use and use[0].info.get("camera_origin") is not None:
        cam = use[0].info["camera_origin"]  # set by vtrack.tracking.frontend (world, m)
    cam_arr = None if cam is None else np.asarray(cam, dtype=np.float64).reshape(3)
    if cam_arr is not None and not np.isfinite(cam_arr).all():
        cam_arr = None
    return _Obs(cat(V), cat(P), cat(N), cat(Fr), cam_arr)


# ---------------------------------------------------------------------------------------------
# Verification
# ---------------------------------------------------------------------------------------------


def _evaluate(
    T_wo: np.ndarray, model: _Model, obs: _Obs, opts: GlobalRegOptions, source: str, vision: np.ndarray | None = None
) -> PoseHypothesis:
    """Score ``T_world_object`` against the observations (object-frame SDF lookups)."""
    T_ow = se3.invert(T_wo)
    R_ow = T_ow[:3, :3]
    Vp = obs.vision if vision is None else vision
    parts, wsum = 0.0, 0.0
    h = PoseHypothesis(
        T_world_object=T_wo, score=0.0, source=source, n_vision=len(Vp), n_touch=len(obs.touch), n_free=len(obs.free)
    )
    pen = []
    if len(Vp):
        d, _ = model.grid.query(se3.transform_points(T_ow, Vp), with_grad=False)
        inl = np.abs(d) < opts.inlier_dist
        h.vision_fitness = float(inl.mean())
        h.vision_rmse = float(np.sqrt(np.mean(d[inl] ** 2))) if inl.any() else float("nan")
        # soft inlier count: rewards the tighter of two near-symmetric fits (mustard front/back)
        parts += opts.w_vision * float(np.mean(np.exp(-0.5 * (d / opts.sigma_vision) ** 2)))
        wsum += opts.w_vision
    if len(obs.touch):
        d, g = model.grid.query(se3.transform_points(T_ow, obs.touch))
        h.contact_residual = float(np.median(np.abs(d)))
        n_o = obs.normals @ R_ow.T
        gn = g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-12)
        cos = np.einsum("ij,ij->i", n_o, gn)
        has_n = np.isfinite(cos)
        h.normal_agreement = float(cos[has_n].mean()) if has_n.any() else float("nan")
        wn = float(np.clip(opts.touch_normal_weight, 0.0, 1.0))
        cterm = np.where(has_n, (1.0 - wn) + wn * np.maximum(np.nan_to_num(cos), 0.0), 1.0)
        parts += opts.w_touch * float(np.mean(np.exp(-0.5 * (d / opts.sigma_touch) ** 2) * cterm))
        wsum += opts.w_touch
        pen.append(np.maximum(0.0, -d - opts.contact_tolerance))
    if len(obs.free):
        d, _ = model.grid.query(se3.transform_points(T_ow, obs.free), with_grad=False)
        inside = np.maximum(0.0, -d - opts.free_margin)
        parts += opts.w_free * float(np.mean(inside <= 0.0))
        wsum += opts.w_free
        pen.append(inside)
    h.penetration = float(np.concatenate(pen).mean()) if pen else float("nan")
    h.score = float(parts / wsum) if wsum > 0 else 0.0
    return h


def _batch_scores(R_wo: np.ndarray, t: np.ndarray, model: _Model, obs: _Obs, opts: GlobalRegOptions) -> np.ndarray:
    """:func:`_evaluate`'s score of K poses ``(R_wo (K, 3, 3), t (K, 3))`` at once (one grid lookup per term;
    the touch-only path ranks 3000 sampled rotations: 8-10 s one by one on the hidden baseball, ~1 s batched)."""
    K = len(R_wo)
    parts, wsum = np.zeros(K), 0.0

    def to_obj(P: np.ndarray) -> np.ndarray:  # (K, M, 3) object-frame points of world points P
        return np.einsum("kji,kmj->kmi", R_wo, P[None] - t[:, None])

    if len(obs.vision):
        d, _ = model.grid.query(to_obj(obs.vision).reshape(-1, 3), with_grad=False)
        parts += opts.w_vision * np.exp(-0.5 * (d.reshape(K, -1) / opts.sigma_vision) ** 2).mean(1)
        wsum += opts.w_vision
    if len(obs.touch):
        d, g = model.grid.query(to_obj(obs.touch).reshape(-1, 3))
        d, g = d.reshape(K, -1), g.reshape(K, -1, 3)
        n_o = np.einsum("kji,mj->kmi", R_wo, obs.normals)  # R^T n per pose
        gn = g / np.maximum(np.linalg.norm(g, axis=2, keepdims=True), 1e-12)
        cos = np.einsum("kmi,kmi->km", n_o, gn)
        wn = float(np.clip(opts.touch_normal_weight, 0.0, 1.0))
        cterm = np.where(np.isfinite(cos), (1.0 - wn) + wn * np.maximum(np.nan_to_num(cos), 0.0), 1.0)
        parts += opts.w_touch * (np.exp(-0.5 * (d / opts.sigma_touch) ** 2) * cterm).mean(1)
        wsum += opts.w_touch
    if len(obs.free):
        d, _ = model.grid.query(to_obj(obs.free).reshape(-1, 3), with_grad=False)
        parts += opts.w_free * (np.maximum(0.0, -d.reshape(K, -1) - opts.free_margin) <= 0.0).mean(1)
        wsum += opts.w_free
    return parts / wsum if wsum > 0 else parts


def _distinct(
    hyps: list[PoseHypothesis], model: _Model, symmetric: bool, opts: GlobalRegOptions
) -> list[PoseHypothesis]:
    from vtrack.eval.pose_metrics import add, add_s

    metric = add_s if symmetric else add
    tol = opts.distinct_frac * model.diameter
    hyps = sorted(hyps, key=lambda h: (-h.score, -np.nan_to_num(h.vision_fitness), h.source))
    out: list[PoseHypothesis] = []
    for h in hyps:
        if not np.all(np.isfinite(h.T_world_object)):
            continue
        if out:
            d = metric(
                np.stack([o.T_world_object for o in out]),
                np.repeat(h.T_world_object[None], len(out), 0),
                model.eval_points,
            )
            if np.any(d < tol):
                continue
        out.append(h)
        if len(out) >= opts.top_k:
            break
    return out


# ---------------------------------------------------------------------------------------------
# Vision path
# ---------------------------------------------------------------------------------------------


def _scene_cloud(points: np.ndarray, model: _Model, camera: np.ndarray | None):
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    down = pcd.voxel_down_sample(model.voxel)
    down.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2.0 * model.voxel, max_nn=30))
    # FPFH needs outward normals like the model's. With a known camera the visible surface faces
    # it; otherwise a partial view's centroid lies behind its surface, so point away from it.
    if camera is not None:
        down.orient_normals_towards_camera_location(camera)
    else:
        Q = np.asarray(down.points)
        Nn = np.asarray(down.normals)
        flip = np.einsum("ij,ij->i", Nn, Q - Q.mean(0)) < 0
        Nn[flip] *= -1
        down.normals = o3d.utility.Vector3dVector(Nn)
    fpfh = o3d.pipelines.registration.compute_fpfh_feature(
        down, o3d.geometry.KDTreeSearchParamHybrid(radius=5.0 * model.voxel, max_nn=100)
    )
    return down, fpfh


def _kabsch(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Batched least-squares rigid fit ``R a + t = b`` of (K, n, 3) point sets."""
    ca, cb = A.mean(1, keepdims=True), B.mean(1, keepdims=True)
    H = np.einsum("kni,knj->kij", A - ca, B - cb)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.einsum("kji,klj->kil", Vt, U)))
    D = np.repeat(np.eye(3)[None], len(A), 0)
    D[:, 2, 2] = d
    R = np.einsum("kji,kjl,kml->kim", Vt, D, U)  # V D U^T
    t = cb[:, 0] - np.einsum("kij,kj->ki", R, ca[:, 0])
    return R, t


def _feature_ransac(
    Q: np.ndarray,
    Fq: np.ndarray,
    M: np.ndarray,
    Fm: np.ndarray,
    rng: np.random.Generator,
    n_iter: int,
    dist: float,
    chunk: int = 2000,
) -> np.ndarray | None:
    """RANSAC on nearest-FPFH correspondences (scene Q -> model M); ``T_object_world`` or None.

    Samples of 3 correspondences whose pairwise lengths disagree by > 10 % are discarded (the
    edge-length check of Open3D); the hypothesis with most correspondences within ``dist`` (m) is
    re-fitted on its inliers.
    """
    from scipy.spatial import cKDTree

    if len(Q) < 3 or len(M) < 3:
        return None
    _, j = cKDTree(Fm.T).query(Fq.T)
    A, B = Q, M[j]
    best_n, best = 2, None
    for k0 in range(0, max(1, n_iter), chunk):
        idx = rng.integers(0, len(A), size=(min(chunk, n_iter - k0), 3))
        a, b = A[idx], B[idx]
        la = np.linalg.norm(a - np.roll(a, 1, axis=1), axis=2)
        lb = np.linalg.norm(b - np.roll(b, 1, axis=1), axis=2)
        ok = np.all((np.minimum(la, lb) >= 0.9 * np.maximum(la, lb)) & (la > 1e-6), axis=1)
        if not ok.any():
            continue
        R, t = _kabsch(a[ok], b[ok])
        res = np.einsum("kij,nj->kni", R, A) + t[:, None] - B[None]
        n_in = (np.einsum("kni,kni->kn", res, res) < dist * dist).sum(1)
        i = int(np.argmax(n_in))
        if n_in[i] > best_n:
            best_n, best = int(n_in[i]), (R[i], t[i])
    if best is None:
        return None
    inl = np.linalg.norm(A @ best[0].T + best[1] - B, axis=1) < dist
    R, t = _kabsch(A[inl][None], B[inl][None])
    return se3.make_transform(R[0], t[0])


def _pca_frames(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c = P.mean(0)
    _, U = np.linalg.eigh(np.cov((P - c).T))
    if np.linalg.det(U) < 0:
        U[:, 0] *= -1
    return c, U


def _vision_starts(scene_down, scene_fpfh, model: _Model, opts: GlobalRegOptions) -> list[tuple[np.ndarray, str]]:
    """Coarse ``T_object_world`` candidates (scene -> model)."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    v = model.voxel
    starts: list[tuple[np.ndarray, str]] = []
    # Open3D's feature RANSAC is not repeatable even with o3d.utility.random.seed (isl-org/Open3D
    # #7475, #6225), so the same hypothesise-and-verify loop runs here on numpy's seeded generator.
    Q = np.asarray(scene_down.points)
    rng = np.random.default_rng(opts.seed)
    for _ in range(max(0, opts.ransac_seeds)):
        T = _feature_ransac(
            Q,
            np.asarray(scene_fpfh.data),
            np.asarray(model.down.points),
            np.asarray(model.fpfh.data),
            rng,
            opts.ransac_max_iter,
            2.0 * v,
        )
        if T is not None:
            starts.append((T, "ransac"))
    if opts.use_fgr:
        o3d.utility.random.seed(int(opts.seed) * 7919 + 101)
        r = reg.registration_fgr_based_on_feature_matching(
            scene_down,
            model.down,
            scene_fpfh,
            model.fpfh,
            reg.FastGlobalRegistrationOption(maximum_correspondence_distance=1.5 * v),
        )
        starts.append((np.asarray(r.transformation).copy(), "fgr"))
    if opts.use_pca:
        # Principal axes of the partial view against the model's: rough but free; ICP does the rest.
        Q = np.asarray(scene_down.points)
        cs, Us = _pca_frames(Q)
        cm, Um = _pca_frames(model.points)
        for sx, sy in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
            D = np.diag([sx, sy, sx * sy])
            R = Um @ D @ Us.T
            starts.append((se3.make_transform(R, cm - R @ cs), "pca"))
    return starts


def _icp(source_pts: np.ndarray, model: _Model, T_init: np.ndarray, max_dists: tuple[float, ...], iterations: int):
    """Robust point-to-plane ICP of world points onto the model; returns ``T_object_world``."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(source_pts))
    T = T_init
    for md in max_dists:
        est = reg.TransformationEstimationPointToPlane(reg.TukeyLoss(k=md))
        r = reg.registration_icp(src, model.pcd, md, T, est, reg.ICPConvergenceCriteria(max_iteration=iterations))
        if np.all(np.isfinite(r.transformation)):
            T = np.asarray(r.transformation).copy()
    return T


def _vision_hypotheses(obs: _Obs, model: _Model, opts: GlobalRegOptions) -> list[PoseHypothesis]:
    scene_down, scene_fpfh = _scene_cloud(obs.vision, model, obs.camera)
    Q = np.asarray(scene_down.points)
    # voxel averages sit slightly inside curved surfaces: the fine stage and the score use raw points
    rng = np.random.default_rng(opts.seed)
    Qf = obs.vision[np.sort(rng.choice(len(obs.vision), min(len(obs.vision), opts.max_score_points), replace=False))]
    starts = _vision_starts(scene_down, scene_fpfh, model, opts)
    v = model.voxel
    out = []
    for T_ow, src in starts:
        T_ow = _icp(Q, model, T_ow, (2.0 * v,), opts.icp_iterations)
        T_ow = _icp(Qf, model, T_ow, (0.6 * v,), opts.icp_iterations)
        T_wo = se3.invert(T_ow)
        T_wo[:3, :3] = se3.orthonormalize(T_wo[:3, :3])
        out.append(_evaluate(T_wo, model, obs, opts, src, vision=Qf))
    if opts.flips > 0 and out:
        # Near-symmetric shapes (mustard front/back) fit a partial view almost equally well when
        # turned 180 deg about a principal axis; features then often find only one of the two.
        # Try those turns of the best distinct hypotheses so touch can decide between them.
        cm, Um = _pca_frames(model.points)
        best = _distinct(out, model, False, GlobalRegOptions(top_k=opts.flips, distinct_frac=opts.distinct_frac))
        n_turns = max(2, int(opts.turns))
        angles = [2.0 * np.pi * j / n_turns for j in range(1, n_turns)]
        for h in best:
            T_ow0 = se3.invert(h.T_world_object)
            for k, a in ((k, a) for k in range(3) for a in angles):
                R_flip = se3.so3_exp(a * Um[:, k])
                T_flip = se3.make_transform(R_flip, cm - R_flip @ cm)  # object frame, about the centroid
                T_ow = _icp(Q, model, T_flip @ T_ow0, (2.0 * v,), opts.icp_iterations)
                T_ow = _icp(Qf, model, T_ow, (0.6 * v,), opts.icp_iterations)
                T_wo = se3.invert(T_ow)
                T_wo[:3, :3] = se3.orthonormalize(T_wo[:3, :3])
                out.append(_evaluate(T_wo, model, obs, opts, h.source + "+flip", vision=Qf))
    return out


# ---------------------------------------------------------------------------------------------
# Touch-only path
# ---------------------------------------------------------------------------------------------


def _touch_hypotheses(obs: _Obs, model: _Model, opts: GlobalRegOptions) -> list[PoseHypothesis]:
    """Contacts (+ normals, free points) only: sampled rotations, SDF-solved translations."""
    from scipy.spatial.transform import Rotation

    P = obs.touch
    if len(P) == 0:
        return []
    K = max(1, int(opts.n_rotations))
    R_wo = Rotation.random(K, random_state=np.random.default_rng(opts.seed)).as_matrix()  # (K, 3, 3)
    # translation t so that R^T (p - t) lies on the surface. Start: model centre at the contacts'
    # centroid pushed inwards along the mean normal by a quarter of the diameter (fingers sit on the
    # outside of the object).
    nbar = np.nanmean(obs.normals, axis=0) if np.isfinite(obs.normals).any() else np.zeros(3)
    c0 = P.mean(0) - 0.25 * model.diameter * (nbar / max(np.linalg.norm(nbar), 1.0))
    t = c0[None] - np.einsum("kij,j->ki", R_wo, model.centre)
    for _ in range(8):
        q = np.einsum("kji,kmj->kmi", R_wo, P[None] - t[:, None])  # (K, M, 3) object frame
        d, g = model.grid.query(q.reshape(-1, 3))
        d, g = d.reshape(K, -1), g.reshape(K, -1, 3)
        gw = np.einsum("kij,kmj->kmi", R_wo, g)  # d(sdf)/dp in world; d(sdf)/dt = -gw
        # Gauss-Newton on sum d^2 over t (3 unknowns per rotation, batched)
        A = np.einsum("kmi,kmj->kij", gw, gw) + 1e-6 * np.eye(3)
        b = np.einsum("kmi,km->ki", gw, d)
        t = t + np.linalg.solve(A, b[..., None])[..., 0]
    T_all = np.repeat(np.eye(4)[None], K, 0)
    T_all[:, :3, :3] = R_wo
    T_all[:, :3, 3] = t
    scores = _batch_scores(R_wo, t, model, obs, opts)
    order = np.argsort(-scores, kind="stable")[: max(1, opts.touch_refine)]
    out = []
    for i in order:
        T_ow = se3.invert(T_all[i])
        if len(P) >= 3:
            T_ow = _icp(P, model, T_ow, (0.01, 0.003), opts.icp_iterations)
        T_wo = se3.invert(T_ow)
        T_wo[:3, :3] = se3.orthonormalize(T_wo[:3, :3])
        out.append(_evaluate(T_wo, model, obs, opts, "touch"))
    return out


# ---------------------------------------------------------------------------------------------
# Public API
# ---------------------------------------------------------------------------------------------


def _scoring(model: _Model, obs: _Obs, opts: GlobalRegOptions) -> tuple[bool, GlobalRegOptions]:
    """(vision path?, the options its hypotheses are scored with)."""
    n_scene = len(_down(obs.vision, model.voxel)) if len(obs.vision) else 0
    if n_scene < opts.min_vision_points:
        return False, opts
    return True, replace(opts, sigma_touch=opts.sigma_touch_vision, touch_normal_weight=opts.touch_normal_weight_vision)


def _run(model: _Model, obs: _Obs, symmetric: bool, opts: GlobalRegOptions) -> list[PoseHypothesis]:
    t0 = time.perf_counter()
    use_vision, sopts = _scoring(model, obs, opts)
    if use_vision:
        hyps = _vision_hypotheses(obs, model, sopts)
    else:
        hyps = _touch_hypotheses(obs, model, opts)
    out = _distinct(hyps, model, symmetric, opts)
    ms = 1000.0 * (time.perf_counter() - t0)
    for h in out:
        h.info["ms"] = ms
        h.info["n_candidates"] = len(hyps)
        h.info["voxel"] = model.voxel
    return out


def global_register(
    vertices: np.ndarray,
    faces: np.ndarray,
    frames: list[TrackingFrame],
    *,
    symmetric: bool = False,
    options: GlobalRegOptions | None = None,
    grid: SDFGrid | None = None,
) -> list[PoseHypothesis]:
    """Ranked ``T_world_object`` hypotheses (best first) for ``frames[0]`` without any pose prior.

    Args:
        vertices: (V, 3) mesh vertices, object frame, metres.
        faces: (F, 3) triangle indices (closed mesh, F >= 4).
        frames: observations, world frame, metres; the first ``options.n_frames`` are accumulated
            (the object must move little over them: ~1-2 mm blur is fine).
        symmetric: merge hypotheses equivalent under the object's symmetry (ADD-S).
        options: :class:`GlobalRegOptions`.
        grid: a ready object-frame SDF of the same mesh (e.g. the tracker's), saves ~0.1-0.5 s.

    Returns:
        Up to ``options.top_k`` distinct :class:`PoseHypothesis`, best first; empty when the frames
        hold no usable observation (no vision points, no contacts).

    Raises:
        InputError: malformed mesh (``vertices`` / ``faces``) or ``frames``.
    """
    opts = options or GlobalRegOptions()
    model = _prepare_model(vertices, faces, opts, grid)
    return _run(model, _gather(frames, opts), symmetric, opts)


class Relocaliser:
    """Re-localise a known object after the tracker reports ``lost``.

    Prepares the model once (features, SDF); :meth:`relocalise` re-runs the registration on the
    given recent frames (newest first), keeping only vision points within ``search_radius`` +
    object radius of the last good position (drops most hand/background clutter) and only
    hypotheses whose position moved less than ``search_radius`` from it.

    Args:
        vertices, faces: mesh, object frame, metres.
        symmetric: see :func:`global_register`.
        options: :class:`GlobalRegOptions` (``n_frames`` = how many recent frames are used).
        search_radius: m, how far the object may have gone since the last good pose.
        min_score: hypotheses scoring below this are rejected (None is returned).
        grid: optional ready SDF grid of the mesh.
    """

    def __init__(
        self,
        vertices: np.ndarray,
        faces: np.ndarray,
        *,
        symmetric: bool = False,
        options: GlobalRegOptions | None = None,
        search_radius: float = 0.05,
        min_score: float = 0.6,
        grid: SDFGrid | None = None,
    ) -> None:
        if not (np.isfinite(search_radius) and search_radius > 0):
            raise InputError(
                "search radius must be positive", field="search_radius", expected="> 0 m", got=search_radius
            )
        self.opts = options or GlobalRegOptions()
        self.model = _prepare_model(vertices, faces, self.opts, grid)
        self.symmetric = symmetric
        self.search_radius = float(search_radius)
        self.min_score = float(min_score)
        self.last_hypotheses: list[PoseHypothesis] = []

    def score(self, frames: list[TrackingFrame], T_world_object: np.ndarray, T_last_good: np.ndarray) -> float:
        """Verification score in [0, 1] of a pose (e.g. the tracker's) on the observations :meth:`relocalise`
        uses with the same ``T_last_good`` (vision points near it, voxel-downsampled), so poses compare."""
        obs = _gather(frames, self.opts)
        T = np.asarray(T_world_object, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            return 0.0
        if len(obs.vision):
            c = se3.transform_points(np.asarray(T_last_good, np.float64), self.model.centre[None])[0]
            reach = self.search_radius + 0.5 * self.model.diameter
            obs.vision = obs.vision[np.linalg.norm(obs.vision - c, axis=1) < reach]
        sopts = _scoring(self.model, obs, self.opts)[1]
        h = _evaluate(T, self.model, obs, sopts, "score", vision=_down(obs.vision, self.model.voxel))
        return float(h.score)

    def relocalise(self, frames: list[TrackingFrame], T_last_good: np.ndarray) -> PoseHypothesis | None:
        """Best hypothesis of ``T_world_object`` for ``frames[0]`` near ``T_last_good``, or None."""
        T_last = np.asarray(T_last_good, dtype=np.float64)
        if T_last.shape != (4, 4) or not np.all(np.isfinite(T_last)):
            raise InputError(
                "last good pose must be a finite 4x4 matrix",
                field="T_last_good",
                expected="(4, 4) T_world_object",
                got=T_last.shape,
            )
        obs = _gather(frames, self.opts)
        c_last = se3.transform_points(T_last, self.model.centre[None])[0]
        reach = self.search_radius + 0.5 * self.model.diameter
        if len(obs.vision):
            obs.vision = obs.vision[np.linalg.norm(obs.vision - c_last, axis=1) < reach]
        hyps = _run(self.model, obs, self.symmetric, self.opts)
        # the last good pose itself is a candidate too (the object may not have moved)
        sopts = _scoring(self.model, obs, self.opts)[1]
        hyps.append(
            _evaluate(T_last.copy(), self.model, obs, sopts, "prior", vision=_down(obs.vision, self.model.voxel))
        )
        near = [
            h
            for h in hyps
            if np.linalg.norm(se3.transform_points(h.T_world_object, self.model.centre[None])[0] - c_last)
            <= self.search_radius
            and h.score >= self.min_score
        ]
        near.sort(key=lambda h: (-h.score, h.source))
        self.last_hypotheses = near
        return near[0] if near else None


def _down(points: np.ndarray, voxel: float) -> np.ndarray:
    if len(points) == 0:
        return points
    import open3d as o3d

    return np.asarray(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points)).voxel_down_sample(voxel).points)


def random_pose(seed: int, centre: np.ndarray | None = None, spread: float = 0.03) -> np.ndarray:
    """A seeded uniform-rotation ``T_world_object`` with translation ``centre`` +- ``spread`` (m)."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    R = Rotation.random(random_state=rng).as_matrix()
    c = np.zeros(3) if centre is None else np.asarray(centre, dtype=np.float64)
    return se3.make_transform(R, c + rng.uniform(-spread, spread, 3))
