"""The tactile sensor frame shared by the simulator, the tactile pipeline and fusion.

Sensor frame (``sensor/<name>``), metres:
- origin at the centre of the undeformed gel surface;
- ``z`` = outward gel normal (from the sensor towards the touched object);
- ``x`` = image column direction (u, to the right), ``y`` = image row direction (v, down).

A height map ``h`` (mm, >= 0) is the indentation of the gel surface *into* the sensor at each
pixel, so the contact surface point of pixel (row, col) is
``((col - (W-1)/2) * s, (row - (H-1)/2) * s, -h / 1000)`` with ``s = mm_per_px / 1000``.
The surface normal (pointing out of the gel, towards the object) from height gradients is
``normalize([dh/dx, dh/dy, 1])`` with gradients in mm/mm (the surface is ``z = -h``).
"""

from __future__ import annotations

import numpy as np

from vtrack.errors import InputError
from vtrack.geometry.pixels import mask_pixels
from vtrack.geometry.pointcloud import row_norms


def pixel_grid_to_sensor_xy(
    rows: np.ndarray, cols: np.ndarray, width: int, height: int, mm_per_px: float
) -> np.ndarray:
    """(N, 2) sensor-frame x, y in metres of pixel (row, col) centres."""
    s = mm_per_px / 1000.0
    return np.stack(
        [
            (np.asarray(cols, np.float64) - (width - 1) / 2.0) * s,
            (np.asarray(rows, np.float64) - (height - 1) / 2.0) * s,
        ],
        axis=-1,
    )


def height_to_points(
    height_mm: np.ndarray, mm_per_px: float, mask: np.ndarray | None = None, stride: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    """Lift a height map to sensor-frame contact points (m) and their outward normals.

    Args:
        height_mm: (H, W) indentation in mm (NaN/Inf pixels are dropped).
        mm_per_px: pixel pitch on the gel, mm.
        mask: optional (H, W) boolean; only these pixels are lifted (e.g. the contact mask).
        stride: keep every ``stride``-th row/column.

    Returns:
        points (N, 3) and unit normals (N, 3), both in the sensor frame.
    """
    h = np.asarray(height_mm, dtype=np.float64)
    if h.ndim != 2:
        raise InputError("height map must be 2-D", field="height_mm", expected="(H, W)", got=h.shape)
    H, W = h.shape
    finite = np.isfinite(h)
    hz = np.where(finite, h, 0.0)
    keep = finite
    if mask is not None:
        m = np.asarray(mask, dtype=bool)
        if m.shape != h.shape:
            raise InputError("mask size differs from the height map", field="mask", expected=str(h.shape), got=m.shape)
        keep = keep & m
    stride = max(1, int(stride))
    rows, cols = mask_pixels(keep[::stride, ::stride])
    rows, cols = rows * stride, cols * stride
    # the gradient only where it is read (a strided subset of the crop); none on a single row or column
    if min(H, W) > 1:
        gy, gx = gradient_at(hz, rows, cols, 0, mm_per_px), gradient_at(hz, rows, cols, 1, mm_per_px)
    else:
        gy = gx = np.zeros(len(rows))
    xy = pixel_grid_to_sensor_xy(rows, cols, W, H, mm_per_px)
    pts = np.concatenate([xy, -hz[rows, cols, None] / 1000.0], axis=1)
    n = np.stack([gx, gy, np.ones(len(rows))], axis=-1)
    n /= row_norms(n)[:, None]
    return pts, n


def gradient_at(f: np.ndarray, rows: np.ndarray, cols: np.ndarray, axis: int, spacing: float) -> np.ndarray:
    """``np.gradient(f, spacing)[axis][rows, cols]`` of a 2-D float64 array, computed at those pixels only (the same
    floats: central differences ``(f[i+1] - f[i-1]) / (2 spacing)`` inside, one-sided ``(f[1] - f[0]) / spacing`` at
    the borders; ``f`` needs 2 samples or more along ``axis``)."""
    n = f.shape[axis]
    i = rows if axis == 0 else cols
    hi, lo = np.minimum(i + 1, n - 1), np.maximum(i - 1, 0)
    num = f[hi, cols] - f[lo, cols] if axis == 0 else f[rows, hi] - f[rows, lo]
    return num / np.where((i > 0) & (i < n - 1), 2.0 * spacing, spacing)
