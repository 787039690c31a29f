"""``vtrack bench simreal``: how close the simulator's tactile optics come to real GelSight presses.

Each labelled real press of the shared set (``gelsight_ball_presses``: 640x480, 0.0295 mm/px, 2.00 mm ball)
is re-rendered from its ball geometry alone (depth from the labelled contact radius ``a``:
``d = R - sqrt(R^2 - a^2)``) on the real background with the GelSight preset of
:mod:`vtrack.sim.tactile_optics`, without camera noise. A box of +-2 contact radii around the press is
compared with the real image by MSE (grey levels^2, all channels) and SSIM (Gaussian window, sigma 1.5 px,
mean over channels), against a background-only baseline (the real background crop vs the real image, i.e.
"no colour change rendered at all").

Rows: the nominal preset, and the preset with its LED parameters (azimuth, elevation, gain per LED) plus
elastomer blur and specular weight fitted by least squares on the TRAINING half of the presses (even
indices, at 1/4 resolution); every row is scored on the held-out odd-index presses only.
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.bench.harness import BenchTable


def ssim(a: np.ndarray, b: np.ndarray, sigma: float = 1.5) -> float:
    """Mean SSIM (Wang et al. 2004, 8-bit constants, Gaussian window) of two images (mean over channels)."""
    import cv2

    x, y = np.asarray(a, np.float32), np.asarray(b, np.float32)
    c1, c2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2

    def blur(z: np.ndarray) -> np.ndarray:
        return cv2.GaussianBlur(z, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)

    mx, my = blur(x), blur(y)
    sxx, syy, sxy = blur(x * x) - mx * mx, blur(y * y) - my * my, blur(x * y) - mx * my
    s = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
    return float(s.mean())


def _crop_box(press: Any, shape: tuple[int, int], scale: float = 1.0, k: float = 2.0) -> tuple[slice, slice]:
    H, W = shape
    cx, cy = press.center_xy_px[0] / scale, press.center_xy_px[1] / scale
    r = k * press.contact_radius_px / scale
    return (
        slice(max(0, int(cy - r)), min(H, int(np.ceil(cy + r)) + 1)),
        slice(max(0, int(cx - r)), min(W, int(np.ceil(cx + r)) + 1)),
    )


def _frames(ps: Any, presses: list, scale: int) -> tuple[np.ndarray, list[tuple[Any, np.ndarray]]]:
    import cv2

    def down(img: np.ndarray) -> np.ndarray:
        if scale == 1:
            return img
        H, W = img.shape[:2]
        return cv2.resize(img, (W // scale, H // scale), interpolation=cv2.INTER_AREA)

    return down(ps.background()), [(p, down(ps.image(p))) for p in presses]


def render_press(model: Any, ps: Any, press: Any, background: np.ndarray, scale: int = 1) -> np.ndarray:
    """Noise-free rendering (uint8 BGR) of a labelled real press from its ball geometry alone."""
    from vtrack.sim.presses import ball_height, press_depth_mm

    mpp = ps.mm_per_px * scale
    d = press_depth_mm(ps.ball_radius_mm, press.contact_radius_px * ps.mm_per_px)
    c = (press.center_xy_px[0] / scale, press.center_xy_px[1] / scale)
    h = ball_height(background.shape[:2], c, ps.ball_radius_mm, d, mpp)
    return model.render(h, mpp, background, rng=None)


def score(model: Any, ps: Any, presses: list, scale: int = 1) -> dict[str, float]:
    """Median crop MSE / SSIM of the rendering and of the background-only baseline, and ms per render."""
    bg, frames = _frames(ps, presses, scale)
    rows = []
    for p, real in frames:
        t0 = time.perf_counter()
        sim = render_press(model, ps, p, bg, scale)
        ms = (time.perf_counter() - t0) * 1e3
        sl = _crop_box(p, bg.shape[:2], scale)
        r, s, b = (x[sl].astype(np.float32) for x in (real, sim, bg))
        rows.append(
            {
                "mse": float(((s - r) ** 2).mean()),
                "ssim": ssim(s, r),
                "mse_bg": float(((b - r) ** 2).mean()),
                "ssim_bg": ssim(b, r),
                "ms": ms,
            }
        )
    return {k: float(np.median([x[k] for x in rows])) for k in rows[0]} | {"n_presses": len(rows)}


_PARAMS_PER_LIGHT = 3  # azimuth (deg), elevation (deg), gain


def fit_lights(model: Any, ps: Any, presses: list, scale: int = 4, max_nfev: int = 60) -> Any:
    """Fit LED azimuth/elevation/gain, elastomer blur and specular weight to real presses (least squares on
    the +-2 contact-radius crops at 1/``scale`` resolution, noise-free renders). Returns a new model."""
    from scipy.optimize import least_squares

    bg, frames = _frames(ps, presses, scale)
    bg_f = bg.astype(np.float32)
    crops = [(p, _crop_box(p, bg.shape[:2], scale), real.astype(np.float32)) for p, real in frames]
    heights = []
    from vtrack.sim.presses import ball_height, press_depth_mm

    mpp = ps.mm_per_px * scale
    for p, _, _ in crops:
        d = press_depth_mm(ps.ball_radius_mm, p.contact_radius_px * ps.mm_per_px)
        heights.append(
            ball_height(bg.shape[:2], (p.center_xy_px[0] / scale, p.center_xy_px[1] / scale), ps.ball_radius_mm, d, mpp)
        )

    def build(x: np.ndarray) -> Any:
        lights = [
            replace(li, azimuth_deg=float(x[3 * i]), elevation_deg=float(x[3 * i + 1]), gain=float(x[3 * i + 2]))
            for i, li in enumerate(model.lights)
        ]
        m = model.with_lights(lights)
        m.blur_mm, m.ks = float(x[-2]), float(x[-1])
        return m

    def resid(x: np.ndarray) -> np.ndarray:
        m = build(x)
        out = []
        geom_v = None
        for (_, sl, real), h in zip(crops, heights, strict=True):
            cc = m.colour_change(h, mpp)
            if geom_v is None:
                geom_v = m._geometry(h.shape, mpp)["vignette"][..., None]
            sim = bg_f[sl] + geom_v[sl] * cc[sl]  # float, unquantised: smooth objective
            out.append(((sim - real[sl]) / 16.0).ravel())
        return np.concatenate(out)

    x0 = np.array(
        [v for li in model.lights for v in (li.azimuth_deg, li.elevation_deg, li.gain)] + [model.blur_mm, model.ks]
    )
    lo = np.array([v for li in model.lights for v in (li.azimuth_deg - 90, 10.0, 0.0)] + [0.0, 0.0])
    hi = np.array([v for li in model.lights for v in (li.azimuth_deg + 90, 80.0, 400.0)] + [1.0, 1.0])
    sol = least_squares(resid, np.clip(x0, lo, hi), bounds=(lo, hi), x_scale="jac", diff_step=1e-3, max_nfev=max_nfev)
    return build(sol.x)


def run(quick: bool = False, press_dir: str | Path | None = None) -> BenchTable:
    """Sim-vs-real rows (background-only baseline, preset, fitted preset) on the held-out odd presses."""
    from vtrack.errors import InputError
    from vtrack.paths import shared_data_dir
    from vtrack.sim.tactile_optics import OpticalModel
    from vtrack.tactile.pressset import load_press_set

    root = Path(press_dir) if press_dir is not None else shared_data_dir() / "gelsight_ball_presses"
    if not (root / "labels.csv").is_file():
        raise InputError("real GelSight press set not found", path=root, expected="labels.csv + images")
    ps = load_press_set(root)
    train = [p for p in ps.presses if p.index % 2 == 0]
    test = [p for p in ps.presses if p.index % 2 == 1]
    if quick:
        train, test = train[:8], test[:8]
    table = BenchTable(stage="simreal", error_key="mse")
    preset = OpticalModel.for_sensor("gelsight")
    t0 = time.perf_counter()
    fitted = fit_lights(preset, ps, train, max_nfev=25 if quick else 60)
    fit_s = time.perf_counter() - t0
    s_pre = score(preset, ps, test)
    s_fit = score(fitted, ps, test)
    table.add(
        method="background only",
        setting="real background crop",
        ms=0.0,
        mse=s_pre["mse_bg"],
        ssim=s_pre["ssim_bg"],
        n_test=s_pre["n_presses"],
    )
    table.add(
        method="optics preset",
        setting="gelsight, nominal",
        ms=s_pre["ms"],
        mse=s_pre["mse"],
        ssim=s_pre["ssim"],
        n_test=s_pre["n_presses"],
    )
    table.add(
        method="optics fitted",
        setting=f"LEDs+blur+ks fitted on {len(train)} train presses ({fit_s:.0f} s)",
        ms=s_fit["ms"],
        mse=s_fit["mse"],
        ssim=s_fit["ssim"],
        n_test=s_fit["n_presses"],
    )
    lights = "; ".join(f"az {li.azimuth_deg:.0f} el {li.elevation_deg:.0f} gain {li.gain:.0f}" for li in fitted.lights)
    table.notes += [
        f"Real set {root.name}: {ps.shape[1]}x{ps.shape[0]}, {ps.mm_per_px} mm/px, ball {ps.ball_radius_mm} mm; "
        f"train = even-index presses ({len(train)}), scored on odd-index presses ({len(test)}) only.",
        "Crop: +-2 contact radii around the labelled centre; MSE in grey levels^2 (median over presses), SSIM "
        "Gaussian sigma 1.5 px; renders are noise-free; ms = one 640x480 render.",
        f"Fitted LEDs (R, G, B): {lights}; blur {fitted.blur_mm:.3f} mm, ks {fitted.ks:.3f}.",
        "Command: `vtrack bench simreal` (`--quick`: 8 train / 8 test presses).",
    ]
    return table


def session_tactile_accuracy(session: str | Path, max_frames: int = 0) -> dict[str, Any]:
    """Tactile pipeline on a synthetic session's images vs its ``gt/tactile/<sensor>`` (scoring only).

    The pipeline is built from the session's embedded scene (``TactilePipeline.from_scene``), i.e. with the
    calibration the session carries. Pooled over sensors and frames: median absolute height error (mm) on
    ground-truth contact pixels, contact-mask IoU, and median normal error (deg; normals from the height
    gradients of both maps) on ground-truth contact pixels. ``max_frames`` > 0 keeps that many frames per
    sensor (evenly spaced).
    """
    from vtrack.io.session import open_session
    from vtrack.tactile.pipeline import TactilePipeline

    r = open_session(session)
    sc = r.scene()
    pipe = TactilePipeline.from_scene(sc)
    herr, nerr, inter, union, n_frames = [], [], 0, 0, 0
    for t in sc.tactile:
        if t.type == "dome" or f"tactile/{t.name}" not in r.streams:
            continue
        p = pipe.for_sensor(t.name)
        imgs, gt = r.streams[f"tactile/{t.name}"], r.streams[f"gt/tactile/{t.name}"]
        n = len(imgs)
        idx = np.arange(n) if max_frames <= 0 or n <= max_frames else np.linspace(0, n - 1, max_frames).astype(int)
        for i in idx:
            fr = p.process(imgs["image"][int(i)])
            h_gt = np.asarray(gt["height_mm"][int(i)], np.float64)
            c_gt = np.asarray(gt["contact"][int(i)]).astype(bool)
            h = np.nan_to_num(np.asarray(fr.height_mm, np.float64))
            inter += int((fr.contact & c_gt).sum())
            union += int((fr.contact | c_gt).sum())
            n_frames += 1
            if c_gt.sum() == 0:
                continue
            herr.append(np.abs(h - h_gt)[c_gt])
            gy, gx = np.gradient(h, t.mm_per_px)
            ty, tx = np.gradient(h_gt, t.mm_per_px)
            n1 = np.stack([-gx[c_gt], -gy[c_gt], np.ones(c_gt.sum())], 1)
            n2 = np.stack([-tx[c_gt], -ty[c_gt], np.ones(c_gt.sum())], 1)
            cosang = (n1 * n2).sum(1) / np.linalg.norm(n1, axis=1) / np.linalg.norm(n2, axis=1)
            nerr.append(np.degrees(np.arccos(np.clip(cosang, -1.0, 1.0))))
    he = np.concatenate(herr) if herr else np.zeros(0)
    ne = np.concatenate(nerr) if nerr else np.zeros(0)
    return {
        "frames": n_frames,
        "contact_pixels": int(he.size),
        "height_err_mm_median": float(np.median(he)) if he.size else float("nan"),
        "contact_iou": inter / union if union else float("nan"),
        "normal_err_deg_median": float(np.median(ne)) if ne.size else float("nan"),
    }
