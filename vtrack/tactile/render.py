"""Inverse sensor model: render a tactile image from a height map (for the simulator).

Two models:
- with ``calib`` (a :class:`~vtrack.tactile.calibration.Calibration` or a path to one): the colour change
  is looked up from the calibration's gradient -> colour table (learned from the real ball presses);
- without: a three-light Lambertian model (one coloured light per channel, 120 deg apart in azimuth,
  like the classic GelSight R/G/B LED ring).

Frames/units: height in mm (indentation into the gel, >= 0), pixel pitch in mm/px; gradients are
dh/dx, dh/dy in mm/mm with x = image columns, y = image rows (see ``vtrack.geometry.tactile_frame``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError

#: Azimuth (deg, from +x towards +y) of the B, G, R lights (OpenCV channel order) of the Lambertian model.
LIGHT_AZIMUTH_DEG = (90.0, 210.0, 330.0)


def lambert_light_dirs(elevation_deg: float = 35.0) -> np.ndarray:
    """(3, 3) unit light directions for the B, G, R channels (sensor frame, z = out of the gel)."""
    el = np.deg2rad(elevation_deg)
    az = np.deg2rad(np.asarray(LIGHT_AZIMUTH_DEG))
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.full(3, np.sin(el))], axis=1)


def lambert_colour_delta(
    gx: np.ndarray, gy: np.ndarray, *, gain: float = 110.0, elevation_deg: float = 35.0
) -> np.ndarray:
    """(H, W, 3) colour change (BGR, grey levels) of a Lambertian gel with slopes (gx, gy) (mm/mm).

    The change is ``gain * (n . l_c - n0 . l_c)`` with ``n0 = (0, 0, 1)``, a flat gel renders the background.
    """
    L = lambert_light_dirs(elevation_deg)
    inv = 1.0 / np.sqrt(gx * gx + gy * gy + 1.0)
    n = np.stack([gx * inv, gy * inv, inv], axis=-1)
    return gain * (n @ L.T - L[:, 2])


_CALIB_CACHE: dict[tuple[str, float], Any] = {}


def _load_calibration(path: Path) -> Any:
    """Load a calibration once per (path, mtime): the simulator passes the path for every frame."""
    from vtrack.tactile.calibration import Calibration

    try:
        key = (str(path.resolve()), path.stat().st_mtime)
    except OSError:
        return Calibration.load(path)  # raises the clear "not found" error
    if key not in _CALIB_CACHE:
        if len(_CALIB_CACHE) > 8:
            _CALIB_CACHE.clear()
        _CALIB_CACHE[key] = Calibration.load(path)
    return _CALIB_CACHE[key]


def _as_bgr(background_bgr: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    import cv2

    bg = np.asarray(background_bgr)
    if bg.ndim == 2:
        bg = np.repeat(bg[..., None], 3, axis=2)
    if bg.ndim != 3 or bg.shape[2] != 3:
        raise InputError(
            "background must be an (H, W, 3) BGR image", field="background_bgr", expected="(H, W, 3)", got=bg.shape
        )
    bg = np.nan_to_num(bg.astype(np.float32), nan=0.0, posinf=255.0, neginf=0.0)
    if bg.shape[:2] != shape:
        bg = cv2.resize(bg, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)
    return bg


def render_tactile_image(
    height_mm: np.ndarray,
    mm_per_px: float,
    background_bgr: np.ndarray,
    calib: Any = None,
    rng: np.random.Generator | None = None,
    *,
    noise_std: float = 1.5,
    blur_px: float = 0.0,
    gain: float = 110.0,
    elevation_deg: float = 35.0,
) -> np.ndarray:
    """Render a uint8 BGR tactile image of a gel indented by ``height_mm``.

    Args:
        height_mm: (H, W) indentation in mm (>= 0; NaN/Inf are treated as 0).
        mm_per_px: pixel pitch on the gel, mm.
        background_bgr: no-contact image (any size; resized to (H, W)).
        calib: optional calibration (object or ``.npz`` path) with gradient->colour table; else Lambertian.
        rng: random generator for sensor noise (no noise when None).
        noise_std: Gaussian pixel noise, grey levels (only with ``rng``).
        blur_px: optional Gaussian blur of the height map (gel membrane smoothing), px.
        gain, elevation_deg: Lambertian model parameters (ignored with ``calib``).

    Returns:
        (H, W, 3) uint8 BGR image.
    """
    import cv2

    h = np.asarray(height_mm, dtype=np.float32)
    if h.ndim != 2 or h.size == 0:
        raise InputError("height map must be a non-empty 2-D array", field="height_mm", expected="(H, W)", got=h.shape)
    if not (np.isfinite(mm_per_px) and mm_per_px > 0):
        raise InputError("pixel pitch must be positive", field="mm_per_px", expected="> 0", got=mm_per_px)
    h = np.nan_to_num(h, nan=0.0, posinf=0.0, neginf=0.0)
    if blur_px > 0:
        h = cv2.GaussianBlur(h, (0, 0), blur_px)
    bg = _as_bgr(background_bgr, h.shape)
    if min(h.shape) > 1:
        gy, gx = np.gradient(h, float(mm_per_px))
    else:
        gx = gy = np.zeros_like(h)
    if calib is not None:
        if isinstance(calib, (str, Path)):
            calib = _load_calibration(Path(calib))
        delta = calib.colour_delta(gx, gy)
    else:
        delta = lambert_colour_delta(gx, gy, gain=gain, elevation_deg=elevation_deg)
    img = bg + delta.astype(np.float32)
    if rng is not None and noise_std > 0:
        img += rng.normal(0.0, noise_std, img.shape).astype(np.float32)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)
