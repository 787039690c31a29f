"""Rotational-symmetry shape prior: detect a surface of revolution in an observed cloud and complete it.

Where the camera never looked (the back of a ball, the far side of a can), the neural SDF falls back on its
prior. The convex hull of the observations cuts such a side flat (a ball seen from one side becomes a ball
with a flat back). Many grasped objects are surfaces of revolution (cans, balls, cups, bottles); when the
observed part is one, revolving its profile about the axis completes the unseen side.

Method (object frame, metres):

1. Axis: the normal line of every point of a surface of revolution meets the axis, i.e.
   ``n . (a x (p - c)) = 0`` for the axis direction ``a`` through ``c``. For a given ``a`` this is linear in
   ``c``; a search over directions (Fibonacci hemisphere, then a local refinement) keeps the direction whose
   trimmed RMS residual (m) is smallest. A sphere fits every direction through its centre, any is fine.
2. Profile: each point becomes ``(h, rho)`` = (height along the axis, distance to it); per height bin the
   radius is a quantile of ``rho`` (robust to a handle, which covers a small share of the angles), gaps are
   interpolated, the profile is median-filtered.
   Points facing the axis (the inner wall of a cup) are left out: the profile is the outer one.
3. Test: the revolved surface must pass through the observed side (points whose normal points away from the
   axis):
   the share of them within ``tol`` of it must reach ``min_inlier``; otherwise (a box, a banana, a mustard
   bottle) there is no symmetry prior.
4. SDF: the 2-D signed distance to the profile region in the (h, rho) half-plane (Euclidean distance
   transforms on a raster, mirrored about the axis), looked up for any 3-D point.

Only numpy / scipy; no torch, no open3d.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vtrack.errors import InputError


@dataclass
class Revolution:
    """A fitted surface of revolution (object frame, metres).

    centre (3,) a point of the axis; axis (3,) unit direction; h0 (m) height of the first profile bin;
    cell (m) raster cell of the (h, rho) plane; sdf2 ((nh, nr)) signed distance (m, negative inside) on the
    raster, rows = heights ``h0 + i * cell``, columns = rho ``j * cell``; inlier: share of the fitted points
    within the test tolerance of the surface; axis_rms (m): trimmed RMS of the normal-line residual.
    """

    centre: np.ndarray
    axis: np.ndarray
    h0: float
    cell: float
    sdf2: np.ndarray
    inlier: float
    axis_rms: float

    def sdf(self, points: np.ndarray) -> np.ndarray:
        """Signed distance (N,) m of object-frame points (N, 3) to the revolved solid (bilinear on the raster;
        outside the raster the distance to its border is added)."""
        X = np.asarray(points, np.float64).reshape(-1, 3)
        if not np.isfinite(X).all():
            raise InputError("non-finite query points", field="points", expected="finite (N, 3) m", got="NaN/Inf")
        X = X - self.centre
        h = X @ self.axis
        rho = np.linalg.norm(X - h[:, None] * self.axis, axis=1)
        nh, nr = self.sdf2.shape
        fi = (h - self.h0) / self.cell
        fj = rho / self.cell
        ci = np.clip(fi, 0, nh - 1)
        cj = np.clip(fj, 0, nr - 1)
        i0 = np.minimum(np.floor(ci).astype(np.int64), nh - 2)
        j0 = np.minimum(np.floor(cj).astype(np.int64), nr - 2)
        ti, tj = ci - i0, cj - j0
        S = self.sdf2
        v = (
            S[i0, j0] * (1 - ti) * (1 - tj)
            + S[i0 + 1, j0] * ti * (1 - tj)
            + S[i0, j0 + 1] * (1 - ti) * tj
            + S[i0 + 1, j0 + 1] * ti * tj
        )
        # beyond the raster the surface is farther still: add the distance to the raster's border
        out = np.hypot(fi - ci, fj - cj) * self.cell
        return v + out


def _fibonacci_hemisphere(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    z = i / n  # z in (0, 1]: one hemisphere (an axis and its opposite are the same)
    phi = np.pi * (1 + 5**0.5) * i
    r = np.sqrt(1 - z**2)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)


def _axis_point(P: np.ndarray, N: np.ndarray, a: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares axis point c (closest to ``ref`` along a) for direction a; residuals (m) per point."""
    A = np.cross(N, a)  # (n x a) . c = n . (a x p)
    b = np.einsum("ij,ij->i", N, np.cross(a, P))
    # c is free along a: fix it with a weak pull to ref (regularised normal equations)
    M = A.T @ A + 1e-6 * len(P) * np.eye(3)
    c = np.linalg.solve(M, A.T @ b + 1e-6 * len(P) * ref)
    c = c - ((c - ref) @ a) * a
    return c, A @ c - b


def pca_normals(points: np.ndarray, normals: np.ndarray, k: int = 40) -> np.ndarray:
    """Unit normals (N, 3) of a cloud (N, 3) m from the smallest principal direction of its ``k`` nearest
    neighbours, oriented like the given ``normals`` (N, 3) (rows of zeros: away from the centroid). The per-pixel
    depth normals of the frames are too noisy for the axis test (median 40 deg off on the benchmark sessions)."""
    from scipy.spatial import cKDTree

    P = np.asarray(points, np.float64).reshape(-1, 3)
    if len(P) < 4:
        return np.zeros_like(P)
    _, idx = cKDTree(P).query(P, k=min(k, len(P)))
    Q = P[idx] - P[idx].mean(1, keepdims=True)
    C = np.einsum("nki,nkj->nij", Q, Q)
    _, vec = np.linalg.eigh(C)
    n = vec[:, :, 0]
    ref = np.asarray(normals, np.float64).reshape(-1, 3)
    ref = np.where(np.linalg.norm(ref, axis=1, keepdims=True) > 0.5, ref, P - P.mean(0))
    return n * np.where(np.einsum("ij,ij->i", n, ref) < 0, -1.0, 1.0)[:, None]


def _trimmed_rms(r: np.ndarray, keep: float = 0.8) -> float:
    r2 = np.sort(r**2)
    k = max(1, int(keep * len(r2)))
    return float(np.sqrt(r2[:k].mean()))


def fit_revolution(
    points: np.ndarray,
    normals: np.ndarray,
    *,
    cell: float = 0.0015,
    quantile: float = 0.75,
    tol: float = 0.002,
    min_inlier: float = 0.7,
    max_axis_rms: float = 0.003,
    n_dirs: int = 600,
    max_points: int = 6000,
    seed: int = 0,
) -> Revolution | None:
    """Fit a surface of revolution to an object-frame cloud (N, 3) m (evenly thinned: each point stands for
    about the same area) with outward normals (N, 3) used only to orient the local-PCA normals.

    Returns the :class:`Revolution` when the revolved profile passes within ``tol`` (m) of at least
    ``min_inlier`` of the points and the axis residual is below ``max_axis_rms`` (m); None otherwise (not a
    surface of revolution, too few points or normals). ``quantile``: per-height radius quantile of the profile.
    """
    P = np.asarray(points, np.float64).reshape(-1, 3)
    N = np.asarray(normals, np.float64).reshape(-1, 3)
    ok = np.isfinite(P).all(1)
    P, N = P[ok], np.where(np.isfinite(N[ok]), N[ok], 0.0)
    if len(P) < 50:
        return None
    sd = np.linalg.svd(P - P.mean(0), compute_uv=False) / np.sqrt(len(P))
    if sd[1] < 0.003:  # a line or a speck: no surface to revolve
        return None
    rng = np.random.default_rng(seed)
    N = pca_normals(P, N)
    if len(P) > max_points:
        sel = rng.choice(len(P), max_points, replace=False)
        P, N = P[sel], N[sel]
    ref = P.mean(0)

    def extent(a: np.ndarray) -> float:
        h = P @ a
        return float(np.percentile(h, 99) - np.percentile(h, 1))

    dirs = _fibonacci_hemisphere(n_dirs)
    fits = [_axis_point(P, N, a, ref) for a in dirs]
    errs = np.array([_trimmed_rms(r) for _, r in fits])
    # A sphere fits every axis through its centre: among the axes as good as the best (noise), take the one the
    # observed points span farthest along, so the revolved profile reaches around the unseen side (an axis along
    # the viewing direction would revolve only the seen cap).
    good = np.nonzero(errs <= 1.15 * errs.min() + 2e-4)[0]
    k = good[int(np.argmax([extent(dirs[i]) for i in good]))]
    e, a, c = errs[k], dirs[k], fits[k][0]
    ext = extent(a)
    # local refinement: shrinking random perturbations of the chosen direction, never shortening its span
    step = 0.1
    for _ in range(60):
        a2 = a + step * rng.normal(size=3)
        a2 /= np.linalg.norm(a2)
        c2, r2 = _axis_point(P, N, a2, ref)
        e2 = _trimmed_rms(r2)
        if e2 < e and extent(a2) >= 0.97 * ext:
            e, a, c = e2, a2, c2
        else:
            step *= 0.93
    if not np.isfinite(e) or e > max_axis_rms:
        return None
    # the handle of a cup (normal lines far from the axis) tilts the fit: refit on the points that agree
    _, r = _axis_point(P, N, a, ref)
    agree = np.abs(r) < 2.5 * e
    if agree.sum() >= 50:
        Pa, Na = P[agree], N[agree]
        e_a = _trimmed_rms(_axis_point(Pa, Na, a, ref)[1], keep=0.95)
        step = 0.05
        for _ in range(40):
            a2 = a + step * rng.normal(size=3)
            a2 /= np.linalg.norm(a2)
            c2, r2 = _axis_point(Pa, Na, a2, ref)
            e2 = _trimmed_rms(r2, keep=0.95)
            if e2 < e_a and extent(a2) >= 0.97 * ext:
                e_a, a, c = e2, a2, c2
            else:
                step *= 0.93
    X = P - c
    h = X @ a
    radial = X - h[:, None] * a
    rho = np.linalg.norm(radial, axis=1)
    n_out = np.einsum("ij,ij->i", N, radial) / np.maximum(rho, 1e-9)  # normal component away from the axis
    # the outer profile only: inward-facing points (the inner wall of a cup) are left to the network
    outer = n_out > -0.3
    P, N, h, rho, n_out = P[outer], N[outer], h[outer], rho[outer], n_out[outer]
    if len(P) < 50:
        return None
    # profile radius per height bin
    lo, hi = h.min(), h.max()
    nb = max(2, int(np.ceil((hi - lo) / cell)) + 1)
    bi = np.clip(((h - lo) / cell).astype(np.int64), 0, nb - 1)
    R = np.full(nb, np.nan)
    order = np.argsort(bi, kind="stable")
    bounds = np.searchsorted(bi[order], np.arange(nb + 1))
    for k in range(nb):
        s = order[bounds[k] : bounds[k + 1]]
        if len(s) >= 3:
            R[k] = np.quantile(rho[s], quantile)
    have = np.isfinite(R)
    if have.sum() < 2:
        return None
    R = np.interp(np.arange(nb), np.nonzero(have)[0], R[have])
    from scipy.ndimage import distance_transform_edt, median_filter

    R = median_filter(R, size=5, mode="nearest")
    # raster of the (h, rho) plane, mirrored about the axis (rho < 0) so the distance across the axis is right
    pad = 8
    nr = int(np.ceil(R.max() / cell)) + pad
    inside = np.zeros((nb + 2 * pad, 2 * nr + 1), bool)
    jr = np.abs(np.arange(-nr, nr + 1))[None, :] * cell  # rho of each column
    inside[pad : pad + nb] = jr <= R[:, None]
    d_out = distance_transform_edt(~inside) * cell
    d_in = distance_transform_edt(inside) * cell
    sdf_full = np.where(inside, -(d_in - 0.5 * cell), d_out - 0.5 * cell)
    sdf2 = sdf_full[:, nr:]  # rho >= 0 half
    rev = Revolution(
        centre=c,
        axis=a,
        h0=float(lo - pad * cell),
        cell=float(cell),
        sdf2=sdf2.astype(np.float32),
        inlier=0.0,
        axis_rms=float(e),
    )
    # the test uses the side (normals across the axis): caps may be recessed (a can's lid below its rim), which a
    # profile radius per height cannot represent and need not (the network fits the observed caps)
    side = n_out > 0.7
    if side.sum() < 0.2 * len(P):
        return None
    rev.inlier = float(np.mean(np.abs(rev.sdf(P[side])) <= tol))
    return rev if rev.inlier >= min_inlier else None
