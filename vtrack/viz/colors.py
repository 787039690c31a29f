"""Colour schemes for fused clouds and tactile panels (uint8 RGB, numpy only).

Colour maps are small lookup tables sampled once from matplotlib (imported lazily) so that
colouring 1 M points costs one vectorised table lookup.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

#: Modality colours: vision points steel blue, touch points orange.
VISION_RGB = (70, 130, 180)
TOUCH_RGB = (255, 140, 0)
#: Points without a value in the chosen scheme (e.g. vision points when colouring by tactile value).
NEUTRAL_RGB = (150, 150, 150)

COLOR_MODES = ("modality", "time", "tactile value", "confidence", "sensor", "rgb")


@lru_cache(maxsize=16)
def lut(name: str, n: int = 256) -> np.ndarray:
    """(n, 3) uint8 table of a matplotlib colour map."""
    import matplotlib

    cmap = matplotlib.colormaps[name].resampled(n)
    return (cmap(np.linspace(0.0, 1.0, n))[:, :3] * 255.0 + 0.5).astype(np.uint8)


def scalar_colors(
    values: np.ndarray, vmin: float | None = None, vmax: float | None = None, cmap: str = "viridis"
) -> np.ndarray:
    """Map values to (N, 3) uint8 colours; NaN/Inf get :data:`NEUTRAL_RGB`; a constant field maps to the
    middle of the map (never divides by zero)."""
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    finite = np.isfinite(v)
    out = np.empty((len(v), 3), dtype=np.uint8)
    out[:] = NEUTRAL_RGB
    if not finite.any():
        return out
    lo = float(np.min(v[finite])) if vmin is None else float(vmin)
    hi = float(np.max(v[finite])) if vmax is None else float(vmax)
    table = lut(cmap)
    if not np.isfinite(lo) or not np.isfinite(hi) or hi - lo <= 1e-12:
        out[finite] = table[len(table) // 2]
        return out
    x = np.clip((v[finite] - lo) / (hi - lo), 0.0, 1.0)
    out[finite] = table[np.minimum((x * (len(table) - 1) + 0.5).astype(np.int64), len(table) - 1)]
    return out


def modality_colors(modality: np.ndarray) -> np.ndarray:
    """0 = vision -> :data:`VISION_RGB`, 1 = touch -> :data:`TOUCH_RGB`, other -> neutral."""
    m = np.asarray(modality).reshape(-1)
    out = np.empty((len(m), 3), dtype=np.uint8)
    out[:] = NEUTRAL_RGB
    out[m == 0] = VISION_RGB
    out[m == 1] = TOUCH_RGB
    return out


def categorical_colors(ids: np.ndarray) -> np.ndarray:
    """Distinct colours for small integer ids (tab10, cycling)."""
    table = lut("tab10", 10)
    i = np.asarray(ids).reshape(-1).astype(np.int64)
    return table[np.mod(i, 10)]


def colorize_height(height_mm: np.ndarray, vmax_mm: float) -> np.ndarray:
    """(H, W, 3) uint8 image of a height map (mm), 0 .. ``vmax_mm`` on 'inferno'; NaN black."""
    h = np.asarray(height_mm, dtype=np.float64)
    img = scalar_colors(h.reshape(-1), 0.0, max(float(vmax_mm), 1e-6), cmap="inferno").reshape(*h.shape, 3)
    img[~np.isfinite(h)] = 0
    return img


def mask_image(mask: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8: contact white on black."""
    m = np.asarray(mask).astype(bool)
    return np.repeat((m * 255).astype(np.uint8)[..., None], 3, axis=2)
