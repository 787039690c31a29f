"""Automatic contact-circle labels for ball-press sets (no hand labels).

A person calibrating a sensor presses a ball of known radius into the gel at many places and takes one
image per press plus a no-contact background. This module finds each press's visible contact circle
itself, the way a person would click it:

1. colour change against the background, corrected for the global drift of the frame
   (:func:`vtrack.tactile.calibration.drift_offset`), summed over channels and slightly blurred;
2. a rough blob: the largest connected region above ``blob_frac`` of the change's peak, joined by the large
   regions within twice their joint area-radius (lobes of the same press; farther ones are a second
   contact); its centroid and area-radius seed the next step;
3. the edge: along rays from the centre, the radius where the change FALLS fastest (the ball's rim: inside it
   the gel follows the steep sphere, outside it relaxes to flat); rays that leave the image are skipped,
   so presses cut by the image border still get a circle from their visible arc;
4. a robust algebraic circle fit (Kasa, ``fit_sphere`` in 2-D, outliers beyond 2.5 median residuals
   dropped), iterated twice from the refined centre.

Each detection is checked for plausibility against the ball (a contact circle is never larger than the
ball), the image (saturation, blank frame, most of the circle outside the image), the fit (edge rays found,
residual) and the scene (a second contact of similar size). Untrusted presses are dropped with the reason.

Pixel coordinates follow the press-set convention: ``x`` = column, ``y`` = row, origin top-left.
"""

from __future__ import annotations

import csv
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from vtrack.errors import InputError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
#: Fewest usable presses a calibration is trained from.
MIN_PRESSES = 5


@dataclass
class AutoLabelOptions:
    """Thresholds of :func:`detect_contact` (grey levels are summed over the three channels)."""

    blob_frac: float = 0.3  # rough blob: change above this fraction of the peak
    min_peak: float = 24.0  # weakest peak change (grey levels) still called a press
    noise_factor: float = 3.0  # ... and this many times the frame's (unblurred) noise level
    min_radius_frac: float = 0.2  # contact radius below this x ball radius: too shallow to calibrate
    max_radius_frac: float = 1.1  # contact radius above this x ball radius: not this ball (or wrong pitch)
    min_coverage: float = 0.5  # fraction of the circle's rays with a usable edge (inside the image)
    max_fit_rms_frac: float = 0.08  # circle-fit RMS residual, as a fraction of the radius (>= 1.5 px)
    max_saturated: float = 0.02  # fraction of pixels at 0 or 255 beyond the background's
    second_blob_frac: float = 0.35  # a second blob this large (area vs the first) -> two contacts
    n_rays: int = 180
    #: where on the rim profile the edge is put: 0 = the ring's peak change, 1 = the steepest fall beyond it
    edge_weight: float = 0.75
    #: refine the rim's fall and peak between the 0.5 px ray samples (parabola through the three samples
    #: around each extreme) instead of taking the nearest sample
    subpixel: bool = False


@dataclass
class Detection:
    """Outcome of :func:`detect_contact` for one press image (px; ``reason`` empty when usable)."""

    file: str
    center_x_px: float = float("nan")
    center_y_px: float = float("nan")
    contact_radius_px: float = float("nan")
    coverage: float = 0.0  # fraction of rays with an edge
    fit_rms_px: float = float("nan")
    peak_change: float = 0.0
    reason: str = ""

    @property
    def ok(self) -> bool:
        return not self.reason


def _robust_circle(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float, float, np.ndarray]:
    """Algebraic circle fit with outlier rejection (:func:`~vtrack.geometry.fit.robust_sphere` in 2-D, residuals
    under max(1 px, 2.5 median residuals) kept): (cx, cy, r, rms, kept mask); r is not finite for a degenerate
    set. Needs >= 3 points."""
    from vtrack.geometry.fit import robust_sphere

    (cx, cy), r, rms, keep = robust_sphere(np.column_stack([x, y]), floor=1.0)
    return cx, cy, r, rms, keep


def _parabola_offset(v: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Sub-sample offset (in [-0.5, 0.5] samples) of the minimum of each row of ``v`` near index ``j``: the
    vertex of the parabola through ``v[j - 1], v[j], v[j + 1]`` (0 at the row ends or where it is flat)."""
    n = v.shape[1]
    i = np.arange(len(j))
    jm, jp = np.clip(j - 1, 0, n - 1), np.clip(j + 1, 0, n - 1)
    a, b, c = v[i, jm], v[i, j], v[i, jp]
    den = a - 2.0 * b + c
    with np.errstate(divide="ignore", invalid="ignore"):
        off = np.where((den > 1e-12) & (j > 0) & (j < n - 1), 0.5 * (a - c) / den, 0.0)
    return np.clip(np.nan_to_num(off), -0.5, 0.5)


def _blank_reason(img: np.ndarray) -> str:
    """Why a constant frame is unusable, naming an all-white (over-exposed) or all-black (dark) one."""
    m = float(np.mean(img))
    what = ": saturated / over-exposed" if m >= 250 else ": black frame / no light" if m <= 5 else ""
    return f"blank image (constant colour {m:.0f}{what})"


def change_magnitude(image: np.ndarray, background: np.ndarray, blur_px: float) -> tuple[np.ndarray, float]:
    """Drift-corrected total colour change |image - background| (grey levels, (H, W) float32), blurred with a
    Gaussian of ``blur_px``, and the frame's noise level (grey levels, see ``drift_offset``)."""
    import cv2

    from vtrack.tactile.calibration import drift_offset, shift_background

    off, level = drift_offset(image, background)
    d = np.asarray(image, np.float32) - shift_background(background, off).astype(np.float32)
    a = np.abs(d).sum(axis=2)
    return cv2.GaussianBlur(a, (0, 0), blur_px), level


def detect_contact(
    image: np.ndarray,
    background: np.ndarray,
    ball_radius_px: float,
    file: str = "",
    opts: AutoLabelOptions | None = None,
) -> Detection:
    """Find the visible contact circle of one ball press (see module docstring).

    Args:
        image, background: uint8 BGR frames of the same size.
        ball_radius_px: ball radius in pixels (ball radius mm / mm per px); bounds the plausible contact.
        file: name reported in the detection.
    """
    import cv2

    o = opts or AutoLabelOptions()
    det = Detection(file)
    img = np.asarray(image)
    if float(img.std()) < 2.0:
        det.reason = _blank_reason(img)
        return det
    bg = np.asarray(background)
    sat = float(((img == 0) | (img == 255)).any(axis=2).mean() - ((bg == 0) | (bg == 255)).any(axis=2).mean())
    if sat > o.max_saturated:
        det.reason = f"saturated ({100 * sat:.0f} % of pixels clipped at 0/255 beyond the background)"
        return det
    H, W = img.shape[:2]
    a, level = change_magnitude(img, bg, max(0.7, ball_radius_px / 60.0))
    peak = float(np.percentile(a, 99.9))
    det.peak_change = peak
    if peak < max(o.min_peak, o.noise_factor * level):
        det.reason = f"no contact (peak colour change {peak:.0f} grey levels, noise {level:.1f})"
        return det
    blob = (a > o.blob_frac * peak).astype(np.uint8)
    n, lab, st, cen = cv2.connectedComponentsWithStats(blob)
    if n < 2:
        det.reason = "no contact region"
        return det
    areas = st[1:, cv2.CC_STAT_AREA].astype(np.float64)
    order = np.argsort(areas)[::-1]
    k = int(order[0])
    # One press can split into lobes: with LEDs at a low elevation (DIGIT) the lit and the shadowed side of
    # the dent change strongly and its flat middle little, so at blob_frac of the peak the two sides are
    # separate blobs about one contact radius apart. A large blob counts as a second contact only when it
    # lies farther from the main one than twice the radius of their joint area (two presses of the same
    # ball are at least two contact radii apart); nearer ones are lobes of this press (a merged pair of
    # touching contacts is then refused by the roundness check below).
    A, c = areas[k], cen[1 + k] * areas[k]
    for j in order[1:]:
        if areas[j] <= o.second_blob_frac * areas[k] or areas[j] <= 30:
            break
        if np.hypot(*(cen[1 + j] - cen[1 + k])) > 2.0 * np.sqrt((areas[k] + areas[j]) / np.pi):
            det.reason = "more than one contact"
            return det
        A, c = A + areas[j], c + cen[1 + j] * areas[j]
    cx, cy = (float(v) for v in c / A)
    r = float(np.sqrt(A / np.pi))
    th = np.linspace(0.0, 2.0 * np.pi, o.n_rays, endpoint=False)
    cos, sin = np.cos(th)[:, None], np.sin(th)[:, None]
    idx = np.arange(o.n_rays)
    cov = rms = 0.0
    for _ in range(3):
        rr = np.arange(0.0, 1.35 * max(r, 3.0), 0.5, dtype=np.float64)
        X, Y = cx + cos * rr, cy + sin * rr
        inside = (X >= 0) & (X <= W - 1) & (Y >= 0) & (Y <= H - 1)
        prof = cv2.remap(a, X.astype(np.float32), Y.astype(np.float32), cv2.INTER_LINEAR)
        der = np.gradient(prof, axis=1)
        der[~inside] = 0.0
        der[:, rr < 0.3 * r] = 0.0  # the centre of a press is flat-ish and changes little: not the rim
        j = np.argmin(der, axis=1)
        jf = j.astype(np.float64)  # edge position in ray samples (fractional with ``subpixel``)
        if o.subpixel:
            jf = j + _parabola_offset(der, j)
        if o.edge_weight < 1.0:
            pk = np.where(np.arange(len(rr))[None, :] <= j[:, None], prof, -np.inf)
            pk[:, rr < 0.3 * r] = -np.inf
            jp = np.argmax(pk, axis=1)
            jp = np.where(np.isfinite(pk[idx, jp]), jp, j)
            jpf = jp + _parabola_offset(-prof, jp) * (jp != j) if o.subpixel else jp.astype(np.float64)
            jf = jpf + o.edge_weight * (jf - jpf)
            j = np.clip(np.rint(jf), 0, len(rr) - 1).astype(int)
            if not o.subpixel:
                jf = j.astype(np.float64)
        # the edge must lie inside the image with a little of the profile beyond it (else it is the border)
        beyond = np.minimum(j + 4, len(rr) - 1)
        good = inside[idx, beyond] & (der[idx, j] < 0.0)
        cov = float(good.mean())
        if good.sum() < 8:
            break
        rad = np.interp(jf, np.arange(len(rr)), rr)  # the edge's radius along each ray (px)
        ex, ey = (cx + cos[:, 0] * rad)[good], (cy + sin[:, 0] * rad)[good]
        cx2, cy2, r2, rms, keep = _robust_circle(ex, ey)
        if not np.isfinite(r2):
            break
        cov = float(keep.sum() / o.n_rays)
        cx, cy, r = cx2, cy2, r2
    det.center_x_px, det.center_y_px, det.contact_radius_px = cx, cy, r
    det.coverage, det.fit_rms_px = cov, rms
    if cov < o.min_coverage:
        det.reason = (
            f"contact edge found on {100 * cov:.0f} % of the circle (off the image or not round; "
            f"need {100 * o.min_coverage:.0f} %)"
        )
    elif not np.isfinite(rms) or rms > max(1.5, o.max_fit_rms_frac * r):
        det.reason = f"contact is not circular (fit residual {rms:.1f} px)"
    elif r < o.min_radius_frac * ball_radius_px:
        det.reason = (
            f"too shallow (contact radius {r:.1f} px < {o.min_radius_frac:g} x ball radius {ball_radius_px:.1f} px)"
        )
    elif r > o.max_radius_frac * ball_radius_px:
        det.reason = (
            f"contact radius {r:.1f} px larger than the ball ({ball_radius_px:.1f} px): wrong "
            "mm_per_px / ball_radius_mm, or not a ball press"
        )
    elif not (0 <= cx < W and 0 <= cy < H):
        det.reason = "contact centre outside the image (off-centre press)"
    return det


def press_images(root: Path, background_file: str = "background.png") -> list[str]:
    """Image files of a press folder other than the background, sorted by name."""
    return sorted(
        p.name
        for p in root.iterdir()
        if p.is_file()
        and p.suffix.lower() in IMAGE_SUFFIXES
        and p.name != background_file
        and not p.name.startswith(".")
    )


def auto_label(
    root: str | Path,
    ball_radius_px: float,
    opts: AutoLabelOptions | None = None,
    background_file: str = "background.png",
) -> list[Detection]:
    """Detect the contact circle of every press image in a press folder (see module docstring)."""
    from vtrack.tactile.pressset import read_bgr

    root = Path(root)
    bg = read_bgr(root / background_file)
    files = press_images(root, background_file)
    if not files:
        raise InputError("no press images in the press set", path=root, expected="PNG/JPEG press images")
    out = []
    for f in files:
        try:
            img = read_bgr(root / f)
        except InputError as e:
            import cv2

            raw = cv2.imread(str(root / f), cv2.IMREAD_UNCHANGED)
            # an all-black/white frame is refused by read_bgr as colourless; name the real problem
            blank = raw is not None and float(raw.std()) < 2.0
            out.append(Detection(f, reason=_blank_reason(raw) if blank else f"unreadable ({e})"))
            continue
        if img.shape != bg.shape:
            out.append(Detection(f, reason=f"size {img.shape[1]}x{img.shape[0]} differs from the background"))
            continue
        out.append(detect_contact(img, bg, ball_radius_px, f, opts))
    return out


AUTO_COLUMNS = (
    "file",
    "center_x_px",
    "center_y_px",
    "contact_radius_px",
    "coverage",
    "fit_rms_px",
    "peak_change",
    "used",
    "reason",
)


def write_auto_labels(path: str | Path, detections: list[Detection]) -> Path:
    """Write ``labels.auto.csv``: the press-set label columns plus detection quality, ``used`` and ``reason``
    (dropped presses are kept with their reason so a person can see what was left out and why)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(AUTO_COLUMNS)
        for d in detections:
            row = asdict(d)
            w.writerow(
                [d.file]
                + [f"{row[c]:.2f}" if np.isfinite(row[c]) else "" for c in AUTO_COLUMNS[1:4]]
                + [
                    f"{d.coverage:.2f}",
                    f"{d.fit_rms_px:.2f}" if np.isfinite(d.fit_rms_px) else "",
                    f"{d.peak_change:.0f}",
                    int(d.ok),
                    d.reason,
                ]
            )
    return path


def review_sheet(
    root: str | Path,
    detections: list[Detection],
    out: str | Path,
    tile_px: int = 200,
    cols: int = 8,
    background_file: str = "background.png",
) -> Path:
    """Contact sheet of every press with its detected circle (green: used; red: dropped, with the reason's
    first words) for a person to check the automatic labels."""
    import cv2

    from vtrack.tactile.pressset import read_bgr

    root, out = Path(root), Path(out)
    tiles = []
    for d in detections:
        try:
            img = read_bgr(root / d.file).copy()
        except InputError:  # drawn anyway (a blank frame is what the person should see)
            raw = cv2.imread(str(root / d.file), cv2.IMREAD_COLOR)
            img = raw if raw is not None else np.zeros((tile_px, tile_px, 3), np.uint8)
        s = tile_px / max(img.shape[:2])
        img = cv2.resize(
            img, (max(1, round(img.shape[1] * s)), max(1, round(img.shape[0] * s))), interpolation=cv2.INTER_AREA
        )
        colour = (0, 200, 0) if d.ok else (0, 0, 255)
        if np.isfinite(d.contact_radius_px):
            c = (round(d.center_x_px * s), round(d.center_y_px * s))
            cv2.circle(img, c, max(1, round(d.contact_radius_px * s)), colour, 1, cv2.LINE_AA)
            cv2.drawMarker(img, c, colour, cv2.MARKER_CROSS, 6, 1)
        tile = np.zeros((img.shape[0] + 16, tile_px, 3), np.uint8)
        tile[: img.shape[0], : img.shape[1]] = img
        text = d.file if d.ok else f"{d.file}: {d.reason[:24]}"
        cv2.putText(tile, text, (2, img.shape[0] + 12), cv2.FONT_HERSHEY_SIMPLEX, 0.33, colour, 1, cv2.LINE_AA)
        tiles.append(tile)
    if not tiles:
        raise InputError("nothing to draw: no presses", path=root)
    cols = min(cols, len(tiles))
    rows = -(-len(tiles) // cols)
    th = max(t.shape[0] for t in tiles)
    sheet = np.zeros((rows * th, cols * tile_px, 3), np.uint8)
    for i, t in enumerate(tiles):
        r, c = divmod(i, cols)
        sheet[r * th : r * th + t.shape[0], c * tile_px : (c + 1) * tile_px] = t
    out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out), sheet):
        raise InputError("cannot write the review sheet", path=out, expected="a writable .png path")
    return out
