"""How far can automatic contact circles agree with hand labels? (issue #21, target: >= 90 % of presses within
2 px (centre) and 5 % (radius) of the hand label.)

    python data_tools/calib_label_agreement.py SET [--sim] [--json OUT.json]

Compares three estimates of every press's contact circle:
- ``H``: the labels in ``SET/labels.csv`` (hand labels on a real set; the true circles on a simulated one);
- ``A``: :func:`vtrack.tactile.autolabel.detect_contact` (rim along rays, robust circle fit), at edge
  placements 0.25 / 0.5 / 0.75;
- ``B``: a second centre estimate sharing no step with ``A``'s rim search: sub-pixel phase correlation of
  each press's colour change with the set's mean press (:func:`registered_centres`).

Reports, per axis, the mean offset ``H - A`` with its standard error (a convention such as pixel corner vs
pixel centre would show as a shared offset of 0.5 px), the radius ratio ``A / H`` (a radius convention shows
as a common scale), and the three-cornered-hat estimate of each method's own centre scatter: for independent
errors, ``var(A - H) = sA^2 + sH^2`` etc., so ``sH^2 = (var(A-H) + var(B-H) - var(A-B)) / 2`` (robust
variances, 1.4826 MAD; 90 % bootstrap interval over presses). From ``sH`` it predicts the share of presses
within 2 px that even an exact detector would reach: ``1 - exp(-2^2 / (2 sH^2))`` for isotropic scatter.

With ``--geometry`` a fourth estimate joins:
- ``C``: the centre of the ball itself, fitted to the reconstructed surface: each press is reconstructed by a
  calibration trained (on AUTO labels, placement 0.5) on the other presses only (4 folds, cross-fitted), and a
  sphere is fitted to the reconstructed height inside 0.6 x ``A``'s radius around ``B``'s centre. It uses the
  ball geometry (the whole cap's shape), not the rim, and never the hand labels.
With four estimates the per-axis scatters are over-determined: ``var(i - j) = s_i^2 + s_j^2`` for the six
pairs, solved by least squares (:func:`ncornered_hat`), which also says whether the three-estimate numbers hold.

An evaluation tool: it reads the labels only to compare. Prints a text report (and JSON with ``--json``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def registered_centres(ps, seeds: np.ndarray, iters: int = 2) -> np.ndarray:
    """Detector ``B``: (N, 2) press centres (x, y px) by sub-pixel phase correlation of each press's colour
    change magnitude with the set's mean press (a template built from the presses themselves).

    A press looks like every other press shifted (same ball, same lights), so registration measures its
    centre from the whole shading pattern, not from a rim. ``seeds`` (N, 2) only place the crops; their
    per-press errors are removed by the registration, and the template's own reference point is a constant
    offset common to every press (it cancels in the scatter estimates, not in the mean offset)."""
    import cv2

    from vtrack.tactile.autolabel import change_magnitude

    bg = ps.background()
    R = ps.ball_radius_px
    half = int(round(1.3 * R))
    size = 2 * half + 1
    H, W = ps.shape
    mags = [change_magnitude(ps.image(p), bg, max(0.7, R / 60.0))[0] for p in ps.presses]
    centres = np.asarray(seeds, np.float64).copy()
    win = cv2.createHanningWindow((size, size), cv2.CV_32F)

    def crop(a: np.ndarray, c: np.ndarray) -> np.ndarray:
        # sub-pixel crop centred on c (reflected borders: presses cut by the image edge stay usable)
        M = np.float32([[1, 0, half - c[0]], [0, 1, half - c[1]]])
        return cv2.warpAffine(a, M, (size, size), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)

    inner = (centres[:, 0] > half) & (centres[:, 0] < W - half) & (centres[:, 1] > half) & (centres[:, 1] < H - half)
    for _ in range(iters):
        crops = [crop(m, c) for m, c in zip(mags, centres, strict=True)]
        tmpl = np.mean([c / max(float(c.max()), 1e-6) for c, ok in zip(crops, inner, strict=True) if ok], axis=0)
        tmpl = np.ascontiguousarray(tmpl, np.float32)
        new = centres.copy()
        for i, c in enumerate(crops):
            (dx, dy), _ = cv2.phaseCorrelate(tmpl, np.ascontiguousarray(c / max(float(c.max()), 1e-6), np.float32), win)
            new[i] = centres[i] + (dx, dy)
        centres = new
    return centres


def _rvar(x: np.ndarray) -> float:
    """Robust variance: (1.4826 MAD)^2."""
    return float((1.4826 * np.median(np.abs(x - np.median(x)))) ** 2)


def _hat(dAH: np.ndarray, dBH: np.ndarray, dAB: np.ndarray) -> tuple[float, float, float]:
    """Three-cornered hat: (sA, sB, sH) from the pairwise differences of one axis (a negative variance
    estimate, i.e. a scatter below what the others resolve, is reported as 0)."""
    vAH, vBH, vAB = _rvar(dAH), _rvar(dBH), _rvar(dAB)
    out = []
    for v in ((vAH + vAB - vBH) / 2, (vBH + vAB - vAH) / 2, (vAH + vBH - vAB) / 2):
        out.append(float(np.sqrt(max(v, 0.0))))
    return out[0], out[1], out[2]


def ncornered_hat(est: dict[str, np.ndarray]) -> dict[str, float]:
    """Per-estimate scatter (px, one axis) from all pairwise differences of >= 3 estimates of the same
    quantities: ``var(i - j) = s_i^2 + s_j^2`` (robust variances), least squares over the pairs, negative
    variances clipped to 0. ``est``: name -> (N,) values of one axis."""
    names = list(est)
    if len(names) < 3:
        raise ValueError("the hat needs at least 3 estimates")
    rows, rhs = [], []
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            r = np.zeros(len(names))
            r[[i, j]] = 1.0
            rows.append(r)
            rhs.append(_rvar(est[names[i]] - est[names[j]]))
    v, *_ = np.linalg.lstsq(np.array(rows), np.array(rhs), rcond=None)
    return {n: float(np.sqrt(max(x, 0.0))) for n, x in zip(names, v, strict=True)}


def sphere_centres(
    root: str | Path, files: list[str], disc_centres: np.ndarray, disc_radii: np.ndarray, folds: int = 4
) -> np.ndarray:
    """Estimate ``C``: (N, 2) centres (x, y px) of the ball fitted to each press's reconstructed surface, the
    press reconstructed by an ``mlp`` calibration trained on auto labels (placement 0.5) of the OTHER folds'
    presses (press i is in fold i % folds). Points: inside ``0.6 * disc_radii`` around ``disc_centres``
    (a sphere fit is unbiased whichever part of the cap it sees). NaN where a press cannot be fitted.

    Returns (N, 3): centre x, y and the contact radius of the fitted ball (px): where the fitted sphere meets
    the flat gel (height 0), ``sqrt(r^2 - z_c^2)`` - the radius that ball geometry gives the press."""
    from vtrack.geometry.fit import fit_sphere
    from vtrack.tactile.autolabel import AutoLabelOptions
    from vtrack.tactile.calibration import calibrate
    from vtrack.tactile.pipeline import TactilePipeline
    from vtrack.tactile.pressset import load_press_set

    auto = load_press_set(root, labels="auto", autolabel_opts=AutoLabelOptions(edge_weight=0.5))
    fold = {f: i % folds for i, f in enumerate(files)}
    out = np.full((len(files), 3), np.nan)
    s = auto.mm_per_px
    Hh, Ww = auto.shape
    yy, xx = np.mgrid[0:Hh, 0:Ww]
    for f in range(folds):
        train = [p for p in auto.presses if fold.get(p.file, -1) != f]
        pipe = TactilePipeline(calibrate(auto, "mlp", train))
        for i, name in enumerate(files):
            if fold[name] != f or not np.isfinite(disc_centres[i]).all() or not np.isfinite(disc_radii[i]):
                continue
            h = pipe.height(auto.read(name))
            m = np.hypot(xx - disc_centres[i, 0], yy - disc_centres[i, 1]) < 0.6 * disc_radii[i]
            if m.sum() < 20:
                continue
            c, r = fit_sphere(np.column_stack([xx[m] * s, yy[m] * s, -np.asarray(h, np.float64)[m]]))
            if np.isfinite(r):
                out[i, :2] = c[:2] / s
                out[i, 2] = np.sqrt(max(r * r - c[2] * c[2], 0.0)) / s
    return out


def analyse(
    root: str | Path, weights=(0.25, 0.5, 0.75, 1.0), n_boot: int = 500, seed: int = 0, geometry: bool = False
) -> dict:
    """The comparison for one press set (see the module docstring)."""
    from vtrack.tactile.autolabel import AutoLabelOptions, detect_contact
    from vtrack.tactile.pressset import load_press_set

    ps = load_press_set(root, labels="hand")
    bg = ps.background()
    Rpx = ps.ball_radius_px
    H = np.array([[*p.center_xy_px, p.contact_radius_px] for p in ps.presses], np.float64)
    seeds = np.array(
        [
            [d.center_x_px, d.center_y_px]
            for d in (
                detect_contact(ps.image(p), bg, Rpx, p.file, AutoLabelOptions(edge_weight=0.75)) for p in ps.presses
            )
        ]
    )
    seeds = np.where(np.isfinite(seeds), seeds, H[:, :2])  # a crop position only (see registered_centres)
    B = registered_centres(ps, seeds)
    C = None
    if geometry:
        a05 = [detect_contact(ps.image(p), bg, Rpx, p.file, AutoLabelOptions(edge_weight=0.5)) for p in ps.presses]
        C = sphere_centres(root, [p.file for p in ps.presses], B, np.array([d.contact_radius_px for d in a05]))
    out: dict = {"set": str(root), "n_presses": len(ps.presses), "placements": []}
    rng = np.random.default_rng(seed)
    for w in weights:
        dets = [detect_contact(ps.image(p), bg, Rpx, p.file, AutoLabelOptions(edge_weight=w)) for p in ps.presses]
        A = np.array([[d.center_x_px, d.center_y_px, d.contact_radius_px] for d in dets])
        ok = np.array([d.ok for d in dets]) & np.isfinite(B).all(1)
        if C is not None:
            ok &= np.isfinite(C[:, :2]).all(1)
        a, b, h = A[ok], np.column_stack([B[ok], A[ok, 2]]), H[ok]
        dAH, dBH, dAB = a[:, :2] - h[:, :2], b[:, :2] - h[:, :2], a[:, :2] - b[:, :2]
        cen = np.hypot(*dAH.T)
        rr = a[:, 2] / h[:, 2] - 1.0
        row = {
            "edge_weight": w,
            "n_used": int(ok.sum()),
            "centre_A_vs_H_median_px": float(np.median(cen)),
            "centre_within_2px": float(np.mean(cen <= 2.0)),
            "radius_A_over_H_median_pct": float(100 * np.median(rr)),
            "radius_within_5pct": float(np.mean(np.abs(rr) <= 0.05)),
            "both": float(np.mean((cen <= 2.0) & (np.abs(rr) <= 0.05))),
            "offset_H_minus_A_px": [float(-dAH[:, i].mean()) for i in (0, 1)],
            "offset_se_px": [float(dAH[:, i].std(ddof=1) / np.sqrt(len(dAH))) for i in (0, 1)],
            "centre_B_vs_H_median_px": float(np.median(np.hypot(*(dBH - dBH.mean(0)).T))),
            "centre_A_vs_B_median_px": float(np.median(np.hypot(*(dAB - dAB.mean(0)).T))),
        }
        # scatter of each method per axis (three-cornered hat), with a bootstrap interval for the hand labels
        hats = [_hat(dAH[:, i], dBH[:, i], dAB[:, i]) for i in (0, 1)]
        row["sd_A_px"] = [hh[0] for hh in hats]
        row["sd_B_px"] = [hh[1] for hh in hats]
        row["sd_H_px"] = [hh[2] for hh in hats]
        boot = []
        for _ in range(n_boot):
            k = rng.integers(0, len(dAH), len(dAH))
            s = [_hat(dAH[k, i], dBH[k, i], dAB[k, i])[2] for i in (0, 1)]
            boot.append(np.sqrt(np.mean(np.square(s))))
        sH = float(np.sqrt(np.mean(np.square(row["sd_H_px"]))))
        row["sd_H_px_rms_axes"] = sH
        row["sd_H_px_90ci"] = [float(np.percentile(boot, 5)), float(np.percentile(boot, 95))]
        row["predicted_within_2px_exact_detector"] = float(1.0 - np.exp(-4.0 / (2.0 * sH * sH))) if sH > 0 else 1.0
        # conventions: shift the hand centres by the measured mean offset / by half a pixel, scale the radii
        for name, sh in (("mean_offset", dAH.mean(0)), ("half_px", np.array([0.5, 0.5]))):
            c2 = np.hypot(*(dAH - sh).T)  # hand centres + sh
            row[f"centre_within_2px_hand_shifted_{name}"] = float(np.mean(c2 <= 2.0))
        k = float(np.median(a[:, 2] / h[:, 2]))
        rr2 = a[:, 2] / (k * h[:, 2]) - 1.0
        row["radius_scale_A_over_H"] = k
        row["radius_within_5pct_after_scale"] = float(np.mean(np.abs(rr2) <= 0.05))
        row["both_after_offset_and_scale"] = float(
            np.mean((np.hypot(*(dAH - dAH.mean(0)).T) <= 2.0) & (np.abs(rr2) <= 0.05))
        )
        if C is not None:
            # four estimates: the over-determined hat (A, B, C = ball fit, H), bootstrap interval for H
            four = [ncornered_hat({"A": a[:, i], "B": b[:, i], "C": C[ok, i], "H": h[:, i]}) for i in (0, 1)]
            row["hat4_sd_px"] = {k: [four[0][k], four[1][k]] for k in four[0]}
            boot4 = []
            for _ in range(n_boot):
                k = rng.integers(0, len(a), len(a))
                s4 = [ncornered_hat({"A": a[k, i], "B": b[k, i], "C": C[ok][k, i], "H": h[k, i]})["H"] for i in (0, 1)]
                boot4.append(np.sqrt(np.mean(np.square(s4))))
            sH4 = float(np.sqrt(np.mean(np.square(row["hat4_sd_px"]["H"]))))
            row["hat4_sd_H_px_rms_axes"] = sH4
            row["hat4_sd_H_px_90ci"] = [float(np.percentile(boot4, 5)), float(np.percentile(boot4, 95))]
            row["hat4_predicted_within_2px_exact_detector"] = (
                float(1.0 - np.exp(-4.0 / (2.0 * sH4 * sH4))) if sH4 > 0 else 1.0
            )
            dCH = C[ok, :2] - h[:, :2]
            row["centre_C_vs_H_median_px"] = float(np.median(np.hypot(*(dCH - dCH.mean(0)).T)))
            row["centre_C_vs_A_median_px"] = float(np.median(np.hypot(*(C[ok, :2] - a[:, :2]).T)))
            # radius: hand, rim detector and the fitted ball's geometric contact radius (log ratios, so a
            # common scale such as the gel's bulge around the contact cancels): each one's relative scatter
            lr = {"A": np.log(a[:, 2]), "C": np.log(np.maximum(C[ok, 2], 1e-6)), "H": np.log(h[:, 2])}
            row["radius_C_over_H_median_pct"] = float(100 * (np.exp(np.median(lr["C"] - lr["H"])) - 1))
            row["radius_hat_sd_pct"] = {k: 100 * v for k, v in ncornered_hat(lr).items()}
            row["centre_C_within_2px_of_H"] = float(np.mean(np.hypot(*dCH.T) <= 2.0))
        # hand labels on this set: integers? (quantisation alone is sd 0.29 px per axis)
        row["hand_centres_integer"] = bool(np.all(h[:, :2] == np.rint(h[:, :2])))
        out["placements"].append(row)
    return out


def _report(res: dict) -> str:
    lines = [f"{res['set']}: {res['n_presses']} presses"]
    for r in res["placements"]:
        lines.append(
            f"  w={r['edge_weight']:.2f} used {r['n_used']}: centre A-H median {r['centre_A_vs_H_median_px']:.2f} px, "
            f"<=2 px {100 * r['centre_within_2px']:.0f} %, radius A/H {r['radius_A_over_H_median_pct']:+.1f} %, "
            f"<=5 % {100 * r['radius_within_5pct']:.0f} %, both {100 * r['both']:.0f} %"
        )
        lines.append(
            f"    offset H-A (x, y) {r['offset_H_minus_A_px'][0]:+.2f}, {r['offset_H_minus_A_px'][1]:+.2f} px "
            f"(se {r['offset_se_px'][0]:.2f}, {r['offset_se_px'][1]:.2f}); "
            f"B-H median {r['centre_B_vs_H_median_px']:.2f}"
            f" px, A-B median {r['centre_A_vs_B_median_px']:.2f} px (B's constant offset removed)"
        )
        lines.append(
            "    sd per axis (x, y): A {:.2f}, {:.2f}  B {:.2f}, {:.2f}  H {:.2f}, {:.2f} px; sH {:.2f} px "
            "(90 % CI {:.2f}-{:.2f}) -> an exact detector is within 2 px of H for {:.0f} %".format(
                *r["sd_A_px"],
                *r["sd_B_px"],
                *r["sd_H_px"],
                r["sd_H_px_rms_axes"],
                *r["sd_H_px_90ci"],
                100 * r["predicted_within_2px_exact_detector"],
            )
        )
        lines.append(
            f"    conventions: hand centres shifted by the mean offset -> <=2 px "
            f"{100 * r['centre_within_2px_hand_shifted_mean_offset']:.0f} %, by (+0.5, +0.5) -> "
            f"{100 * r['centre_within_2px_hand_shifted_half_px']:.0f} %; "
            f"radius scale A/H {r['radius_scale_A_over_H']:.3f}"
            f" -> <=5 % {100 * r['radius_within_5pct_after_scale']:.0f} %; both after offset+scale "
            f"{100 * r['both_after_offset_and_scale']:.0f} %"
        )
        if "hat4_sd_px" in r:
            sd = r["hat4_sd_px"]
            lines.append(
                "    four-cornered hat (x, y): A {:.2f}, {:.2f}  B {:.2f}, {:.2f}  C(ball fit) {:.2f}, {:.2f}  "
                "H {:.2f}, {:.2f} px; sH {:.2f} px (90 % CI {:.2f}-{:.2f}) -> exact detector within 2 px of H "
                "{:.0f} %; C-A median {:.2f} px, C within 2 px of H {:.0f} %".format(
                    *sd["A"],
                    *sd["B"],
                    *sd["C"],
                    *sd["H"],
                    r["hat4_sd_H_px_rms_axes"],
                    *r["hat4_sd_H_px_90ci"],
                    100 * r["hat4_predicted_within_2px_exact_detector"],
                    r["centre_C_vs_A_median_px"],
                    100 * r["centre_C_within_2px_of_H"],
                )
            )
            rs = r["radius_hat_sd_pct"]
            lines.append(
                f"    radius: ball-fit C / H median {r['radius_C_over_H_median_pct']:+.1f} %; relative scatter "
                f"(three-cornered hat) A {rs['A']:.1f} %, C {rs['C']:.1f} %, H {rs['H']:.1f} %"
            )
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("set", type=Path)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--geometry", action="store_true", help="add C, the ball fitted to cross-fitted reconstructions")
    ap.add_argument("--weights", default="0.25,0.5,0.75,1.0", help="edge placements of A (comma-separated)")
    a = ap.parse_args()
    from vtrack.threads import limit_threads

    limit_threads(1)
    res = analyse(a.set, tuple(float(w) for w in a.weights.split(",")), geometry=a.geometry)
    print(_report(res))
    if a.json:
        from vtrack.io.jsonio import write_json

        write_json(a.json, res)


if __name__ == "__main__":
    main()
