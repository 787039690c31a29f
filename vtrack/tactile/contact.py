"""Contact mask and contact statistics from a height map (mm) and, optionally, the image difference.

The mask is ``h > tau`` where ``tau = max(threshold_mm, k_sigma * noise_mm, rel * max(h))`` (noise-aware: the
height noise of the sensor, measured on no-contact pixels of the calibration presses; ``rel`` rejects the
skirt of gel pulled down around a deep contact, which is deformed but not touching the object -- on the real
GelSight ball presses ``rel = 0.15`` raises the IoU with the labelled contact disc from 0.36 to 0.67),
intersected with the pixels whose colour changed (image-difference support, removes integration drift in
untouched regions), then cleaned by a morphological closing and removal of components < ``min_area_px``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vtrack.geometry.pixels import mask_pixels
from vtrack.geometry.tactile_frame import pixel_grid_to_sensor_xy


@dataclass
class ContactStats:
    """Contact-region summary. Pixel quantities: x = column, y = row; sensor-frame quantities in m."""

    area_px: int
    area_mm2: float
    centroid_px: tuple[float, float]  # (x, y), NaN when there is no contact
    centroid_sensor_m: tuple[float, float]  # (x, y) in the sensor frame
    axes_px: tuple[float, float]  # principal semi-axis lengths (2 sigma), px, major first
    angle_rad: float  # major-axis direction from +x towards +y
    max_depth_mm: float
    mean_depth_mm: float
    volume_mm3: float

    @property
    def in_contact(self) -> bool:
        return self.area_px > 0


def contact_mask(
    height_mm: np.ndarray,
    threshold_mm: float = 0.05,
    *,
    noise_mm: float = 0.0,
    k_sigma: float = 3.0,
    rel: float = 0.0,
    diff_mask: np.ndarray | None = None,
    min_area_px: int = 3,
    close_px: int = 3,
) -> np.ndarray:
    """Boolean contact mask (H, W). NaN heights are never in contact."""
    import cv2

    h = np.asarray(height_mm)
    tau = max(float(threshold_mm), float(k_sigma) * float(noise_mm))
    if rel > 0 and h.size:
        hmax = float(h.max())
        if not np.isfinite(hmax):  # NaN/Inf present: use the finite maximum
            fin = h[np.isfinite(h)]
            hmax = float(fin.max()) if fin.size else 0.0
        tau = max(tau, float(rel) * hmax)
    with np.errstate(invalid="ignore"):
        m = h > tau  # NaN compares False
    if diff_mask is not None:
        m &= np.asarray(diff_mask, bool)
    if not m.any():
        return m
    m8 = m.view(np.uint8) if m.flags.c_contiguous else m.astype(np.uint8)
    if close_px > 1:
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (close_px, close_px))
        m8 = cv2.morphologyEx(m8, cv2.MORPH_CLOSE, k)
    if min_area_px > 1:
        n, lab, stats, _ = cv2.connectedComponentsWithStats(m8, connectivity=8)
        keep = np.zeros(n, bool)
        keep[1:] = stats[1:, cv2.CC_STAT_AREA] >= min_area_px
        return keep[lab]
    return m8.astype(bool)


def contact_stats(height_mm: np.ndarray, mask: np.ndarray, mm_per_px: float) -> ContactStats:
    """Area, centroid, principal axes and depth of the contact region (all NaN-free; zero when empty)."""
    H, W = mask.shape
    rows, cols = mask_pixels(mask)
    n = len(rows)
    if n == 0:
        nan = float("nan")
        return ContactStats(0, 0.0, (nan, nan), (nan, nan), (0.0, 0.0), 0.0, 0.0, 0.0, 0.0)
    h = np.nan_to_num(np.asarray(height_mm, np.float64)[rows, cols])
    cx, cy = float(cols.mean()), float(rows.mean())
    if n >= 2:
        cov = np.cov(np.stack([cols, rows]).astype(np.float64))
        w, v = np.linalg.eigh(cov)
        w = np.clip(w, 0.0, None)
        axes = (2.0 * float(np.sqrt(w[1])), 2.0 * float(np.sqrt(w[0])))
        angle = float(np.arctan2(v[1, 1], v[0, 1]))
    else:
        axes, angle = (0.5, 0.5), 0.0
    xy = pixel_grid_to_sensor_xy(np.array([cy]), np.array([cx]), W, H, mm_per_px)[0]
    a_px = mm_per_px * mm_per_px
    return ContactStats(
        n,
        n * a_px,
        (cx, cy),
        (float(xy[0]), float(xy[1])),
        axes,
        angle,
        float(h.max()),
        float(h.mean()),
        float(h.sum() * a_px),
    )
