"""Box completion prior: a cloud whose surface is made of orthogonal plane families (a carton, a tin box) is
completed by its face-aligned bounding box.

The convex hull of a partly seen box cuts a diagonal across the unseen corner (half a box when two adjacent faces
are seen). When the normals cluster on three orthogonal directions and the points lie on the faces of the box
spanned by their extent along those directions, the box itself is the completion: its unseen faces are the planes
through the extreme seen points. The neural SDF takes the box only when the cameras did not see the volume it adds
empty (``NeuralSDFReconstructor.set_hull_prior``). Triggered by the observed data only (points, normals, free
space; object frame): nothing comes from a mesh or an object identity.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vtrack.errors import InputError


@dataclass
class Box:
    """Oriented box (object frame, metres): ``centre`` (3,), ``axes`` (3, 3) rows = unit face normals,
    ``half`` (3,) half extents; ``on_face`` and ``aligned``: share of the points within the tolerance of a face
    and share of the normals within the angle of an axis (the acceptance evidence)."""

    centre: np.ndarray
    axes: np.ndarray
    half: np.ndarray
    on_face: float
    aligned: float

    def sdf(self, points: np.ndarray) -> np.ndarray:
        """Exact signed distance (N,) m to the box, negative inside."""
        X = np.asarray(points, np.float64).reshape(-1, 3)
        if not np.isfinite(X).all():
            raise InputError("non-finite query points", field="points", expected="finite (N, 3) m", got="NaN/Inf")
        q = np.abs((X - self.centre) @ self.axes.T) - self.half
        outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
        inside = np.minimum(q.max(1), 0.0)
        return outside + inside


def _procrustes_frame(N: np.ndarray, R: np.ndarray, cos_tol: float, iters: int = 10) -> np.ndarray:
    """Refine the rotation ``R`` (rows = axes) so the unit normals ``N`` (M, 3) align with its signed axes."""
    for _ in range(iters):
        c = N @ R.T  # (M, 3) cosines to each axis
        a = np.abs(c).argmax(1)
        ca = c[np.arange(len(N)), a]
        ok = np.abs(ca) >= cos_tol
        if ok.sum() < 3:
            return R
        E = np.zeros((int(ok.sum()), 3))
        E[np.arange(len(E)), a[ok]] = np.sign(ca[ok])
        # R maps object -> box coordinates; want R n ~ e  =>  maximise trace(R sum n e^T)^T
        U, _, Vt = np.linalg.svd(E.T @ N[ok])
        D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
        R = U @ D @ Vt
    return R


def pca_normals(points: np.ndarray, k: int = 20) -> np.ndarray:
    """Unit normals (N, 3) of a cloud (N, 3) m by local PCA over the ``k`` nearest points (unsigned)."""
    from scipy.spatial import cKDTree

    P = np.asarray(points, np.float64).reshape(-1, 3)
    k = min(k, len(P))
    if k < 3:
        return np.zeros_like(P)
    _, idx = cKDTree(P).query(P, k)
    nb = P[idx] - P[idx].mean(1, keepdims=True)
    _, v = np.linalg.eigh(np.einsum("nki,nkj->nij", nb, nb))
    return v[:, :, 0]


def fit_box(
    points: np.ndarray,
    normals: np.ndarray | None = None,
    *,
    angle_deg: float = 15.0,
    face_tol: float = 0.003,
    min_aligned: float = 0.3,
    min_on_face: float = 0.2,
    min_faces: int = 3,
    min_face_share: float = 0.02,
    trim: float = 0.005,
    seed: int = 0,
) -> Box | None:
    """Fit a face-aligned box to an object-frame cloud; ``None`` when the cloud is not box-like.

    points (N, 3) m and normals (N, 3) (zero rows = unknown) in the object frame. ``normals=None`` (what the
    neural SDF uses: the fused observations' normals are ~25 deg off the true ones at the median on the YCB
    sessions) estimates them by local PCA (:func:`pca_normals`; thin the cloud to ~2 mm first). The frame comes
    from the normals (orthogonal Procrustes on their assignment to the nearest signed axis, started from the
    points' principal axes and random rotations); the extent along each axis is the points' ``trim`` and
    ``1 - trim`` quantiles (a few stray points do not grow the box). Accepted when >= ``min_aligned`` of the
    normals are within ``angle_deg`` of an axis, >= ``min_on_face`` of the points are within ``face_tol`` of a
    face, and >= ``min_faces`` faces (signed axes) each hold >= ``min_face_share`` of the points.
    """
    P = np.asarray(points, np.float64).reshape(-1, 3)
    if normals is None:
        P = P[np.isfinite(P).all(1)]
        normals = pca_normals(P)
    Nn = np.asarray(normals, np.float64).reshape(-1, 3)
    if len(P) != len(Nn):
        raise InputError("points and normals differ in length", field="normals", expected=len(P), got=len(Nn))
    fin = np.isfinite(P).all(1) & np.isfinite(Nn).all(1)
    P, Nn = P[fin], Nn[fin]
    ln = np.linalg.norm(Nn, axis=1)
    good = ln > 0.5
    if len(P) < 50 or good.sum() < 50:
        return None
    N = Nn[good] / ln[good, None]
    cos_tol = float(np.cos(np.radians(angle_deg)))
    rng = np.random.default_rng(seed)
    # starts: principal axes of the points, and random rotations (a cube's principal axes are arbitrary)
    C = P - P.mean(0)
    _, _, Vt = np.linalg.svd(C[rng.choice(len(C), min(len(C), 5000), replace=False)], full_matrices=False)
    starts = [Vt]
    for _ in range(6):
        Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        starts.append(Q)
    sub = N[rng.choice(len(N), min(len(N), 4000), replace=False)]
    best, best_score = None, -1.0
    for R0 in starts:
        if np.linalg.det(R0) < 0:
            R0 = R0 * np.array([[1.0], [1.0], [-1.0]])
        R = _procrustes_frame(sub, R0, cos_tol=float(np.cos(np.radians(2 * angle_deg))))
        R = _procrustes_frame(sub, R, cos_tol=cos_tol)
        score = float((np.abs(sub @ R.T).max(1) >= cos_tol).mean())
        if score > best_score:
            best, best_score = R, score
    R = best
    aligned = float((np.abs(N @ R.T).max(1) >= cos_tol).mean())
    if aligned < min_aligned:
        return None
    L = P @ R.T
    lo, hi = np.quantile(L, trim, axis=0), np.quantile(L, 1 - trim, axis=0)
    half = 0.5 * (hi - lo)
    if (half <= 0).any():
        return None
    cL = 0.5 * (lo + hi)
    # distance of each point to the nearest face plane, and which face
    dlo, dhi = np.abs(L - lo), np.abs(L - hi)
    d = np.minimum(dlo, dhi)
    ax = d.argmin(1)
    on = d[np.arange(len(L)), ax] <= face_tol
    on_face = float(on.mean())
    if on_face < min_on_face:
        return None
    side = dhi[np.arange(len(L)), ax] < dlo[np.arange(len(L)), ax]
    face = 2 * ax + side
    counts = np.bincount(face[on], minlength=6) / len(L)
    if int((counts >= min_face_share).sum()) < min_faces:
        return None
    return Box(centre=cL @ R, axes=R, half=half, on_face=on_face, aligned=aligned)
