"""Elliptic-section prior: complete the unseen back of an elongated object from its seen cross-sections.

The neural SDF's hull prior cuts a never-seen side flat. On the 5 s benchmark sessions that is most of what is
still lost on the banana and the mustard bottle: a third of the true surface lies more than 5 mm from any
observation, and every reconstructed sample more than 5 mm off lies INSIDE the object, on the flat cut
(docs/benchmarks/fusion_recon2.md). Their cross-sections across the long axis are close to ellipses, and the
camera sees about two thirds of each section's perimeter (the front and both sides), which fixes the ellipse.

Method (object frame, metres; numpy + scipy):

1. Points thinned to 2 mm cells, stray clusters dropped (as for the hull prior); principal axes ``a`` (longest),
   ``u``, ``v`` about the centroid.
2. Slabs ``slab`` wide along ``a`` every ``step``; in each, the points' ``(u, v)`` coordinates get a direct
   least-squares ellipse fit (Fitzgibbon et al. 1999; three reweighting rounds down-weight points farther than
   2 ``tol``: a finger's contact, a cap), refined into a superellipse ``|x/A|^n + |y/B|^n = 1`` (n in [2, 8]) by
   robust geometric least squares (the algebraic fit of a partial arc is biased small; a bottle's section is a
   rounded rectangle).
3. Only OPEN sections count: the largest angular gap of the seen points around the fitted centre must reach
   ``min_gap`` (a section seen all round is closed by the hull already). An open slab is accepted when the
   trimmed RMS distance of its points to the curve is at most ``tol``, they cover at least ``min_arc`` of the turn
   and the curve stays within ``max_grow`` times the points' own extent (no wild extrapolation from a flat arc: a
   box's flat face gives a huge ellipse and is rejected). Second pass: a slab refused only for growth (a short seen
   arc: the banana's middle, seen edge-on) is accepted when its curve grows at most ``consistent_grow`` times and
   its semi-axes agree within ``consistent_size`` with the nearest accepted slab on either side.
4. The prior is accepted with at least ``min_slabs`` accepted slabs holding at least ``min_share`` of the open
   slabs' points; a box (potted meat can), a cup with its handle or a cloud seen all round keeps the hull.
5. SDF: between two accepted slab centres the signed distances to their curves are blended linearly in the slab
   coordinate; outside every accepted slab (and beyond the points' ends along ``a``) the section prior does not
   exist (+inf). The neural SDF unites it with the hull (minimum), so it can only add volume where the hull cut
   the unseen side.

The 2-D distance is the first-order estimate ``(k - 1) / |grad k|`` with ``k`` the superellipse's normalised
radius, exact on the curve and good to a few per cent within the few millimetres that matter.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vtrack.errors import InputError


@dataclass
class Sections:
    """Fitted elliptic sections along an axis (object frame, metres).

    centre (3,): origin of the section frame; axes (3, 3): rows ``a`` (slab axis), ``u``, ``v``; s (K,): slab
    centres along ``a`` (relative to ``centre``), ascending; ellipses (K, 5): ``(cu, cv, A, B, theta)`` per slab
    (centre in (u, v), semi-axes m, rotation rad); s_range (2,): the points' extent along ``a``; share: share of
    the points in accepted slabs.
    """

    centre: np.ndarray
    axes: np.ndarray
    s: np.ndarray
    ellipses: np.ndarray
    s_range: np.ndarray
    share: float

    def sdf(self, points: np.ndarray) -> np.ndarray:
        """Signed distance estimate (N,) m to the section solid; +inf where no accepted section covers a point."""
        X = np.asarray(points, np.float64).reshape(-1, 3)
        if not np.isfinite(X).all():
            raise InputError("non-finite query points", field="points", expected="finite (N, 3) m", got="NaN/Inf")
        L = (X - self.centre) @ self.axes.T
        s, q = L[:, 0], L[:, 1:]
        out = np.full(len(X), np.inf)
        K = len(self.s)
        if K == 0:
            return out
        # neighbouring accepted slab centres (gap of more than 1.5 steps: no blend across it)
        j = np.clip(np.searchsorted(self.s, s) - 1, 0, max(K - 2, 0))
        if K == 1:
            d = _ellipse_sdf(q, self.ellipses[0])
            near = np.abs(s - self.s[0]) <= self._half
            out[near] = d[near]
        else:
            s0, s1 = self.s[j], self.s[j + 1]
            t = np.clip((s - s0) / np.maximum(s1 - s0, 1e-9), 0.0, 1.0)
            d0 = np.empty(len(X))
            d1 = np.empty(len(X))
            for k in np.unique(j):
                m = j == k
                d0[m] = _ellipse_sdf(q[m], self.ellipses[k])
                d1[m] = _ellipse_sdf(q[m], self.ellipses[k + 1])
            d = (1 - t) * d0 + t * d1
            adjacent = (s1 - s0) <= 1.5 * self._step
            inside = (s >= s0 - self._half) & (s <= s1 + self._half)
            ok = inside & (adjacent | (np.minimum(s - s0, s1 - s) <= self._half) | (s < s0) | (s > s1))
            # between two non-adjacent slabs only the halves next to each slab are covered, by that slab alone
            lone = ok & ~adjacent & (s >= s0) & (s <= s1)
            use0 = lone & (s - s0 <= self._half)
            d = np.where(use0, d0, np.where(lone, d1, d))
            out[ok] = d[ok]
        # caps: the solid ends where the observations end
        cap = np.maximum(self.s_range[0] - s, s - self.s_range[1])
        return np.where(np.isfinite(out), np.maximum(out, cap), out)

    _step: float = 0.01
    _half: float = 0.01


def _ellipse_sdf(q: np.ndarray, e: np.ndarray) -> np.ndarray:
    """First-order signed distance (N,) m of 2-D points q (N, 2) to the superellipse
    e = (cu, cv, A, B, theta[, n]): ``|x / A|^n + |y / B|^n = 1`` in its frame (n = 2, an ellipse, when absent)."""
    cu, cv, A, B, th = e[:5]
    n = float(e[5]) if len(e) > 5 else 2.0
    c, sn = np.cos(th), np.sin(th)
    x = np.abs((q[:, 0] - cu) * c + (q[:, 1] - cv) * sn) / A
    y = np.abs(-(q[:, 0] - cu) * sn + (q[:, 1] - cv) * c) / B
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        k = (x**n + y**n) ** (1.0 / n)
        kk = np.maximum(k, 1e-12)
        g = kk ** (1.0 - n) * np.hypot(x ** (n - 1) / A, y ** (n - 1) / B)
        d = (k - 1.0) / np.maximum(g, 1e-12)
    return np.where((k > 1e-9) & np.isfinite(d), d, -min(A, B))


def fit_ellipse(xy: np.ndarray, w: np.ndarray | None = None) -> np.ndarray | None:
    """Direct least-squares ellipse fit (Fitzgibbon, Pilu, Fisher 1999) of 2-D points (N, 2) with optional
    weights (N,); returns (cu, cv, A, B, theta) (A >= B semi-axes) or None when no ellipse fits."""
    P = np.asarray(xy, np.float64).reshape(-1, 2)
    if len(P) < 6:
        return None
    m = P.mean(0)
    sc = float(np.sqrt(((P - m) ** 2).sum(1).mean())) or 1.0
    x, y = ((P - m) / sc).T
    D1 = np.stack([x * x, x * y, y * y], 1)
    D2 = np.stack([x, y, np.ones_like(x)], 1)
    if w is not None:
        sw = np.sqrt(np.asarray(w, np.float64))[:, None]
        D1, D2 = D1 * sw, D2 * sw
    S1, S2, S3 = D1.T @ D1, D1.T @ D2, D2.T @ D2
    try:
        T = -np.linalg.solve(S3, S2.T)
    except np.linalg.LinAlgError:
        return None
    M = S1 + S2 @ T
    M = np.array([M[2] / 2, -M[1], M[0] / 2])
    _, vecs = np.linalg.eig(M)
    vecs = np.real(vecs)
    cond = 4 * vecs[0] * vecs[2] - vecs[1] ** 2
    ok = cond > 0
    if not ok.any():
        return None
    a1 = vecs[:, np.argmax(np.where(ok, cond, -np.inf))]
    a, b, c, d, e, f = np.concatenate([a1, T @ a1])
    den = b * b - 4 * a * c
    if den >= 0:
        return None
    cu = (2 * c * d - b * e) / den
    cv = (2 * a * e - b * d) / den
    num = 2 * (a * e * e + c * d * d - b * d * e + den * f)
    root = np.sqrt((a - c) ** 2 + b * b)
    with np.errstate(divide="ignore", invalid="ignore"):
        ax2 = -np.array([num / (den * ((a + c) + root)), num / (den * ((a + c) - root))])
    A2, B2 = float(np.max(ax2)), float(np.min(ax2))
    if not (B2 > 0 and np.isfinite(A2)):
        return None
    th = 0.5 * np.arctan2(-b, c - a)
    A, B = np.sqrt(A2) * sc, np.sqrt(B2) * sc
    ell = np.array([cu * sc + m[0], cv * sc + m[1], A, B, th])
    # pick the orientation under which the points fit (the closed forms differ by 90 deg between conventions)
    alt = ell.copy()
    alt[4] = th + np.pi / 2
    r0 = np.abs(_ellipse_sdf(P, ell)).mean()
    r1 = np.abs(_ellipse_sdf(P, alt)).mean()
    return ell if r0 <= r1 else alt


def _refine(xy: np.ndarray, ell: np.ndarray, tol: float) -> np.ndarray:
    """Geometric refinement of an ellipse into a superellipse (robust least squares on the first-order distance,
    exponent n in [2, 8]): the algebraic fit of a partial arc is biased towards too small ellipses, which would
    cut the unseen side short, and a bottle's section is a rounded rectangle rather than an ellipse."""
    from scipy.optimize import least_squares

    def unpack(p: np.ndarray) -> np.ndarray:
        return np.array([p[0], p[1], abs(p[2]) + 1e-4, abs(p[3]) + 1e-4, p[4], 2.0 + 6.0 / (1.0 + np.exp(-p[5]))])

    def res(p: np.ndarray) -> np.ndarray:
        return _ellipse_sdf(xy, unpack(p))

    try:
        r = least_squares(res, np.r_[ell[:5], -3.0], loss="soft_l1", f_scale=tol, max_nfev=80)
    except ValueError:
        return np.r_[ell[:5], 2.0]
    out = unpack(r.x)
    return out if np.all(np.isfinite(out)) else np.r_[ell[:5], 2.0]


def fit_sections(
    points: np.ndarray,
    *,
    slab: float = 0.02,
    step: float = 0.01,
    tol: float = 0.0015,
    min_arc: float = 0.5,
    max_grow: float = 1.6,
    min_share: float = 0.6,
    min_points: int = 30,
    min_gap: float = np.pi / 2,
    min_slabs: int = 3,
    consistent_grow: float = 2.5,
    consistent_size: float = 0.15,
) -> Sections | None:
    """Fit elliptic sections to an elongated observed cloud (N, 3) m; None when they do not explain it.

    Args: see the module docstring (``slab``, ``step``, ``tol`` (m), ``min_arc`` (share of 2 pi), ``max_grow``,
    ``min_gap`` (rad), ``min_slabs``, ``min_share`` as there; ``min_points`` per slab after thinning).
    consistent_grow: a slab refused only for growing past ``max_grow`` (a short seen arc extrapolates more) is
    accepted when its curve grows at most ``consistent_grow`` times the points' extent and its semi-axes are within
    ``consistent_size`` (relative) of the nearest accepted slab's on either side; 0 turns this second pass off
    (on the 5 s medium banana sessions it adds the 3-6 slabs in the middle of the banana whose seen arc is short:
    F@5 0.811 -> 0.885 over seeds 0-2, docs/benchmarks/sections_hold.md).
    """
    from vtrack.fusion.neural_sdf import largest_cluster

    P = np.asarray(points, np.float64).reshape(-1, 3)
    P = P[np.isfinite(P).all(1)]
    if len(P) < 4 * min_points:
        return None
    P = largest_cluster(P, 0.004)
    _, first = np.unique(np.floor((P - P.min(0)) / 0.002).astype(np.int64), axis=0, return_index=True)
    P = P[first]
    if len(P) < 4 * min_points:
        return None
    c0 = P.mean(0)
    _, sv, Vt = np.linalg.svd(P - c0, full_matrices=False)
    if sv[0] < 1.5 * sv[1]:  # not elongated: sections along no preferred axis
        return None
    L = (P - c0) @ Vt.T
    s, q = L[:, 0], L[:, 1:]
    centres = np.arange(s.min() + 0.5 * slab, s.max() - 0.5 * slab + 1e-9, step)
    kept_s, kept_e = [], []
    grown: list[tuple[float, np.ndarray, np.ndarray]] = []  # refused for growth only: (s, ellipse, point mask)
    covered = np.zeros(len(P), bool)
    open_ = np.zeros(len(P), bool)  # points in slabs whose section is open (seen over less than the full turn)
    for sc_ in centres:
        m = np.abs(s - sc_) <= 0.5 * slab
        if m.sum() < min_points:
            continue
        xy = q[m]
        w = np.ones(len(xy))
        ell = None
        for _ in range(3):
            ell = fit_ellipse(xy, w)
            if ell is None:
                break
            r = np.abs(_ellipse_sdf(xy, ell))
            w = np.where(r <= 2 * tol, 1.0, 1e-3)
        if ell is None:
            continue
        ell = _refine(xy, ell, tol)
        r = np.sort(np.abs(_ellipse_sdf(xy, ell)))
        rms = float(np.sqrt(np.mean(r[: max(1, int(0.8 * len(r)))] ** 2)))
        # angular coverage of the points around the ellipse centre (12 bins of 30 deg)
        ang = np.arctan2(xy[:, 1] - ell[1], xy[:, 0] - ell[0])
        arc = len(np.unique(np.floor((ang + np.pi) / (np.pi / 6)).astype(int))) / 12.0
        span = np.ptp(xy, axis=0)
        c, sn = np.abs(np.cos(ell[4])), np.abs(np.sin(ell[4]))
        box = 2 * np.array([ell[2] * c + ell[3] * sn, ell[2] * sn + ell[3] * c])  # bounding box (any n)
        # largest angular gap of the points around the section: a section seen all round is closed by the hull
        # already (an imperfect superellipse would only bulge past it), only an open one needs completing
        srt = np.sort(ang)
        gap = float(np.max(np.diff(np.r_[srt, srt[0] + 2 * np.pi]))) if len(srt) else 2 * np.pi
        if gap < min_gap:
            continue
        open_ |= m
        grow = float(np.max(box / np.maximum(span, 1e-3)))
        if rms <= tol and arc >= min_arc and grow <= max_grow:
            kept_s.append(sc_)
            kept_e.append(ell)
            covered |= m
        elif rms <= tol and arc >= min_arc and grow <= consistent_grow:
            grown.append((sc_, ell, m))
    if kept_s and grown:
        # second pass: a short arc's curve is trusted when it agrees in size with an accepted neighbour
        ks = np.asarray(kept_s)
        ke = np.asarray(kept_e)
        for sc_, ell, m in grown:
            # the nearest accepted slab on each side (a tapering end may disagree with one of them)
            left, right = ks <= sc_, ks >= sc_
            refs = [ke[left][np.argmax(ks[left])]] if left.any() else []
            refs += [ke[right][np.argmin(ks[right])]] if right.any() else []
            if any(np.all(np.abs(ell[2:4] - r[2:4]) <= consistent_size * r[2:4]) for r in refs):
                kept_s.append(sc_)
                kept_e.append(ell)
                covered |= m
        order = np.argsort(kept_s)
        kept_s = [kept_s[i] for i in order]
        kept_e = [kept_e[i] for i in order]
    share = float(covered.sum() / max(1, open_.sum()))
    if len(kept_s) < min_slabs or share < min_share:
        return None
    out = Sections(c0, Vt, np.asarray(kept_s), np.asarray(kept_e), np.array([s.min(), s.max()]), share)
    out._step, out._half = step, 0.5 * slab
    return out
