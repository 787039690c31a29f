"""Gel markers: detection (sub-pixel centroids), frame-to-frame tracking, shear and torsion.

Pixel coordinates are (x, y) = (column, row). Displacements are in px; :class:`ShearEstimate` also gives
them in mm when ``mm_per_px`` is known. Markers are dark dots on a brighter gel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vtrack.errors import InputError


def _grey(image: np.ndarray) -> np.ndarray:
    import cv2

    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(np.ascontiguousarray(img, np.uint8), cv2.COLOR_BGR2GRAY)
    if img.ndim != 2:
        raise InputError("marker image must be (H, W) or (H, W, 3)", field="image", got=img.shape)
    return img.astype(np.float32)


def detect_markers(
    image: np.ndarray, *, contrast: float = 25.0, min_area_px: int = 4, max_area_px: int = 400, blur_px: float = 0.0
) -> np.ndarray:
    """(N, 2) float64 sub-pixel marker centroids (x, y), darkness-weighted.

    A pixel is a marker candidate when it is ``contrast`` grey levels darker than its local background
    (a wide median of the image); blobs outside [min_area_px, max_area_px] are rejected.
    """
    import cv2

    g = _grey(image)
    if blur_px > 0:
        g = cv2.GaussianBlur(g, (0, 0), blur_px)
    k = int(max(15, 2 * int(np.sqrt(max_area_px)) + 1)) | 1
    local = cv2.blur(g, (k, k))
    dark = np.clip(local - g, 0, None)
    m = (dark > contrast).astype(np.uint8)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    if n <= 1:
        return np.zeros((0, 2))
    area = stats[:, cv2.CC_STAT_AREA]
    ok = (area >= min_area_px) & (area <= max_area_px)
    ok[0] = False
    rows, cols = np.nonzero(lab)
    labs = lab[rows, cols]
    w = dark[rows, cols].astype(np.float64)
    sw = np.bincount(labs, weights=w, minlength=n)
    cx = np.bincount(labs, weights=w * cols, minlength=n)
    cy = np.bincount(labs, weights=w * rows, minlength=n)
    good = ok & (sw > 0)
    return np.column_stack([cx[good] / sw[good], cy[good] / sw[good]])


@dataclass
class ShearEstimate:
    """Marker displacement field relative to the reference (first) frame.

    Attributes:
        reference: (M, 2) reference marker positions (x, y), px.
        displacement: (M, 2) displacement of each reference marker, px (NaN when lost).
        tracked: (M,) bool, marker found in this frame.
        shear_px: (2,) in-plane translation of the marker field at the reference centroid (x, y), px.
        shear_mm: (2,) the same in mm (NaN without mm_per_px).
        torsion_rad: in-plane rotation of the tracked markers about their centroid (rad, x towards y).
    """

    reference: np.ndarray
    displacement: np.ndarray
    tracked: np.ndarray
    shear_px: np.ndarray
    shear_mm: np.ndarray
    torsion_rad: float

    @property
    def n_tracked(self) -> int:
        return int(self.tracked.sum())


def rigid_2d(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray]:
    """Least-squares 2-D rotation angle (rad) and translation mapping ``src`` to ``dst`` (Kabsch)."""
    if len(src) < 2:
        t = (dst - src).mean(0) if len(src) else np.zeros(2)
        return 0.0, t
    cs, cd = src.mean(0), dst.mean(0)
    S = (src - cs).T @ (dst - cd)
    ang = float(np.arctan2(S[0, 1] - S[1, 0], S[0, 0] + S[1, 1]))
    c, s = np.cos(ang), np.sin(ang)
    R = np.array([[c, -s], [s, c]])
    return ang, cd - R @ cs


def robust_rigid_2d(
    src: np.ndarray, dst: np.ndarray, iters: int = 3, min_tol_px: float = 0.3
) -> tuple[float, np.ndarray]:
    """:func:`rigid_2d` with trimming: matches whose residual exceeds ``max(min_tol_px, 3 x median)`` are
    dropped and the fit repeated. A worn gel gives wrong matches (dust dots that never move, two markers
    merged into one blob, a marker matched to its neighbour's blob); least squares alone lets them drag the
    shear by tenths of a pixel."""
    src, dst = np.asarray(src, float), np.asarray(dst, float)
    keep = np.ones(len(src), bool)
    ang, t = rigid_2d(src, dst)
    for _ in range(iters):
        if keep.sum() < 3:
            break
        c, s = np.cos(ang), np.sin(ang)
        res = np.linalg.norm(src @ np.array([[c, s], [-s, c]]) + t - dst, axis=1)
        new = res <= max(min_tol_px, 3.0 * float(np.median(res[keep])))
        if new.sum() < 3 or (new == keep).all():
            break
        keep = new
        ang, t = rigid_2d(src[keep], dst[keep])
    return ang, t


class MarkerTracker:
    """Track markers frame to frame: each reference marker is matched to the nearest detection around its
    last known position (gated by ``max_step_px``); lost markers keep their last position and are re-found
    later, so missing detections (occlusion, saturation) do not break the field."""

    def __init__(self, mm_per_px: float | None = None, max_step_px: float = 6.0, **detect_kw) -> None:
        self.mm_per_px = mm_per_px
        self.max_step_px = float(max_step_px)
        self.detect_kw = detect_kw
        self.reference: np.ndarray | None = None
        self.last: np.ndarray | None = None

    def reset(self, image: np.ndarray | None = None) -> None:
        self.reference = None if image is None else detect_markers(image, **self.detect_kw)
        self.last = None if self.reference is None else self.reference.copy()

    def update(self, image: np.ndarray) -> ShearEstimate:
        from scipy.spatial import cKDTree

        det = detect_markers(image, **self.detect_kw)
        if self.reference is None:
            self.reference, self.last = det, det.copy()
        ref, last = self.reference, self.last
        M = len(ref)
        cur = np.full((M, 2), np.nan)
        tracked = np.zeros(M, bool)
        if M and len(det):
            # predict with the median motion of the previous step to follow fast shear
            tree = cKDTree(det)
            d, j = tree.query(last, distance_upper_bound=self.max_step_px)
            ok = np.isfinite(d)
            # one detection per marker: keep the closest claimant
            order = np.argsort(np.where(ok, d, np.inf))
            used: set[int] = set()
            for i in order:
                if not ok[i]:
                    break
                if j[i] in used:
                    continue
                used.add(int(j[i]))
                cur[i] = det[j[i]]
                tracked[i] = True
        self.last = np.where(tracked[:, None], cur, last) if M else last
        disp = cur - ref
        if tracked.any():
            # rigid fit of the tracked markers, evaluated at the centroid of ALL reference markers: missing
            # markers then do not bias the shear through the rotation part of the field
            ang, t = robust_rigid_2d(ref[tracked], cur[tracked])
            c0 = ref.mean(0)
            R = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
            shear = R @ c0 + t - c0
        else:
            shear, ang = np.zeros(2), 0.0
        mm = shear * self.mm_per_px if self.mm_per_px else np.full(2, np.nan)
        return ShearEstimate(ref, disp, tracked, shear, mm, ang)
