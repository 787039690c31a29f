"""Synthetic tactile inputs for tests and benchmarks: ball indentations and marker patterns."""

from __future__ import annotations

import numpy as np


def sphere_height(
    h: int, w: int, cx: float, cy: float, ball_r_px: float, depth_px: float, mm_per_px: float
) -> np.ndarray:
    """(h, w) indentation (mm) of a ball of radius ``ball_r_px`` pressed ``depth_px`` deep at (cx, cy) px."""
    yy, xx = np.mgrid[0:h, 0:w]
    rho2 = (xx - cx) ** 2 + (yy - cy) ** 2
    z = np.sqrt(np.clip(ball_r_px**2 - rho2, 0, None)) - (ball_r_px - depth_px)
    return np.clip(z, 0, None) * mm_per_px


def marker_grid(h: int, w: int, pitch_px: float = 12.0, margin_px: float = 8.0) -> np.ndarray:
    """(N, 2) marker centres (x, y) on a regular grid."""
    xs = np.arange(margin_px, w - margin_px + 1e-9, pitch_px)
    ys = np.arange(margin_px, h - margin_px + 1e-9, pitch_px)
    X, Y = np.meshgrid(xs, ys)
    return np.column_stack([X.ravel(), Y.ravel()])


def draw_markers(
    image: np.ndarray, centres: np.ndarray, radius_px: float = 2.0, darkness: float = 80.0, ss: int = 4
) -> np.ndarray:
    """Darken anti-aliased discs (sub-pixel accurate via ``ss`` x supersampling) at ``centres`` (x, y)."""
    img = np.asarray(image, np.float32).copy()
    H, W = img.shape[:2]
    r = radius_px
    for cx, cy in np.asarray(centres, float):
        x0, x1 = max(int(np.floor(cx - r - 1)), 0), min(int(np.ceil(cx + r + 2)), W)
        y0, y1 = max(int(np.floor(cy - r - 1)), 0), min(int(np.ceil(cy + r + 2)), H)
        if x0 >= x1 or y0 >= y1:
            continue
        off = (np.arange(ss) + 0.5) / ss - 0.5
        ys = np.arange(y0, y1)[:, None] + off[None, :]
        xs = np.arange(x0, x1)[:, None] + off[None, :]
        inside = ((ys[:, None, :, None] - cy) ** 2 + (xs[None, :, None, :] - cx) ** 2) <= r * r
        cover = inside.mean(axis=(2, 3))
        if img.ndim == 3:
            img[y0:y1, x0:x1] -= darkness * cover[..., None]
        else:
            img[y0:y1, x0:x1] -= darkness * cover
    return np.clip(img, 0, 255).astype(np.uint8)
