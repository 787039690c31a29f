"""Simulated ball-press calibration sets and per-sensor calibrations from them.

A simulated sensor is calibrated exactly like a real one: ball presses are rendered with the independent
optical model (:mod:`vtrack.sim.tactile_optics`), written in the press-set format that ``vtrack calibrate``
reads (:mod:`vtrack.tactile.pressset`), labelled with the visible contact circle a person would click
(from the ball geometry, not from the renderer), and calibrated by the same code path as
``vtrack calibrate`` (:func:`vtrack.tactile.calibration.calibrate`, method ``mlp``, hold-out ``every:4:3``).
The pipeline only ever sees the resulting ``.npz``; it never reads the renderer's internals.
"""

from __future__ import annotations

import csv
import hashlib
import json
import os
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError

#: The simulated sensors' calibration model: the MLP, the library default (``vtrack calibrate``'s CLI default is
#: ``auto``, a cross-validated choice that costs minutes; the simulator calibrates every sensor of every scene).
DEFAULT_METHOD = "mlp"
DEFAULT_HOLDOUT = "every:4:3"
#: Ball radius of the simulated calibration presses per sensor type (mm): a 6 mm ball on the small DIGIT
#: gel gives contact circles of 15-30 px at 0.09 mm/px; 4 mm as in the real GelSight set otherwise.
BALL_RADIUS_MM = {"digit": 3.0, "gelsight": 2.0, "gelsight_mini": 2.0}
#: Presses per simulated calibration set: 60 over the whole gel (the mean contact height of a large object
#: pressed on a DIGIT's edge went from 0.56 to 0.8 of the truth against 30 presses in the centre).
SIM_PRESSES = 60


def sensor_seed(name: str) -> int:
    """Stable per-unit seed of a sensor name (its optical jitter; independent of the session seed so the
    same physical sensor is calibrated once)."""
    return int(zlib.crc32(name.encode("utf-8")))


def ball_height(
    shape_hw: tuple[int, int], centre_xy_px: tuple[float, float], radius_mm: float, depth_mm: float, mm_per_px: float
) -> np.ndarray:
    """Indentation (mm, (H, W) float32) of a ball of ``radius_mm`` pressed ``depth_mm`` into a flat gel."""
    H, W = shape_hw
    yy, xx = np.mgrid[0:H, 0:W]
    rho2 = ((xx - centre_xy_px[0]) ** 2 + (yy - centre_xy_px[1]) ** 2) * mm_per_px**2
    h = np.sqrt(np.clip(radius_mm**2 - rho2, 0.0, None)) - (radius_mm - depth_mm)
    return np.clip(h, 0.0, None).astype(np.float32)


def contact_radius_mm(radius_mm: float, depth_mm: float) -> float:
    """Radius of the visible contact circle of a ball pressed ``depth_mm`` into a flat gel (mm)."""
    return float(np.sqrt(max(0.0, 2.0 * radius_mm * depth_mm - depth_mm**2)))


def press_depth_mm(ball_radius_mm: float, contact_radius_mm: float) -> float:
    """Indentation depth (mm) of a ball whose visible contact circle has radius ``contact_radius_mm``
    (the inverse of :func:`contact_radius_mm`)."""
    a = min(contact_radius_mm, 0.999 * ball_radius_mm)
    return float(ball_radius_mm - np.sqrt(ball_radius_mm**2 - a**2))


def render_press_set(
    sensor_type: str,
    out_dir: str | Path,
    *,
    n: int = 30,
    ball_radius_mm: float | None = None,
    mm_per_px: float | None = None,
    width: int | None = None,
    height: int | None = None,
    background: np.ndarray | None = None,
    seed: int = 0,
    model: Any = None,
    depth_frac: tuple[float, float] = (0.15, 0.45),
    noise: float = 1.0,
) -> Path:
    """Render ``n`` ball presses at random positions/depths and write a press set (see module docstring).

    Args:
        sensor_type: digit | gelsight | gelsight_mini (optical preset; also ``meta.json`` ``sensor``).
        out_dir: folder to (over)write: ``background.png``, ``press_XX.png``, ``labels.csv``, ``meta.json``.
        ball_radius_mm: ball radius (default per sensor type, :data:`BALL_RADIUS_MM`).
        mm_per_px, width, height: pixel pitch (mm) and image size (px); default: the sensor type's preset
            (:data:`vtrack.tactile.sensors.SENSOR_PRESETS`: stored size, nominal pitch at that size).
        background: real no-contact BGR frame of (height, width) (default: the generator's choice).
        seed: press positions/depths and camera noise; also the unit's optical jitter when ``model`` is None.
        model: an :class:`~vtrack.sim.tactile_optics.OpticalModel` (default ``for_sensor(sensor_type, seed)``).
        depth_frac: press depth range as a fraction of the ball radius.
        noise: camera-noise scale.

    Returns:
        the press-set folder.
    """
    import cv2

    from vtrack.sim.tactile_optics import OpticalModel

    if n < 4:
        raise InputError("a press set needs at least 4 presses", field="n", expected=">= 4", got=n)
    if width is None or height is None or mm_per_px is None:
        from vtrack.tactile.sensors import sensor_preset

        preset = sensor_preset(sensor_type, "sensor_type")
        if width is None or height is None:
            width, height = preset.stored_size
        if mm_per_px is None:
            mm_per_px = preset.pitch_at(width, height)
    if not (width > 0 and height > 0 and np.isfinite(mm_per_px) and mm_per_px > 0):
        raise InputError(
            "bad sensor geometry", field="width/height/mm_per_px", expected="> 0", got=(width, height, mm_per_px)
        )
    R = float(ball_radius_mm if ball_radius_mm is not None else BALL_RADIUS_MM.get(sensor_type, 2.0))
    model = model if model is not None else OpticalModel.for_sensor(sensor_type, seed)
    if background is None:
        from vtrack.tactile.sensors import default_background

        background = default_background(sensor_type, width, height)
    bg = np.asarray(background)
    if bg.shape != (height, width, 3):
        raise InputError(
            "background size differs from the sensor", field="background", expected=f"{height}x{width}x3", got=bg.shape
        )
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    # the no-contact capture a person would take (real background + this camera's noise)
    cv2.imwrite(
        str(out / "background.png"), model.render(np.zeros((height, width), np.float32), mm_per_px, bg, rng, noise)
    )
    rows = []
    for i in range(n):
        d = float(rng.uniform(*depth_frac)) * R
        a_px = contact_radius_mm(R, d) / mm_per_px
        # Presses cover the WHOLE gel, up to partial ones at the edges (about half of the circle or more in
        # view), as a careful user rolls the ball over all of it: a calibration that never saw the border
        # (the old margin kept centres a radius + 5 % inside) read contacts there at a fifth of their depth,
        # and the large objects of the sessions touch the gel's edges in almost every frame.
        margin = 0.3 * a_px
        if 2 * (a_px + margin) >= min(width, height):
            raise InputError("ball too large for the sensor image", field="ball_radius_mm", got=R)
        cx = float(rng.uniform(margin, width - margin))
        cy = float(rng.uniform(margin, height - margin))
        img = model.render(ball_height((height, width), (cx, cy), R, d, mm_per_px), mm_per_px, bg, rng, noise)
        name = f"press_{i:02d}.png"
        cv2.imwrite(str(out / name), img)
        rows.append((name, round(cx, 2), round(cy, 2), round(a_px, 2)))
    with open(out / "labels.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["file", "center_x_px", "center_y_px", "contact_radius_px"])
        w.writerows(rows)
    (out / "meta.json").write_text(
        json.dumps(
            {
                "sensor": sensor_type,
                "mm_per_px": float(mm_per_px),
                "ball_radius_mm": R,
                "simulated": True,
                "seed": seed,
            },
            indent=1,
        )
    )
    return out


def _file_digest(path: Path) -> str:
    return hashlib.sha1(path.read_bytes()).hexdigest()[:12] if path.is_file() else "none"


def sensor_calibration(
    spec: Any,
    seed: int | None = None,
    *,
    n: int = SIM_PRESSES,
    method: str = DEFAULT_METHOD,
    holdout: str = DEFAULT_HOLDOUT,
) -> Path:
    """Calibration ``.npz`` of a simulated sensor (a scene's ``TactileSpec``), trained like ``vtrack calibrate``.

    Renders a press set with the sensor's optical model (unit jitter ``seed``, default
    :func:`sensor_seed` of ``spec.name``) on the generator's background into the cache, calibrates it with
    :func:`vtrack.tactile.calibration.calibrate` (``method``, ``holdout`` as the CLI defaults) and saves the
    result under ``cache_dir()/sim_calib``, keyed by the optics/press code, the spec, the background
    content and the options (a second call returns the cached file).
    """
    from vtrack.paths import cache_dir
    from vtrack.sim.tactile_optics import optics_fingerprint
    from vtrack.tactile.calibration import TrainOptions, calibrate, options_key
    from vtrack.tactile.pressset import load_press_set
    from vtrack.tactile.sensors import default_background

    seed = sensor_seed(spec.name) if seed is None else int(seed)
    bg = default_background(spec.type, spec.width, spec.height, spec.background)
    opts = TrainOptions()
    key = json.dumps(
        {
            "optics": optics_fingerprint(),
            "presses": _file_digest(Path(__file__)),
            "type": spec.type,
            "w": spec.width,
            "h": spec.height,
            "mm_per_px": spec.mm_per_px,
            "bg": hashlib.sha1(np.ascontiguousarray(bg).tobytes()).hexdigest()[:12],
            "seed": seed,
            "n": n,
            "method": method,
            "holdout": holdout,
            "opts": options_key(opts),
        },
        sort_keys=True,
    )
    digest = hashlib.sha1(key.encode()).hexdigest()[:16]
    path = cache_dir() / "sim_calib" / f"{spec.type}_{digest}.npz"
    if path.is_file():
        return path
    ps_dir = render_press_set(
        spec.type,
        cache_dir() / "sim_presses" / digest,
        n=n,
        mm_per_px=spec.mm_per_px,
        width=spec.width,
        height=spec.height,
        background=bg,
        seed=seed,
    )
    ps = load_press_set(ps_dir)
    train, _ = ps.split(holdout)
    calib = calibrate(ps, method, train, opts)
    calib.info["holdout"] = holdout
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.npz")  # atomic: parallel generators may race here
    calib.save(tmp)
    os.replace(tmp, path)
    return path
