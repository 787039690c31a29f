"""Marker extraction and the marker graph (FusionTouch S5).

Pipeline: grey -> gamma normalisation -> white top-hat (removes vignetting/background) -> Otsu threshold
-> connected components -> split merged blobs (k-means on elongated/concave blobs) -> per-marker image moments ->
8-D descriptor ``[x_rel, y_rel, area_norm, r, eta, sin2t, cos2t, boundary]`` -> Delaunay graph with
relative-geometry edge attributes ``[dx, dy, dist, d_area, d_eta]``.

Coordinates: pixels, x = column, y = row; ``x_rel, y_rel`` are relative to the image centre and divided
by half the image size, ``r = hypot(x_rel, y_rel)``, ``area_norm`` = area / median marker area,
``eta`` = minor / major axis (1 = round), ``t`` = major-axis angle, ``boundary`` = 1 on the convex hull.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vtrack.errors import InputError

NODE_DIM = 8
EDGE_DIM = 5


@dataclass
class MarkerSet:
    """Detected markers of one image: centres (n, 2) px, areas (n,) px^2, axes (n, 2) px, angle (n,) rad."""

    centers: np.ndarray
    areas: np.ndarray
    axes: np.ndarray
    angles: np.ndarray
    image_size: tuple[int, int]  # (height, width)
    n_split: int = 0
    n_rejected: int = 0

    def __len__(self) -> int:
        return len(self.centers)


@dataclass
class MarkerGraph:
    """Node features (n, 8), undirected edges as directed pairs (2, m), edge attributes (m, 5)."""

    x: np.ndarray
    edge_index: np.ndarray
    edge_attr: np.ndarray
    centers: np.ndarray
    method: str = "delaunay"
    info: dict = field(default_factory=dict)


def check_image(image: np.ndarray, expected_size: int | None = None, *, path=None) -> np.ndarray:
    """Validate an image and return it as 2-D grey uint8/float32; InputError names what is wrong."""
    if image is None:
        raise InputError("could not read image", path=path, expected="a PNG/JPG image")
    a = np.asarray(image)
    if a.ndim == 3 and a.shape[2] in (3, 4):
        import cv2

        a = cv2.cvtColor(a[..., :3].astype(np.uint8) if a.dtype != np.uint8 else a[..., :3], cv2.COLOR_BGR2GRAY)
    if a.ndim != 2 or min(a.shape) < 8:
        raise InputError(
            "bad image shape", path=path, field="image", expected="(H, W) or (H, W, 3), H, W >= 8", got=tuple(a.shape)
        )
    if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
        raise InputError("image holds NaN/Inf", path=path, field="image", expected="finite pixel values")
    if expected_size is not None and a.shape != (expected_size, expected_size):
        raise InputError(
            "image of the wrong size for this model",
            path=path,
            field="image",
            expected=f"{expected_size}x{expected_size} px (or pass resize=True)",
            got=f"{a.shape[1]}x{a.shape[0]}",
        )
    return a


def extract_markers(
    image: np.ndarray,
    *,
    polarity: str = "auto",
    gamma: float = 0.8,
    mask_radius: float = 0.98,
    min_area: float = 2.0,
    split: bool = True,
    max_area_ratio: float = 6.0,
) -> MarkerSet:
    """Detect markers in a grey image.

    Args:
        polarity: ``"bright"`` (white pins on dark, TacTip), ``"dark"`` (dark dots on bright) or ``"auto"``
            (dark if the image median is above mid-grey).
        gamma: exponent applied to the percentile-normalised image (boosts faint markers when < 1).
        mask_radius: keep blobs whose centre lies within this fraction of the half image size (drops the
            dome rim and corners).
        min_area: smallest blob kept (px^2).
        split: split merged blobs (area > 1.6 x median and elongated or concave) by k-means on their
            pixels, k = round(area / median area).
        max_area_ratio: blobs still larger than this x median after splitting are rejected (rim arcs).
    """
    import cv2

    g0 = check_image(image)
    g = g0.astype(np.float32)
    H, W = g.shape
    # order statistics (1st / 99.7th percentile, max, the two middle values): from the 256-bin histogram
    # for 8-bit frames (exact, ~10x cheaper than np.percentile + np.median on the float image)
    qs = np.array([0.01 * (g.size - 1), 0.997 * (g.size - 1), g.size - 1, (g.size - 1) // 2, g.size // 2])
    fl = np.floor(qs).astype(np.int64)
    nx = np.minimum(fl + 1, g.size - 1)  # the order statistics interpolated between (numpy's "linear" method)
    if g0.dtype == np.uint8:
        cum = np.cumsum(np.bincount(g0.ravel(), minlength=256))
        v0, v1 = (np.searchsorted(cum, k, side="right").astype(np.float64) for k in (fl, nx))
    else:
        srt = np.partition(g.ravel(), np.unique(np.concatenate([fl, nx])))
        v0, v1 = srt[fl].astype(np.float64), srt[nx].astype(np.float64)
    stats = v0 + (qs - fl) * (v1 - v0)
    lo, hi, gmax = float(stats[0]), float(stats[1]), float(stats[2])
    if hi - lo < 0.25 * (gmax - lo):  # very few marker pixels (a handful of markers): use the maximum
        hi = gmax
    if hi - lo < 1e-6:  # flat image: nothing to find
        return _empty(H, W)
    g = np.clip((g - lo) / (hi - lo), 0, 1)
    median = float(np.mean(np.clip((stats[3:] - lo) / (hi - lo), 0, 1)))  # median of the normalised image
    if polarity == "dark" or (polarity == "auto" and median > 0.5):
        g = 1.0 - g
    g = g**gamma
    # top-hat with a kernel larger than a marker: removes vignetting and smooth background
    k = max(7, int(round(min(H, W) / 12)) | 1)
    th = cv2.morphologyEx(g, cv2.MORPH_TOPHAT, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)))
    th8 = np.clip(th * 255, 0, 255).astype(np.uint8)
    if int(th8.max()) < 20:
        return _empty(H, W)
    t, bw = cv2.threshold(th8, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    if t < 10:  # Otsu on pure noise picks a tiny threshold
        _, bw = cv2.threshold(th8, 40, 255, cv2.THRESH_BINARY)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(bw, connectivity=8)
    areas = stats[1:, cv2.CC_STAT_AREA].astype(np.float64)
    keep = np.nonzero(areas >= min_area)[0] + 1
    n_split = 0
    if split and len(keep) >= 3:
        med = float(np.median(areas[keep - 1]))
        next_label = n
        for b in keep[areas[keep - 1] > 1.6 * med]:
            x0, y0, w, h = stats[b, :4]
            yy, xx = np.nonzero(lab[y0 : y0 + h, x0 : x0 + w] == b)
            pts = np.stack([xx, yy], 1).astype(np.float32)
            cov = np.cov(pts.T)
            ev = np.linalg.eigvalsh(cov)
            elong = float(np.sqrt(max(ev[0], 1e-9) / max(ev[1], 1e-9)))
            solidity = len(pts) / max(cv2.contourArea(cv2.convexHull(pts)), 1.0)
            # a single (large, peripheral) marker is round and convex; merged ones are elongated or concave
            if elong > 0.62 and solidity > 0.85:
                continue
            k = int(np.clip(round(areas[b - 1] / med), 2, 4))
            crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 20, 0.1)
            _, owner, _ = cv2.kmeans(pts, k, None, crit, 2, cv2.KMEANS_PP_CENTERS)
            owner = owner.ravel()
            for j in range(1, k):
                lab[y0 + yy[owner == j], x0 + xx[owner == j]] = next_label
                next_label += 1
            n_split += k - 1
        n = next_label
    ctr, area, axes, ang = label_ellipses(lab, n, g, min_area)
    # reject blobs outside the circular mask, and unsplittable giants / arcs (dome rim)
    rr = np.hypot(ctr[:, 0] - (W - 1) / 2, ctr[:, 1] - (H - 1) / 2) / (min(H, W) / 2)
    ok = rr <= mask_radius
    if ok.sum() >= 3:
        med = float(np.median(area[ok]))
        ok &= area <= max_area_ratio * med
        ok &= ~((axes[:, 1] / np.maximum(axes[:, 0], 1e-9) < 0.25) & (area > 2 * med))
    good = np.all(np.isfinite(ctr), 1) & ok
    return MarkerSet(ctr[good], area[good], axes[good], ang[good], (H, W), n_split, int((~good).sum()))


def label_ellipses(
    lab: np.ndarray, n: int, weight: np.ndarray, min_area: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Intensity-weighted ellipse of every label ``1..n-1`` of ``lab`` with at least ``min_area`` pixels
    (image moments vectorised with bincount): centres (K, 2) px ``(x, y)``, areas (K,) px, full axes (K, 2) px
    (major, minor) and orientation (K,) rad. A label with zero weight gives a NaN centre (caller drops it)."""
    ys, xs = np.nonzero(lab)
    ls = lab[ys, xs]
    wts = weight[ys, xs].astype(np.float64) + 1e-3
    m00 = np.bincount(ls, wts, n)
    cnt = np.bincount(ls, None, n)
    with np.errstate(invalid="ignore", divide="ignore"):
        mx = np.bincount(ls, wts * xs, n) / m00
        my = np.bincount(ls, wts * ys, n) / m00
        dx, dy = xs - mx[ls], ys - my[ls]
        # + 1/12: the variance of a uniform unit pixel, so a one-pixel blob has a finite size
        cxx = np.bincount(ls, wts * dx * dx, n) / m00 + 1 / 12
        cyy = np.bincount(ls, wts * dy * dy, n) / m00 + 1 / 12
        cxy = np.bincount(ls, wts * dx * dy, n) / m00
    ids = np.arange(1, n)
    ids = ids[cnt[ids] >= min_area]
    tr, det = cxx[ids] + cyy[ids], cxx[ids] * cyy[ids] - cxy[ids] ** 2
    disc = np.sqrt(np.clip(tr * tr / 4 - det, 0, None))
    l1, l2 = tr / 2 + disc, np.clip(tr / 2 - disc, 1e-9, None)
    axes = np.stack([2 * np.sqrt(l1), 2 * np.sqrt(l2)], 1)
    ang = 0.5 * np.arctan2(2 * cxy[ids], cxx[ids] - cyy[ids])
    ctr = np.stack([mx[ids], my[ids]], 1)
    return ctr, cnt[ids].astype(np.float64), axes, ang


def _empty(H: int, W: int) -> MarkerSet:
    return MarkerSet(np.zeros((0, 2)), np.zeros(0), np.zeros((0, 2)), np.zeros(0), (H, W))


def node_features(ms: MarkerSet, boundary: np.ndarray | None = None) -> np.ndarray:
    """S5 descriptors (n, 8) float32: ``[x_rel, y_rel, area_norm, r, eta, sin2t, cos2t, boundary]``."""
    H, W = ms.image_size
    n = len(ms)
    if n == 0:
        return np.zeros((0, NODE_DIM), np.float32)
    half = min(H, W) / 2.0
    xr = (ms.centers[:, 0] - (W - 1) / 2) / half
    yr = (ms.centers[:, 1] - (H - 1) / 2) / half
    med = float(np.median(ms.areas)) if n else 1.0
    eta = ms.axes[:, 1] / np.maximum(ms.axes[:, 0], 1e-9)
    b = np.zeros(n) if boundary is None else boundary.astype(np.float64)
    f = np.stack(
        [xr, yr, ms.areas / max(med, 1e-9), np.hypot(xr, yr), eta, np.sin(2 * ms.angles), np.cos(2 * ms.angles), b], 1
    )
    return np.nan_to_num(f, nan=0.0, posinf=0.0, neginf=0.0).astype(np.float32)


def _knn_edges(pts: np.ndarray, k: int) -> np.ndarray:
    n = len(pts)
    if n < 2:
        return np.zeros((2, 0), np.int64)
    d2 = ((pts[:, None] - pts[None]) ** 2).sum(-1)
    np.fill_diagonal(d2, np.inf)
    k = min(k, n - 1)
    nb = np.argsort(d2, 1)[:, :k]
    src = np.repeat(np.arange(n), k)
    return np.stack([src, nb.ravel()])


def build_graph(ms: MarkerSet, *, knn_fallback: int = 4) -> MarkerGraph:
    """Delaunay graph of the markers (kNN graph when Delaunay is impossible: < 3 or collinear points).

    Edges are stored in both directions. Edge attributes are the relative geometry of neighbour j seen
    from node i: ``[dx, dy, dist]`` (in units of half the image size) and the area and eta differences.
    """
    from scipy.spatial import Delaunay, QhullError

    n = len(ms)
    method = "delaunay"
    boundary = np.zeros(n, bool)
    e = np.zeros((2, 0), np.int64)
    if n >= 3:
        try:
            tri = Delaunay(ms.centers)
            s = tri.simplices
            e = np.concatenate([s[:, [0, 1]], s[:, [1, 2]], s[:, [2, 0]]]).T
            boundary[np.unique(tri.convex_hull)] = True  # hull edges of the triangulation (no 2nd Qhull run)
        except QhullError:  # collinear / coincident markers
            method = "knn"
    else:
        method = "knn" if n >= 2 else "empty"
    if method == "knn":
        e = _knn_edges(ms.centers, knn_fallback)
        boundary[:] = True
    if e.shape[1]:
        # unique undirected edges via one int64 key per edge (np.unique(axis=1) is ~10x slower)
        lo, hi = e.min(0).astype(np.int64), e.max(0).astype(np.int64)
        key = np.unique(lo * max(n, 1) + hi)
        e = np.stack([key // max(n, 1), key % max(n, 1)])
        e = e[:, e[0] != e[1]]
        e = np.concatenate([e, e[::-1]], 1)
    x = node_features(ms, boundary)
    if e.shape[1]:
        half = min(ms.image_size) / 2.0
        d = (ms.centers[e[1]] - ms.centers[e[0]]) / half
        ea = np.stack(
            [d[:, 0], d[:, 1], np.hypot(d[:, 0], d[:, 1]), x[e[1], 2] - x[e[0], 2], x[e[1], 4] - x[e[0], 4]], 1
        )
    else:
        ea = np.zeros((0, EDGE_DIM))
    return MarkerGraph(
        x,
        e.astype(np.int64),
        ea.astype(np.float32),
        ms.centers.astype(np.float32),
        method,
        {"n_markers": n, "n_split": ms.n_split},
    )
