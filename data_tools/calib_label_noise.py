"""What share of presses can auto labels put within 2 px / 5 % of a HAND label? (issue #21, auto-label target)

    python data_tools/calib_label_noise.py [--n 48] [--draws 4000] [--json OUT.json]

The target asks for >= 90 % of presses with the detected centre within 2 px and the radius within 5 % of the
hand label on the shared GelSight set. The hand labels there are integers and scatter 1.33-1.35 px per axis
(four independent estimates, ``calib_label_agreement.py --geometry``; at least 1.10 px after the method's own
bias). This tool separates the detector's error from the reference's:

1. **Real set** (``../shared/data/gelsight_ball_presses``): the detector ``A``
   (:func:`vtrack.tactile.autolabel.detect_contact`) vs the hand labels, at edge placements 0.5 / 0.75, with
   and without the sub-pixel rim (``AutoLabelOptions.subpixel``).
2. **Simulated sets shaped like the real one** (640x480, 0.0295 mm/px, 2 mm ball, the real background; gel blur
   0.12 mm, the real rim's width, and 0.25 mm), where the circles are exact: the same detector scored
   - against the exact circles;
   - against "hand labels" made from the exact circles the way the real ones look (:data:`REFERENCES`): the
     exact circles rounded to whole pixels (the real hand labels are integers); per-axis Gaussian centre noise
     of 1.10 px (lower bound) or 1.33 px (measured) and radius noise of 2.4 % (the hat's estimate for the real
     hand radii), then rounded; ``--draws`` Monte-Carlo draws give the mean share,
     its 5-95 % range over draws, and the probability that a set of this size shows >= 90 %.
   - and an exact detector (the true circles themselves) against the same noisy references: the cap.

An evaluation tool (reads the true circles only to score). Prints a text report (and JSON with ``--json``).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

#: references built from the exact circles: (name, per-axis centre sd px, relative radius sd, rounded to px)
REFERENCES = (
    ("exact", 0.0, 0.0, False),
    ("exact, rounded to px", 0.0, 0.0, True),
    ("hand-like, lower bound (1.10 px, 2.4 %)", 1.10, 0.024, True),
    ("hand-like, measured (1.33 px, 2.4 %)", 1.33, 0.024, True),
)
BLURS_MM = (0.12, 0.25)


def _within(A: np.ndarray, R: np.ndarray) -> dict:
    """Shares of rows of ``A`` (x, y, r) within 2 px (centre), 5 % (radius) and both of the reference ``R``."""
    cen = np.hypot(A[:, 0] - R[:, 0], A[:, 1] - R[:, 1])
    rr = np.abs(A[:, 2] / R[:, 2] - 1.0)
    return {
        "centre_within_2px": float(np.mean(cen <= 2.0)),
        "radius_within_5pct": float(np.mean(rr <= 0.05)),
        "both": float(np.mean((cen <= 2.0) & (rr <= 0.05))),
    }


def noisy_reference_shares(
    A: np.ndarray,
    T: np.ndarray,
    sd_px: float,
    radius_sd: float,
    rounded: bool,
    draws: int,
    rng: np.random.Generator,
    name: str = "",
) -> dict:
    """Share 'both' of detections ``A`` (N, 3) against references made from the exact circles ``T`` (N, 3)
    with per-axis centre noise ``sd_px``, relative radius noise ``radius_sd`` and (``rounded``) rounding to whole
    pixels, over ``draws`` draws (one when the reference is deterministic): mean, 5 / 95 % of the draws and the
    probability of a share >= 90 %."""
    n = len(T)
    draws = draws if sd_px > 0 or radius_sd > 0 else 1
    both = np.empty(draws)
    for k in range(draws):
        R = T.copy()
        R[:, :2] += rng.normal(0.0, sd_px, (n, 2))
        R[:, 2] *= 1.0 + rng.normal(0.0, radius_sd, n)
        both[k] = _within(A, np.rint(R) if rounded else R)["both"]
    return {
        "reference": name,
        "sd_px": sd_px,
        "radius_sd": radius_sd,
        "both_mean": float(both.mean()),
        "both_p5": float(np.percentile(both, 5)),
        "both_p95": float(np.percentile(both, 95)),
        "p_at_least_90": float(np.mean(both >= 0.9)),
    }


def _detect(ps, weight: float, subpixel: bool) -> tuple[np.ndarray, np.ndarray]:
    from vtrack.tactile.autolabel import AutoLabelOptions, detect_contact

    bg = ps.background()
    o = AutoLabelOptions(edge_weight=weight, subpixel=subpixel)
    dets = [detect_contact(ps.image(p), bg, ps.ball_radius_px, p.file, o) for p in ps.presses]
    A = np.array([[d.center_x_px, d.center_y_px, d.contact_radius_px] for d in dets])
    return A, np.array([d.ok for d in dets])


def real_rows(weights=(0.5, 0.75)) -> list[dict]:
    """Detector vs the hand labels of the shared real set (empty without ``../shared``)."""
    from vtrack.paths import shared_data_dir
    from vtrack.tactile.pressset import load_press_set

    root = shared_data_dir() / "gelsight_ball_presses"
    if not (root / "labels.csv").is_file():
        return []
    ps = load_press_set(root, labels="hand")
    H = np.array([[*p.center_xy_px, p.contact_radius_px] for p in ps.presses])
    rows = []
    for w in weights:
        for sub in (False, True):
            A, ok = _detect(ps, w, sub)
            rows.append(
                {
                    "set": "shared real GelSight",
                    "edge_weight": w,
                    "subpixel": sub,
                    "n_used": int(ok.sum()),
                    "n": len(ok),
                    "hand_labels_integer": bool(np.all(H == np.rint(H))),
                    **_within(A[ok], H[ok]),
                }
            )
    return rows


def sim_rows(n: int, draws: int, seed: int = 9, weights=(0.5, 0.75)) -> list[dict]:
    """Detector vs exact and vs noisy references on simulated real-like sets (see the module docstring)."""
    from dataclasses import replace

    from vtrack.paths import shared_data_dir
    from vtrack.sim.presses import render_press_set
    from vtrack.sim.tactile_optics import OpticalModel
    from vtrack.tactile.pressset import load_press_set

    bg = None
    real = shared_data_dir() / "gelsight_ball_presses" / "background.png"
    if real.is_file():
        import cv2

        bg = cv2.imread(str(real), cv2.IMREAD_COLOR)
    rng = np.random.default_rng(seed)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for blur in BLURS_MM:
            model = replace(OpticalModel.for_sensor("gelsight", seed), blur_mm=blur)
            d = render_press_set("gelsight", Path(tmp) / f"b{blur}", n=n, seed=seed, model=model, background=bg)
            ps = load_press_set(d, labels="hand")
            T = np.array([[*p.center_xy_px, p.contact_radius_px] for p in ps.presses])
            for w in weights:
                for sub in (False, True):
                    A, ok = _detect(ps, w, sub)
                    row = {
                        "set": f"sim GelSight, blur {blur} mm",
                        "blur_mm": blur,
                        "edge_weight": w,
                        "subpixel": sub,
                        "n_used": int(ok.sum()),
                        "n": len(ok),
                        "vs_exact": _within(A[ok], T[ok]),
                        "centre_sd_px": [
                            float(1.4826 * np.median(np.abs(c - np.median(c)))) for c in (A[ok, :2] - T[ok, :2]).T
                        ],
                        "radius_median_pct": float(100 * np.median(A[ok, 2] / T[ok, 2] - 1.0)),
                        "vs_noisy": [
                            noisy_reference_shares(A[ok], T[ok], s, rs, rd, draws, rng, nm)
                            for nm, s, rs, rd in REFERENCES
                        ],
                    }
                    rows.append(row)
            # the cap: an exact detector against the same noisy references
            rows.append(
                {
                    "set": f"sim GelSight, blur {blur} mm",
                    "blur_mm": blur,
                    "detector": "exact (the true circles)",
                    "n": len(T),
                    "vs_noisy": [
                        noisy_reference_shares(T, T, s, rs, rd, draws, rng, nm) for nm, s, rs, rd in REFERENCES
                    ],
                }
            )
    return rows


def _report(real: list[dict], sim: list[dict]) -> str:
    lines = ["real set: placement | subpixel | used | centre <= 2 px | radius <= 5 % | both"]
    for r in real:
        lines.append(
            f"  {r['edge_weight']:.2f} | {r['subpixel']} | {r['n_used']}/{r['n']} | "
            f"{100 * r['centre_within_2px']:.0f} % | {100 * r['radius_within_5pct']:.0f} % | {100 * r['both']:.0f} %"
        )
    lines.append("sim: set | detector | vs exact both | vs references (sd px: mean both [p5-p95], P(>=90 %))")
    for r in sim:
        det = r.get("detector") or f"A {r['edge_weight']:.2f}{' sub' if r['subpixel'] else ''}"
        ex = f"{100 * r['vs_exact']['both']:.0f} %" if "vs_exact" in r else "100 %"
        noisy = "; ".join(
            f"{v['sd_px']:.2f}: {100 * v['both_mean']:.0f} [{100 * v['both_p5']:.0f}-{100 * v['both_p95']:.0f}], "
            f"{100 * v['p_at_least_90']:.0f} %"
            for v in r["vs_noisy"]
        )
        lines.append(f"  {r['set']} | {det} | {ex} | {noisy}")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=48)
    ap.add_argument("--draws", type=int, default=4000)
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args()
    from vtrack.threads import limit_threads

    limit_threads(1)
    real = real_rows()
    sim = sim_rows(a.n, a.draws)
    print(_report(real, sim))
    if a.json:
        from vtrack.io.jsonio import write_json

        cmd = f"python data_tools/calib_label_noise.py --n {a.n} --draws {a.draws}"
        write_json(a.json, {"command": cmd, "real": real, "sim": sim})


if __name__ == "__main__":
    main()
