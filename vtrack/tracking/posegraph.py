"""SLAM back end: keyframe pose graph with registration and loop-closure edges (gtsam).

The front end (:class:`~vtrack.tracking.slam.SLAMTracker`) tracks each frame against the growing map and
drifts where the map is thin or a motion direction is unobservable. The back end re-optimises the
poses of its **keyframes** once the whole (or a longer part of the) session is known:

0. a spin the front end lost by more than the loop gate (1 rad) is re-localised first (:func:`relocalise_spin`:
   a search over the full rotation range against old keyframes, with a symmetry test), and the keyframes after
   the loss are re-posed; the odometry edges then come from these poses;
1. every keyframe keeps a subsample of its segmented depth points and their normals (world frame, m);
2. with the current keyframe poses ``X_k = T_world_object(t_k)`` their clouds are moved into the object
   frame; pairs of keyframes whose object-frame clouds overlap are registered by robust point-to-plane
   ICP (:func:`icp_point_to_plane`), which yields a relative-pose measurement with the information
   matrix of the fit (so a symmetric object's spin, which the clouds do not constrain, gets no weight);
3. a pose graph (gtsam Levenberg-Marquardt) holds odometry edges between consecutive keyframes (the
   front end's relative motion), these registration edges (robust Cauchy noise) and a gauge prior on
   the first keyframe; pairs further apart in time than ``loop_min_gap_s`` are **loop closures**: the
   object shows a face seen earlier. They pass stricter gates (overlap, inlier RMSE, agreement with the
   current estimate) before they enter the graph;
4. steps 2-3 repeat ``rounds`` times (the correspondences follow the corrected poses), then every frame's
   pose is corrected by interpolating the keyframes' corrections in time (:func:`interpolate_corrections`).

Perturbation conventions: a relative measurement ``Z_ij ~ X_i^-1 X_j``; gtsam's ``BetweenFactorPose3``
error is ``Log(Z^-1 X_i^-1 X_j)`` with tangent order ``[omega, v]`` (this module converts from the
tracker's ``[rho, phi]``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vtrack.errors import InputError, VtrackError
from vtrack.geometry import se3


@dataclass
class BackendOptions:
    """Keyframe selection and pose-graph refinement of SLAM (metres, radians, seconds)."""

    #: run the keyframe pose-graph refinement after tracking. Off by default: on the blind YCB benchmarks
    #: (2 s / 5 s sessions, no face seen twice) it changed the mean object-motion error by -0.03 mm unoccluded
    #: and +0.53 mm at medium occlusion; it pays off only when the object shows a face again (bench slam)
    refine: bool = False
    loop_closure: bool = True  #: add loop-closure edges (pairs further apart than loop_min_gap_s)
    kf_trans: float = 0.004  #: a new keyframe after this much motion of the object centre, m ...
    kf_rot: float = 0.07  #: ... or rotation, rad ...
    kf_max_gap_s: float = 0.3  #: ... or this much time, s
    kf_points: int = 500  #: depth points (with normals) a keyframe keeps
    kf_max: int = 2000  #: keyframes kept at most (~24 kB each; a long live run must not grow without bound)
    rounds: int = 3  #: register / solve rounds
    icp_iters: int = 10  #: point-to-plane ICP iterations per pair and round
    icp_dist: float = 0.005  #: correspondence distance, m
    sigma_point: float = 0.002  #: point-to-plane noise, m
    point_correlation: float = 100.0  #: registration-edge ICP information divided by this (correlated points)
    loop_point_correlation: float = 20.0  #: the same for loop edges (stronger: they carry the drift correction)
    min_overlap: float = 0.4  #: fraction of a cloud within icp_dist of the other (after ICP) for an edge
    max_rmse: float = 0.0025  #: inlier point-to-plane RMSE gate, m
    registration: bool = True  #: add keyframe-to-local-map registration edges
    map_window_s: float = 0.7  #: the registration map of a keyframe holds the keyframes within this time, s
    sigma_odom_trans: float = 0.0015  #: odometry edge noise per keyframe step, m
    sigma_odom_rot: float = 0.015  #: rad
    robust_k: float = 3.0  #: Cauchy width of registration / loop edges, in whitened units
    loop_min_gap_s: float = 2.0  #: pairs at least this far apart in time are loop-closure candidates
    loop_min_overlap: float = 0.5  #: stricter overlap gate for loop edges
    loop_max_trans: float = 0.03  #: a loop may correct the current relative estimate by at most this, m
    loop_max_rot: float = 1.0  #: rad (a 180 deg flip onto a similar face is rejected)
    #: > 0: a loop may also correct the current relative rotation by at most this many rad per second of the gap
    #: between its keyframes (the front end drifts gradually; 0: only ``loop_max_rot``). On the blind 5 s YCB
    #: sessions the loops that hurt corrected a mug's spin by 10-49 deg over a 2 s gap (the body's depth does not
    #: see the spin that the front end's colour term tracked), the loops that helped (the potted meat can's spin lag)
    #: by <= 5.4 deg: docs/benchmarks/slam_5s.md
    loop_max_rot_rate: float = 0.0
    loop_view_angle: float = 0.8  #: place recognition: object-frame view directions within this, rad
    loop_global: bool = True  #: FPFH + RANSAC when ICP from the current estimate fails
    loop_voxel: float = 0.004  #: FPFH voxel, m
    #: global re-localisation of a lost spin before the graph (:func:`relocalise_spin`): a keyframe's cloud is
    #: registered (a 1-D search about the axis of revolution + FPFH/RANSAC, then ICP) against old keyframes over
    #: the full rotation range; a correction larger than ``loop_max_rot`` that passes the gates and the symmetry
    #: test re-poses the keyframes after the old one (ramped in time) before the graph is built. Only with
    #: ``loop_closure``. Opt-in: it takes the 20 s mug session from 57.8 to 32.2 mm but closed 12 / 10 false turns
    #: on the 20 s synthetic mustard runs (none 3.2 -> 48.0 mm, medium 26.2 -> 39.5; `bench slam` 2026-11-26)
    spin_search: bool = False
    spin_search_every: int = 4  #: try every this many keyframes
    spin_search_candidates: int = 8  #: old keyframes tried per search (evenly spread in time)
    spin_search_steps: int = 12  #: ICP starts of the 1-D search about the axis of revolution (every 360/steps deg)
    spin_search_max_trans: float = 0.04  #: translation of an accepted correction at most, m
    #: symmetry test: the fit (share of the cloud within icp_dist of the old map, among the points within
    #: 3 icp_dist of it) at the correction must beat the fit at the correction turned by +-spin_search_probe
    #: about its own axis by this much; a surface that turns into itself (a can, a ball) fits as well there and
    #: closes no loop
    spin_search_peak: float = 0.06
    spin_search_probe: float = 0.5  #: rad
    spin_axis_max_rms: float = 0.006  #: axis of revolution accepted up to this trimmed RMS (normal lines), m
    min_keyframes: int = 3  #: fewer keyframes: nothing to refine
    object_radius: float = 0.05  #: m, scales rotation against translation in the observability test
    weak_ratio: float = 1e-3  #: registration directions weaker than this x the strongest are unobserved

    @classmethod
    def from_dict(cls, opts: dict) -> BackendOptions:
        from vtrack.config import checked_fields

        o = cls(**checked_fields(cls, opts, "SLAM back-end"))
        if o.rounds < 1 or o.icp_iters < 1 or o.kf_points < 10:
            raise InputError(
                "rounds and icp_iters must be >= 1 and kf_points >= 10",
                field="rounds/icp_iters/kf_points",
                got=(o.rounds, o.icp_iters, o.kf_points),
            )
        # noise levels, distances and gates enter as divisors or information: zero, negative or NaN would give
        # inf/NaN information deep inside the solver, so they are refused here by name
        positive = (
            "kf_trans kf_rot kf_max_gap_s icp_dist sigma_point point_correlation loop_point_correlation max_rmse "
            "map_window_s sigma_odom_trans sigma_odom_rot loop_max_trans loop_max_rot loop_view_angle loop_voxel "
            "object_radius weak_ratio spin_search_max_trans spin_search_probe spin_axis_max_rms"
        ).split()
        for name in positive:
            v = float(getattr(o, name))
            if not (np.isfinite(v) and v > 0):
                raise InputError("SLAM back-end option must be a positive number", field=name, expected="> 0", got=v)
        for name in (
            "robust_k",
            "loop_min_gap_s",
            "min_overlap",
            "loop_min_overlap",
            "spin_search_peak",
            "loop_max_rot_rate",
        ):
            v = float(getattr(o, name))
            if not (np.isfinite(v) and v >= 0):
                raise InputError("SLAM back-end option must be >= 0", field=name, expected=">= 0", got=v)
        if o.spin_search_every < 1 or o.spin_search_candidates < 1 or o.spin_search_steps < 1:
            raise InputError(
                "spin_search_every and spin_search_candidates must be >= 1",
                field="spin_search_every/spin_search_candidates",
                got=(o.spin_search_every, o.spin_search_candidates),
            )
        if o.kf_max < o.min_keyframes:
            raise InputError(
                "kf_max must be at least min_keyframes", field="kf_max", expected=f">= {o.min_keyframes}", got=o.kf_max
            )
        return o


@dataclass
class Keyframe:
    """A frame kept for the back end: time (s), the front end's pose, world-frame points + normals (m)."""

    t: float
    T: np.ndarray  #: T_world_object from the front end (4x4)
    points: np.ndarray  #: (N, 3) segmented depth points, world
    normals: np.ndarray  #: (N, 3) unit normals, world


@dataclass
class Edge:
    """Relative-pose measurement ``Z ~ X_i^-1 X_j`` with information ``info`` (6x6, tangent ``[rho, phi]``
    of the error ``Log(Z^-1 X_i^-1 X_j)``)."""

    i: int
    j: int
    Z: np.ndarray
    info: np.ndarray
    kind: str = "odometry"  #: odometry | registration | loop
    robust_k: float = 0.0  #: Cauchy width (0: Gaussian)
    stats: dict = field(default_factory=dict)


#: tangent [rho, phi] -> gtsam's [omega, v]
_TO_GTSAM = np.block([[np.zeros((3, 3)), np.eye(3)], [np.eye(3), np.zeros((3, 3))]])


def _import_gtsam():
    try:
        import gtsam
    except ImportError as e:
        # a missing optional package, not bad input: VtrackError (exit 1), naming what to install
        raise VtrackError(
            "the SLAM back end (--refine) needs gtsam: pip install 'vtrack[slam]' (gtsam==4.3.0), "
            f"or run without --refine ({e})"
        ) from e
    return gtsam


def optimise_pose_graph(
    poses: list[np.ndarray] | np.ndarray,
    edges: list[Edge],
    fixed: int = 0,
    sigma_fixed: float = 1e-6,
    max_iterations: int = 50,
) -> np.ndarray:
    """Poses (K, 4, 4) minimising the edges' (robust) errors, pose ``fixed`` held at its value (gauge).

    gtsam Levenberg-Marquardt over ``Pose3`` with ``BetweenFactorPose3`` per edge (Gaussian noise from the
    edge's information, wrapped in a Cauchy estimator when ``edge.robust_k > 0``).
    """
    gtsam = _import_gtsam()
    P = np.asarray(poses, np.float64)
    if P.ndim != 3 or P.shape[1:] != (4, 4) or not np.isfinite(P).all():
        raise InputError("pose graph needs finite (K, 4, 4) poses", field="poses", got=P.shape)
    K = len(P)
    graph = gtsam.NonlinearFactorGraph()
    init = gtsam.Values()
    for k in range(K):
        T = P[k].copy()
        T[:3, :3] = se3.orthonormalize(T[:3, :3])
        init.insert(k, gtsam.Pose3(T))
    gauge = gtsam.noiseModel.Isotropic.Sigma(6, sigma_fixed)
    graph.add(gtsam.PriorFactorPose3(fixed, gtsam.Pose3(init.atPose3(fixed)), gauge))
    for e in edges:
        if not (0 <= e.i < K and 0 <= e.j < K) or e.i == e.j:
            raise InputError("pose-graph edge between unknown poses", field="edge", got=(e.i, e.j), expected=f"< {K}")
        info = _TO_GTSAM @ (0.5 * (e.info + e.info.T)) @ _TO_GTSAM.T
        # a direction without information (a symmetric object's spin) gets a tiny one so the solve is defined
        w, V = np.linalg.eigh(info)
        info = (V * np.maximum(w, 1e-6 * max(w.max(), 1.0))) @ V.T
        noise = gtsam.noiseModel.Gaussian.Information(info)
        if e.robust_k > 0:
            noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(e.robust_k), noise)
        Z = e.Z.copy()
        Z[:3, :3] = se3.orthonormalize(Z[:3, :3])
        graph.add(gtsam.BetweenFactorPose3(e.i, e.j, gtsam.Pose3(Z), noise))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(int(max_iterations))
    result = gtsam.LevenbergMarquardtOptimizer(graph, init, params).optimize()
    out = np.stack([result.atPose3(k).matrix() for k in range(K)])
    if not np.isfinite(out).all():  # never hand NaN downstream
        return P.copy()
    return out


def icp_point_to_plane(
    src: np.ndarray,
    tgt: np.ndarray,
    tgt_normals: np.ndarray,
    tree: Any = None,
    iters: int = 10,
    max_dist: float = 0.005,
    sigma: float = 0.002,
    C0: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Robust (Huber) point-to-plane ICP: the rigid ``C`` with ``C @ src`` on the target surface.

    Returns ``(C, H, stats)``: ``H`` is the 6x6 information of a LEFT perturbation ``C <- exp(d) C``
    (``d = [rho, phi]``, target frame) at the solution, ``sum w J^T J / sigma^2``; ``stats`` has
    ``overlap`` (fraction of source points with a target neighbour within ``max_dist``), ``rmse``
    (inlier point-to-plane, m) and ``n``.
    """
    from scipy.spatial import cKDTree

    from vtrack.tracking.window import _exp

    tree = tree if tree is not None else cKDTree(tgt)
    C = np.eye(4) if C0 is None else np.asarray(C0, np.float64).copy()
    none = (np.zeros((6, 6)), np.zeros(6), {"overlap": 0.0, "rmse": float("inf"), "n": 0})
    if len(src) < 6 or len(tgt) < 6:
        return C, none[0], none[2]

    def linearise(C: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict]:
        X = src @ C[:3, :3].T + C[:3, 3]
        d, idx = tree.query(X, distance_upper_bound=max_dist)
        ok = np.isfinite(d)
        if ok.sum() < 6:
            return none[0], none[1], {"overlap": float(ok.mean()), "rmse": float("inf"), "n": int(ok.sum())}
        x, n = X[ok], tgt_normals[idx[ok]]
        r = np.einsum("ij,ij->i", x - tgt[idx[ok]], n)
        J = np.concatenate([n, np.cross(x, n)], axis=1)  # d r / d [rho, phi] of x <- exp(d) x
        a = np.abs(r) / sigma
        w = np.where(a <= 1.5, 1.0, 1.5 / np.maximum(a, 1e-12)) / sigma**2  # Huber at 1.5 sigma
        st = {"overlap": float(ok.mean()), "rmse": float(np.sqrt(np.mean(r * r))), "n": int(ok.sum())}
        return (J * w[:, None]).T @ J, J.T @ (w * r), st

    H, g, stats = linearise(C)
    for _ in range(iters):
        if stats["n"] < 6:
            break
        delta = -np.linalg.solve(H + (1e-9 * np.trace(H) + 1e-12) * np.eye(6), g)
        C = _exp(delta) @ C
        H, g, stats = linearise(C)  # information at the new estimate
        if np.linalg.norm(delta[:3]) < 1e-6 and np.linalg.norm(delta[3:]) < 1e-5:
            break
    return C, H, stats


def _relative(T_a: np.ndarray, T_b: np.ndarray) -> np.ndarray:
    return se3.invert(T_a) @ T_b


def _fpfh(P: np.ndarray, N: np.ndarray, voxel: float):
    """Voxel-downsampled points (M, 3) and their FPFH features (33, M) (Open3D)."""
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P))
    pc.normals = o3d.utility.Vector3dVector(N)
    d = pc.voxel_down_sample(voxel)
    f = o3d.pipelines.registration.compute_fpfh_feature(d, o3d.geometry.KDTreeSearchParamHybrid(5 * voxel, 100))
    return np.asarray(d.points), np.asarray(f.data)


def _observable(C: np.ndarray, H: np.ndarray, o: BackendOptions) -> np.ndarray:
    """``C`` without its component along directions the registration does not observe.

    Rotation is scaled by ``object_radius`` so both blocks are in metres; eigen-directions of ``H`` weaker than
    ``weak_ratio`` x the strongest (a can's or ball's spin, sliding along a plane) keep the current estimate:
    a registration that found an arbitrary spin must not carry it, even weakly, into the graph (with a large
    spin residual the rotation log couples it into the observed tilt: 2.5 deg of tilt on the synthetic can).
    """
    from vtrack.tracking.window import _exp, _log

    s = np.array([1.0] * 3 + [o.object_radius] * 3)
    w, V = np.linalg.eigh(H / np.outer(s, s))
    weak = V[:, w < o.weak_ratio * max(w.max(), 1e-30)]
    xi = _log(C) * s
    xi = xi - weak @ (weak.T @ xi)
    return _exp(xi / s)


def _edge(i: int, j: int, C: np.ndarray, H: np.ndarray, X: np.ndarray, o: BackendOptions, kind: str, st: dict) -> Edge:
    """Edge ``Z = X_i'^-1 X_j`` from the correction ``C`` that moved keyframe ``i``'s object-frame cloud onto
    a map expressed with the current poses (``X_i' = X_i C^-1``, only its observable part); ``H`` is the
    information of a left perturbation of ``C``, carried to the error ``Log(Z^-1 X_i^-1 X_j)``."""
    Z = _observable(C, H, o) @ _relative(X[i], X[j])
    from vtrack.tracking.window import _adjoint  # one adjoint for [rho, phi] twists

    AdZ = _adjoint(Z)
    corr = o.loop_point_correlation if kind == "loop" else o.point_correlation
    info = AdZ.T @ (H / max(corr, 1.0)) @ AdZ
    return Edge(i, j, Z, info, kind=kind, robust_k=o.robust_k, stats=st)


def registration_edges(
    keyframes: list[Keyframe], X: np.ndarray, o: BackendOptions, loops: bool
) -> tuple[list[Edge], dict]:
    """Registration and loop-closure edges at the current keyframe poses ``X`` (K, 4, 4).

    - **registration**: keyframe ``i``'s cloud against the map of the other keyframes within
      ``loop_min_gap_s`` (a map nearly covers the view, so ICP is not biased by the partial overlap of
      two single views, which under-estimated their relative rotation by up to 18 mrad in the synthetic
      test); the edge goes to the map keyframe holding most of the matches;
    - **loop** (``loops``): place recognition of a face seen at least ``loop_min_gap_s`` earlier: the old
      keyframes whose object-frame view direction (centroid of the cloud from the object origin) is within
      ``loop_view_angle`` of ``i``'s; their local map (``j`` and its neighbours) is registered by ICP from
      the current estimate and, if that fails the gates, by FPFH + seeded RANSAC then ICP (a drifted spin
      is beyond ICP's basin). A loop passes stricter gates (overlap, inlier RMSE, bounded correction);
      a symmetric object's spin gets no weight through the ICP information.
    """
    from scipy.spatial import cKDTree

    from vtrack.tracking.globalreg import _feature_ransac

    K = len(keyframes)
    Xinv = se3.invert(X)
    Q = [se3.transform_points(Xinv[k], kf.points) for k, kf in enumerate(keyframes)]
    Nq = [se3.rotate_vectors(Xinv[k], kf.normals) for k, kf in enumerate(keyframes)]
    times = np.array([kf.t for kf in keyframes])
    view = np.stack([q.mean(0) / max(np.linalg.norm(q.mean(0)), 1e-9) if len(q) else np.zeros(3) for q in Q])
    edges: list[Edge] = []
    rep = {"registration": 0, "loop": 0, "loop_rejected": 0, "rejected": 0, "loop_candidates": 0}
    feats: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for i in range(K):
        if len(Q[i]) < 10:
            continue
        dt = times - times[i]
        near = [j for j in range(K) if j != i and abs(dt[j]) <= o.map_window_s and len(Q[j])]
        if near and i > 0 and o.registration:
            M = np.concatenate([Q[j] for j in near])
            MN = np.concatenate([Nq[j] for j in near])
            owner = np.concatenate([np.full(len(Q[j]), j) for j in near])
            tree = cKDTree(M)
            C, H, st = icp_point_to_plane(Q[i], M, MN, tree, o.icp_iters, o.icp_dist, o.sigma_point)
            if st["overlap"] >= o.min_overlap and st["rmse"] <= o.max_rmse:
                _, idx = tree.query(Q[i] @ C[:3, :3].T + C[:3, 3], distance_upper_bound=o.icp_dist)
                hit = owner[idx[idx < len(M)]]
                j = int(np.bincount(hit).argmax()) if len(hit) else near[0]
                edges.append(_edge(i, j, C, H, X, o, "registration", st))
                rep["registration"] += 1
            else:
                rep["rejected"] += 1
        if not loops:
            continue
        old = [j for j in range(K) if dt[j] <= -o.loop_min_gap_s and len(Q[j])]
        if not old:
            continue
        cosang = view[old] @ view[i]
        j = old[int(np.argmax(cosang))]
        if cosang.max() < np.cos(o.loop_view_angle):
            continue
        rep["loop_candidates"] += 1
        sub = [k for k in (j - 1, j, j + 1) if 0 <= k < K and times[i] - times[k] >= o.loop_min_gap_s]
        M = np.concatenate([Q[k] for k in sub])
        MN = np.concatenate([Nq[k] for k in sub])
        tree = cKDTree(M)
        C, H, st = icp_point_to_plane(Q[i], M, MN, tree, o.icp_iters, o.icp_dist, o.sigma_point)
        good = st["overlap"] >= o.loop_min_overlap and st["rmse"] <= o.max_rmse
        if not good and o.loop_global:
            # global alignment: FPFH correspondences + seeded RANSAC (reproducible), refined by ICP
            if i not in feats:
                feats[i] = _fpfh(Q[i], Nq[i], o.loop_voxel)
            key = -1 - j
            if key not in feats:
                feats[key] = _fpfh(M, MN, o.loop_voxel)
            (Ps, Fs), (Pm, Fm) = feats[i], feats[key]
            T0 = _feature_ransac(Ps, Fs, Pm, Fm, np.random.default_rng(1000 * i + j), 3000, 1.5 * o.loop_voxel)
            if T0 is not None:
                C2, H2, st2 = icp_point_to_plane(Q[i], M, MN, tree, o.icp_iters, o.icp_dist, o.sigma_point, C0=T0)
                if st2["overlap"] >= o.loop_min_overlap and st2["rmse"] <= o.max_rmse:
                    C, H, st, good = C2, H2, st2, True
        if not good:
            continue
        max_rot = o.loop_max_rot
        if o.loop_max_rot_rate > 0:  # bounded by the drift the front end can have built up over the gap
            max_rot = min(max_rot, o.loop_max_rot_rate * float(times[i] - times[j]))
        if np.linalg.norm(C[:3, 3]) > o.loop_max_trans or float(se3.rotation_angle(C)) > max_rot:
            # a false match on a symmetric or repetitive surface usually needs a large jump
            rep["loop_rejected"] += 1
            continue
        edges.append(_edge(i, j, C, H, X, o, "loop", st))
        rep["loop"] += 1
    return edges, rep


def revolution_axis(
    points: np.ndarray, normals: np.ndarray, max_points: int = 800, n_dirs: int = 150, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, float] | None:
    """The axis a surface of revolution would have, from points (N, 3) and unit normals (N, 3), m: ``(c, a,
    rms)`` = a point of the axis, its unit direction and the trimmed RMS (best 80 %) distance of the normal lines
    to it, m (every normal line of a surface of revolution meets its axis; a handle's do not, hence the trim).
    Direction search as :func:`vtrack.fusion.symmetry.fit_revolution`'s, without its profile (the search needs
    the axis only, at ~20 ms). None with fewer than 50 points with a normal."""
    from vtrack.fusion.symmetry import _axis_point, _fibonacci_hemisphere, _trimmed_rms

    P = np.asarray(points, np.float64).reshape(-1, 3)
    N = np.asarray(normals, np.float64).reshape(-1, 3)
    ok = (np.linalg.norm(N, axis=1) > 0.5) & np.isfinite(P).all(1)
    P, N = P[ok], N[ok]
    if len(P) < 50:
        return None
    rng = np.random.default_rng(seed)
    if len(P) > max_points:
        sel = rng.choice(len(P), max_points, replace=False)
        P, N = P[sel], N[sel]
    ref = P.mean(0)
    dirs = _fibonacci_hemisphere(n_dirs)
    fits = [_axis_point(P, N, a, ref) for a in dirs]
    errs = np.array([_trimmed_rms(r) for _, r in fits])
    k = int(np.argmin(errs))
    a, c, e = dirs[k], fits[k][0], float(errs[k])
    step = 0.1
    for _ in range(40):  # local refinement by shrinking random perturbations
        a2 = a + step * rng.normal(size=3)
        a2 /= np.linalg.norm(a2)
        c2, r2 = _axis_point(P, N, a2, ref)
        e2 = _trimmed_rms(r2)
        if e2 < e:
            a, c, e = a2, c2, e2
        else:
            step *= 0.9
    return c, a, e


def _fit_share(src: np.ndarray, C: np.ndarray, tree: Any, dist: float, support: float = 0.0) -> float:
    """Share of ``src`` points (N, 3) moved by ``C`` that have a point of ``tree`` within ``dist`` (m); with
    ``support`` > 0, the share among the moved points within ``support`` (m) of the tree's points only (so a
    cloud turned off the edge of a partial map is not counted against the turn; 0 when none is)."""
    d, _ = tree.query(src @ C[:3, :3].T + C[:3, 3], distance_upper_bound=max(dist, support))
    if support <= 0:
        return float(np.mean(d <= dist))
    near = d <= support
    return float(np.mean(d[near] <= dist)) if near.sum() >= 10 else 0.0


def _turned(C: np.ndarray, angle: float, axis: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """``C`` followed by a further turn of ``angle`` rad about ``axis`` = (point, unit direction), or about
    ``C``'s own screw axis (through its fixed point) when None."""
    if axis is None:
        w = se3.so3_log(C[:3, :3])
        th = float(np.linalg.norm(w))
        a = w / max(th, 1e-12)
        # a point of the screw axis: (I - R) c = t minus its part along the axis (least squares)
        c = np.linalg.lstsq(np.eye(3) - C[:3, :3], C[:3, 3] - a * (a @ C[:3, 3]), rcond=None)[0]
    else:
        c, a = axis
    Rx = se3.so3_exp(a * angle)
    return se3.make_transform(Rx, c - Rx @ c) @ C


def relocalise_spin(keyframes: list[Keyframe], X: np.ndarray, o: BackendOptions) -> tuple[np.ndarray, dict]:
    """Keyframe poses with a lost spin re-localised (global place recognition over the full rotation range).

    A front end that lost an object's spin by more than ``loop_max_rot`` shows its faces at the wrong place in
    the object frame, so neither the view-direction candidates nor the correction gate of the loop edges can
    close that loop. Here every ``spin_search_every``-th keyframe ``i`` (in time order, at least
    ``loop_min_gap_s`` after the first) is registered against the local maps of up to
    ``spin_search_candidates`` old keyframes spread over the earlier run, by FPFH + seeded RANSAC then ICP
    (any rotation). A correction ``C`` (``X_i' = X_i C^-1``) is accepted when it is larger than
    ``loop_max_rot`` (smaller ones are the loop edges' job), moves the origin by at most
    ``spin_search_max_trans``, passes the loop gates (overlap, inlier RMSE) and the **symmetry test**: the
    cloud must fit the old map at ``C`` better, by ``spin_search_peak`` of its points, than at ``C`` turned by
    ``+-spin_search_probe`` about its own axis (a can or a ball fits everywhere and is never corrected). The
    best accepted correction re-poses the keyframes after the old one ``j``: ramped linearly in time from
    none at ``j`` to all of it at ``i``, all of it after ``i`` (the front end tracks the relative motion after
    the loss, so its error is a constant object-frame offset). Returns the new poses and a report.
    """
    from scipy.spatial import cKDTree

    from vtrack.tracking.globalreg import _feature_ransac
    from vtrack.tracking.window import _exp, _log

    X = np.asarray(X, np.float64).copy()
    K = len(keyframes)
    times = np.array([kf.t for kf in keyframes])
    rep: dict[str, Any] = {"spin_searches": 0, "spin_relocalised": 0, "spin_rejected_symmetric": 0, "spin_fixes": []}
    if not (o.spin_search and o.loop_closure) or K < 4:  # a loop closure too: off with --no-loop-closure
        return X, rep
    allq = np.concatenate([se3.transform_points(se3.invert(X[k]), kf.points) for k, kf in enumerate(keyframes)])
    alln = np.concatenate([se3.rotate_vectors(se3.invert(X[k]), kf.normals) for k, kf in enumerate(keyframes)])
    fit = revolution_axis(allq, alln, max_points=1500)
    # the axis the clouds revolve about best: the spin search turns about it, and the symmetry test too (a
    # correction is believed only if the cloud fits worse once turned about it: the surface is not a surface of
    # revolution there); a fit worse than spin_axis_max_rms means no such axis: C's own axis is probed
    axis = None if fit is None or fit[2] > o.spin_axis_max_rms else (fit[0], fit[1])
    i = 0
    while i < K:
        if times[i] - times[0] < o.loop_min_gap_s or len(keyframes[i].points) < 30:
            i += 1
            continue
        old = [j for j in range(K) if times[i] - times[j] >= o.loop_min_gap_s and len(keyframes[j].points) >= 30]
        if not old:
            i += 1
            continue
        rep["spin_searches"] += 1
        pick = np.unique(np.linspace(0, len(old) - 1, min(o.spin_search_candidates, len(old))).round().astype(int))
        Xinv_i = se3.invert(X[i])
        Qi = se3.transform_points(Xinv_i, keyframes[i].points)
        Ni = se3.rotate_vectors(Xinv_i, keyframes[i].normals)
        Pi, Fi = _fpfh(Qi, Ni, o.loop_voxel)
        # the spin a front end loses is the one about the object's (near) symmetry axis: a 1-D search about the
        # axis of revolution the earlier clouds fit best, beside the feature-based hypothesis
        starts = []
        if axis is not None:
            c, a = axis
            for th in np.arange(1, o.spin_search_steps) * (2 * np.pi / o.spin_search_steps):
                R = se3.so3_exp(a * th)
                starts.append(se3.make_transform(R, c - R @ c))
        best = None
        for j in (old[k] for k in pick):
            sub = [k for k in (j - 1, j, j + 1) if 0 <= k < K and times[i] - times[k] >= o.loop_min_gap_s]
            M = np.concatenate([se3.transform_points(se3.invert(X[k]), keyframes[k].points) for k in sub])
            MN = np.concatenate([se3.rotate_vectors(se3.invert(X[k]), keyframes[k].normals) for k in sub])
            Pm, Fm = _fpfh(M, MN, o.loop_voxel)
            T0 = _feature_ransac(Pi, Fi, Pm, Fm, np.random.default_rng(7919 * i + j), 3000, 1.5 * o.loop_voxel)
            tree = cKDTree(M)
            found = None
            for S0 in ([T0] if T0 is not None else []) + starts:
                C, _, st = icp_point_to_plane(Qi, M, MN, tree, o.icp_iters, o.icp_dist, o.sigma_point, C0=S0)
                if st["overlap"] < o.loop_min_overlap or st["rmse"] > o.max_rmse:
                    continue
                if found is None or st["overlap"] > found[1]["overlap"]:
                    found = (C, st)
            if found is None:
                continue
            C, st = found
            if float(se3.rotation_angle(C)) <= o.loop_max_rot or np.linalg.norm(C[:3, 3]) > o.spin_search_max_trans:
                continue
            f0 = _fit_share(Qi, C, tree, o.icp_dist)
            # the symmetry test counts only points that land on (near) the old map after the turn: a partial map
            # would otherwise make any surface look peaked at the correction
            sup = 3.0 * o.icp_dist
            g0 = _fit_share(Qi, C, tree, o.icp_dist, sup)
            # probe about the axis the matched pair revolves about (the old map and the corrected cloud): a
            # consistent pair gives the object's own axis even when the drifted run as a whole is smeared
            pair = revolution_axis(
                np.concatenate([M, Qi @ C[:3, :3].T + C[:3, 3]]),
                np.concatenate([MN, Ni @ C[:3, :3].T]),
                max_points=1000,
                n_dirs=100,
            )
            pax = None if pair is None or pair[2] > o.spin_axis_max_rms else (pair[0], pair[1])
            g_side = max(
                _fit_share(Qi, _turned(C, s * o.spin_search_probe, pax), tree, o.icp_dist, sup) for s in (-1, 1)
            )
            if g0 < g_side + o.spin_search_peak:
                rep["spin_rejected_symmetric"] += 1
                continue
            # the most distinctive match wins (what the symmetric part cannot explain), not the best-covered one
            if best is None or g0 - g_side > best[3]:
                best = (f0, j, C, g0 - g_side)
        if best is None:
            i += o.spin_search_every
            continue
        _, j, C, peak = best
        e = _log(se3.invert(C))  # object-frame correction of keyframe i: X_i' = X_i C^-1
        for k in range(j + 1, K):
            a = min(1.0, (times[k] - times[j]) / max(times[i] - times[j], 1e-9))
            X[k] = X[k] @ _exp(a * e)
        rep["spin_relocalised"] += 1
        rep["spin_fixes"].append(
            {
                "i": i,
                "j": j,
                "deg": float(np.degrees(se3.rotation_angle(C))),
                "fit": round(float(best[0]), 3),
                "peak": round(float(peak), 3),
            }
        )
        i += o.spin_search_every
    return X, rep


def odometry_edges(X_front: np.ndarray, o: BackendOptions) -> list[Edge]:
    """Consecutive-keyframe edges carrying the front end's relative motion."""
    sig = np.array([o.sigma_odom_trans] * 3 + [o.sigma_odom_rot] * 3)
    info = np.diag(1.0 / sig**2)
    return [Edge(k, k + 1, _relative(X_front[k], X_front[k + 1]), info) for k in range(len(X_front) - 1)]


def refine_keyframes(
    keyframes: list[Keyframe], options: BackendOptions | dict | None = None
) -> tuple[np.ndarray, dict]:
    """Refined keyframe poses (K, 4, 4) and a report (edges per kind, seconds, per-round corrections)."""
    o = options if isinstance(options, BackendOptions) else BackendOptions.from_dict(options or {})
    t0 = time.perf_counter()
    X0 = np.stack([kf.T for kf in keyframes]) if keyframes else np.zeros((0, 4, 4))
    rep: dict[str, Any] = {"keyframes": len(keyframes), "rounds": []}
    if len(keyframes) < o.min_keyframes:
        rep["seconds"] = time.perf_counter() - t0
        return X0.copy(), rep
    X, spin_rep = relocalise_spin(keyframes, X0, o)
    rep.update(spin_rep)
    # a re-localised spin is the new front end: odometry from the corrected poses
    odo = odometry_edges(X, o)
    for _ in range(o.rounds):
        reg, r = registration_edges(keyframes, X, o, loops=o.loop_closure)
        Xn = optimise_pose_graph(X, odo + reg, fixed=0)
        r["max_change_mm"] = float(np.max(np.linalg.norm(Xn[:, :3, 3] - X[:, :3, 3], axis=1)) * 1e3)
        rep["rounds"].append(r)
        X = Xn
    last = rep["rounds"][-1]
    rep.update(
        registration_edges=last["registration"],
        loop_edges=last["loop"],
        loop_rejected=last["loop_rejected"],
        loop_candidates=last["loop_candidates"],
    )
    rep["seconds"] = time.perf_counter() - t0
    return X, rep


def interpolate_corrections(
    kf_times: np.ndarray, X_old: np.ndarray, X_new: np.ndarray, times: np.ndarray, poses: np.ndarray
) -> np.ndarray:
    """Every frame's pose with the keyframes' corrections ``E_k = X_old^-1 X_new`` (object frame) applied,
    interpolated linearly in ``se(3)`` between the neighbouring keyframes (held beyond the ends)."""
    from vtrack.tracking.window import _exp, _log

    kt = np.asarray(kf_times, np.float64)
    if len(kt) == 0:
        return np.asarray(poses).copy()
    E = np.stack([_log(se3.invert(a) @ b) for a, b in zip(X_old, X_new, strict=True)])
    out = np.asarray(poses, np.float64).copy()
    for n, t in enumerate(np.asarray(times, np.float64)):
        k = int(np.searchsorted(kt, t))
        if k == 0:
            e = E[0]
        elif k >= len(kt):
            e = E[-1]
        else:
            a = (t - kt[k - 1]) / max(kt[k] - kt[k - 1], 1e-12)
            e = (1 - a) * E[k - 1] + a * E[k]
        out[n] = out[n] @ _exp(e)
    return out
