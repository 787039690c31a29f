"""Marker segmentation network (FusionTouch S4): gamma matching, a small U-Net, morphological splitting.

Pipeline (:func:`extract_markers_unet`, returns the same :class:`~vtrack.dome.markers.MarkerSet` as the classic
Otsu + k-means extractor :func:`~vtrack.dome.markers.extract_markers`):

1. **Gamma matched to the reference.** The image is percentile-normalised to [0, 1] and a gamma is chosen so
   that the median brightness of its foreground (pixels above the 90th percentile) matches that of the
   reference frame's foreground (``gamma = log(m_ref) / log(m_img)``, clipped to [0.4, 2.5]).
2. **U-Net** (:class:`TinyUNet`: 3 levels, 8-16-32 channels, ~25k parameters) resized to the training
   resolution (160 px) -> marker probability; fixed threshold 0.5.
3. **Morphological post-processing.** Components of normal area and shape are kept as they are; components
   larger than 1.4x the median area that are elongated or concave (or > 2.5x) are eroded (3x3 cross, up to
   4 times: 3 left two touching pin pairs of the real 360 px TacTip frames merged, 4 splits them with no change
   on the simulated frames) until they
   break into several cores; each core is dilated back inside the original component (nearest-core
   assignment) so the split markers keep their pixels; residues below ``min_area`` or 0.3x the median area,
   giants (> 6x) and thin arcs (the dome rim) are dropped.
4. Centres = probability-weighted moments of each component, in the input image's pixels.

Training data (:func:`make_seg_dataset`): simulated dome presses rendered with exact marker masks
(anti-aliased coverage > 0.5), varied lighting (gain, background, vignetting strength and centre), blur
(sigma 0.4-1.6 px), noise (0-6 % of full scale), internal pressure (0-10 kPa, via the press sampler), partial
occlusion (random dark or bright ellipses covering part of the image; covered markers are removed from the
mask) and two pin layouts (331 and 127 pins, different marker sizes).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from vtrack.dome.markers import MarkerSet, _empty, check_image, label_ellipses

#: training resolution (px)
SEG_SIZE = 160


def foreground_median(img01: np.ndarray) -> float:
    """Median of the brightest 10 % of a [0, 1] image (the marker pixels of a bright-pin frame)."""
    v = np.asarray(img01, np.float64).ravel()
    t = np.percentile(v, 90)
    fg = v[v >= t]
    return float(np.median(fg)) if fg.size else 0.5


def normalise(img: np.ndarray) -> np.ndarray:
    """Percentile (1, 99.7) normalisation to [0, 1] float32 (flat image -> zeros)."""
    g = np.asarray(img, np.float32)
    lo, hi = np.percentile(g, [1, 99.7])
    if hi - lo < 1e-6:
        hi = float(g.max())
    if hi - lo < 1e-6:
        return np.zeros_like(g)
    return np.clip((g - lo) / (hi - lo), 0, 1)


def match_gamma(img01: np.ndarray, ref_fg_median: float) -> tuple[np.ndarray, float]:
    """Gamma-correct a [0, 1] image so its foreground median matches ``ref_fg_median``; -> (image, gamma)."""
    m = min(max(foreground_median(img01), 1e-3), 0.999)
    r = min(max(ref_fg_median, 1e-3), 0.999)
    gamma = float(np.clip(np.log(r) / np.log(m), 0.4, 2.5))
    return np.power(img01, gamma, dtype=np.float32), gamma


def _torch_unet():
    import torch
    from torch import nn

    def block(i: int, o: int) -> nn.Sequential:
        return nn.Sequential(nn.Conv2d(i, o, 3, 1, 1), nn.ReLU(), nn.Conv2d(o, o, 3, 1, 1), nn.ReLU())

    class TinyUNet(nn.Module):
        """3-level U-Net (8-16-32 channels), 1-channel input in [0, 1], marker logit out (same size)."""

        def __init__(self) -> None:
            super().__init__()
            self.e1, self.e2, self.e3 = block(1, 8), block(8, 16), block(16, 32)
            self.u2 = nn.ConvTranspose2d(32, 16, 2, 2)
            self.d2 = block(32, 16)
            self.u1 = nn.ConvTranspose2d(16, 8, 2, 2)
            self.d1 = block(16, 8)
            self.out = nn.Conv2d(8, 1, 1)

        def forward(self, x: torch.Tensor) -> torch.Tensor:
            import torch.nn.functional as F

            a = self.e1(x)
            b = self.e2(F.max_pool2d(a, 2))
            c = self.e3(F.max_pool2d(b, 2))
            d = self.d2(torch.cat([self.u2(c), b], 1))
            return self.out(self.d1(torch.cat([self.u1(d), a], 1)))

    return TinyUNet


def build_unet():
    return _torch_unet()()


def default_weights() -> Path:
    return Path(__file__).resolve().parent / "weights" / "marker_unet.pt"


class MarkerSegmenter:
    """U-Net marker extractor (S4). ``reference``: a no-contact frame of the same sensor (sets the gamma
    target); without one the simulated sensor's reference brightness is used."""

    def __init__(self, weights: str | Path | None = None, reference: np.ndarray | None = None) -> None:
        import torch

        from vtrack.errors import InputError

        path = Path(weights) if weights else default_weights()
        if not path.is_file():
            raise InputError("marker U-Net weights not found (train with `vtrack dome segment train`)", path=path)
        try:
            b = torch.load(path, map_location="cpu", weights_only=True)
            self.net = build_unet()
            self.net.load_state_dict({k: v.float() for k, v in b["state"].items()})
        except Exception as e:  # noqa: BLE001 - corrupt file, wrong keys
            raise InputError(f"not a marker U-Net file ({type(e).__name__})", path=path) from None
        self.net.eval()
        self.info = b.get("info", {})
        self.ref_fg = float(b.get("ref_fg_median", 0.8))
        if reference is not None:
            self.ref_fg = foreground_median(normalise(check_image(reference)))
        self._torch = torch

    def probability(self, image: np.ndarray) -> np.ndarray:
        """Marker probability (H, W) float32 of a grey image (resized to the training resolution and back)."""
        import cv2

        g = check_image(image)
        H, W = g.shape
        x = normalise(g)
        if (H, W) != (SEG_SIZE, SEG_SIZE):
            x = cv2.resize(x, (SEG_SIZE, SEG_SIZE), interpolation=cv2.INTER_AREA)
        x, _ = match_gamma(x, self.ref_fg)
        with self._torch.no_grad():
            logit = self.net(self._torch.from_numpy(np.ascontiguousarray(x))[None, None])[0, 0].numpy()
        p = 1.0 / (1.0 + np.exp(-logit))
        if (H, W) != (SEG_SIZE, SEG_SIZE):
            p = cv2.resize(p, (W, H), interpolation=cv2.INTER_LINEAR)
        return p.astype(np.float32)

    def extract(self, image: np.ndarray, *, mask_radius: float = 0.98, min_area: float | None = None) -> MarkerSet:
        """Markers of one image (centres in the input image's pixels)."""
        p = self.probability(image)
        H, W = p.shape
        scale = (H * W) / SEG_SIZE**2
        ms = markers_from_probability(
            p, mask_radius=mask_radius, min_area=2.0 * scale if min_area is None else min_area
        )
        # plausibility: a marker image has blobs of similar size; noise gives a tangle of odd-sized, merged ones
        # (measured area std / mean: pure noise 0.59-0.65 with 20-29 % of blobs split; simulated frames with
        # lighting, blur, noise and occlusion <= 0.18)
        if (
            len(ms) >= 3
            and float(np.std(ms.areas) / max(np.mean(ms.areas), 1e-9)) > 0.45
            and ms.n_split > 0.1 * len(ms)
        ):
            return _empty(H, W)
        return ms


def _split_component(comp: np.ndarray, max_iter: int = 4) -> list[np.ndarray]:
    """Split a merged blob (bool mask) by erosion until >= 2 cores appear, then grow the cores back inside
    the blob (nearest core); returns the part masks (one element = not split)."""
    import cv2
    from scipy import ndimage

    k = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
    m = comp.astype(np.uint8)
    for _ in range(max_iter):
        m = cv2.erode(m, k)
        n, lab = cv2.connectedComponents(m, connectivity=4)
        if n - 1 >= 2:
            # dilation back: every blob pixel goes to its nearest core (distance transform on the cores)
            _, (iy, ix) = ndimage.distance_transform_edt(lab == 0, return_indices=True)
            owner = lab[iy, ix]
            return [comp & (owner == j) for j in range(1, n)]
        if n - 1 == 0:
            break
    return [comp]


def markers_from_probability(
    prob: np.ndarray,
    *,
    threshold: float = 0.5,
    mask_radius: float = 0.98,
    min_area: float = 2.0,
    max_area_ratio: float = 6.0,
) -> MarkerSet:
    """Connected components of ``prob > threshold`` with morphological splitting of merged markers (S4); parts
    larger than ``max_area_ratio`` x the median marker area or thin arcs are rejected (the dome rim), as in the
    classic extractor."""
    import cv2

    H, W = prob.shape
    bw = (prob > threshold).astype(np.uint8)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(bw, connectivity=8)
    if n <= 1:
        return _empty(H, W)
    areas = stats[1:, cv2.CC_STAT_AREA].astype(np.float64)
    med = float(np.median(areas[areas >= min_area])) if (areas >= min_area).any() else 1.0
    next_label, n_split = n, 0
    for b in np.nonzero(areas >= 1.4 * med)[0] + 1:
        x0, y0, w, h = stats[b, :4]
        sub = lab[y0 : y0 + h, x0 : x0 + w] == b
        yy, xx = np.nonzero(sub)
        pts = np.stack([xx, yy], 1).astype(np.float32)
        ev = np.linalg.eigvalsh(np.cov(pts.T))
        elong = float(np.sqrt(max(ev[0], 1e-9) / max(ev[1], 1e-9)))
        solidity = len(pts) / max(cv2.contourArea(cv2.convexHull(pts)), 1.0)
        if elong > 0.62 and solidity > 0.85 and areas[b - 1] < 2.5 * med:  # one big round marker
            continue
        parts = _split_component(sub)
        if len(parts) < 2:
            continue
        for part in parts[1:]:
            lab[y0 : y0 + h, x0 : x0 + w][part] = next_label
            next_label += 1
        n_split += len(parts) - 1
    n = next_label
    ctr, area, axes, ang = label_ellipses(lab, n, prob, min_area)  # small residues removed
    rr = np.hypot(ctr[:, 0] - (W - 1) / 2, ctr[:, 1] - (H - 1) / 2) / (min(H, W) / 2)
    good = np.all(np.isfinite(ctr), 1) & (rr <= mask_radius)
    if good.sum() >= 3:  # giants and thin arcs that did not split into marker-sized parts: the dome rim
        med = float(np.median(area[good]))
        good &= (area <= max_area_ratio * med) & (area >= 0.3 * med)  # giants; residues of the splitting
        good &= ~((axes[:, 1] / np.maximum(axes[:, 0], 1e-9) < 0.25) & (area > 2 * med))
    return MarkerSet(ctr[good], area[good], axes[good], ang[good], (H, W), n_split, int((~good).sum()))


# ---------------------------------------------------------------------------------------------- data
def render_seg_sample(rng: np.random.Generator, sims: list, *, hard: bool = True) -> dict[str, np.ndarray]:
    """One segmentation sample: grey uint8 image, exact marker mask, visible marker centres (px).

    ``hard``: the training distribution (random lighting, blur, noise, occlusion); else the simulator's own
    rendering (``DomeSimulator.render`` photometry)."""
    import cv2

    from vtrack.dome.simulate import sample_press

    sim = sims[int(rng.integers(len(sims)))]
    press = sample_press(rng, sim.cfg)
    d = sim.deform(press)
    cov, ctr = sim.draw_markers(sim.geo.marker_rest + d["disp_markers"])
    S = sim.cfg.image_size
    yy, xx = np.mgrid[0:S, 0:S]
    visible = np.ones(len(ctr), bool)
    if hard:
        blur = rng.uniform(0.4, 1.6)
        gain = rng.uniform(0.35, 1.0)
        c0 = (S - 1) / 2 + rng.normal(0, 8, 2)
        rr = np.hypot(xx - c0[0], yy - c0[1]) / (S / 2)
        vign = 1.0 - rng.uniform(0.0, 0.6) * rr**2
        bg = rng.uniform(0.02, 0.25)
        grad = rng.uniform(-0.08, 0.08) * (xx - S / 2) / S + rng.uniform(-0.08, 0.08) * (yy - S / 2) / S
        img = cv2.GaussianBlur(cov, (0, 0), blur) * gain * vign + (bg + grad) * vign
        if rng.random() < 0.5:  # partial occlusion: a dark (shadow) or bright (glare) ellipse
            occ = np.zeros((S, S), np.uint8)
            cx, cy = rng.uniform(0, S, 2)
            ax = rng.uniform(8, 35, 2)
            cv2.ellipse(occ, (int(cx), int(cy)), (int(ax[0]), int(ax[1])), float(rng.uniform(0, 180)), 0, 360, 1, -1)
            occ = occ.astype(bool)
            level = rng.uniform(0.0, 0.05) if rng.random() < 0.6 else rng.uniform(0.7, 1.0)
            img = np.where(occ, level, img)
            cov = np.where(occ, 0.0, cov)
            ci = np.clip(np.rint(ctr).astype(int), 0, S - 1)
            visible &= ~occ[ci[:, 1], ci[:, 0]]
        img = img + rng.normal(0, rng.uniform(0.0, 0.06), img.shape)
    else:
        img = sim.render(sim.geo.marker_rest + d["disp_markers"], rng)
        img = img.astype(np.float32) / 255.0
    inside = (ctr >= 0).all(1) & (ctr <= S - 1).all(1)
    return {
        "image": np.clip(img * 255, 0, 255).astype(np.uint8),
        "mask": (cov > 0.5).astype(np.uint8),
        "centers": ctr[visible & inside].astype(np.float32),
    }


def seg_simulators() -> list:
    """The two pin layouts the U-Net is trained on: 331 pins (10 rings, r 0.55 mm) and 127 pins (6 rings,
    r 0.85 mm), same dome and camera."""
    from vtrack.dome.model import DomeConfig
    from vtrack.dome.simulate import DomeSimulator

    return [DomeSimulator(DomeConfig()), DomeSimulator(DomeConfig(marker_rings=6, marker_radius_mm=0.85))]


def make_seg_dataset(n: int, seed: int, *, hard: bool = True) -> list[dict]:
    rng = np.random.default_rng(seed)
    sims = seg_simulators()
    return [render_seg_sample(rng, sims, hard=hard) for _ in range(n)]


def train_unet(
    n_train: int = 1200, epochs: int = 12, seed: int = 0, out: Path | None = None, log=print, crop: int = 96
) -> Path:
    """Train the marker U-Net on simulated frames (BCE + Dice on random ``crop`` px crops); saves float16
    weights (``marker_unet.pt``) with the reference foreground brightness it was trained at."""
    import torch
    import torch.nn.functional as F

    torch.manual_seed(seed)
    data = make_seg_dataset(n_train, seed)
    ref = seg_simulators()[0].reference_image(0.0)
    ref_fg = foreground_median(normalise(ref))
    xs = np.stack([match_gamma(normalise(d["image"]), ref_fg)[0] for d in data]).astype(np.float32)
    ys = np.stack([d["mask"] for d in data]).astype(np.float32)
    net = build_unet()
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    bs = 16
    steps = epochs * (n_train // bs)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=3e-3, total_steps=steps, pct_start=0.1)
    rng = np.random.default_rng(seed + 1)
    S = xs.shape[1]
    t0 = time.time()
    for ep in range(epochs):
        perm = rng.permutation(n_train)
        tot = 0.0
        for b in range(n_train // bs):
            idx = perm[b * bs : (b + 1) * bs]
            oy, ox = rng.integers(0, S - crop + 1, 2)
            x = torch.from_numpy(xs[idx, oy : oy + crop, ox : ox + crop])[:, None]
            y = torch.from_numpy(ys[idx, oy : oy + crop, ox : ox + crop])[:, None]
            if rng.random() < 0.5:
                x, y = x.flip(-1), y.flip(-1)
            logit = net(x)
            pr = torch.sigmoid(logit)
            dice = 1 - (2 * (pr * y).sum() + 1) / (pr.sum() + y.sum() + 1)
            loss = F.binary_cross_entropy_with_logits(logit, y) + dice
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            tot += loss.item() / (n_train // bs)
        log(f"[unet] epoch {ep + 1}/{epochs} loss {tot:.4f} ({time.time() - t0:.0f}s)")
    out = Path(out) if out else default_weights()
    out.parent.mkdir(parents=True, exist_ok=True)
    state = {k: v.half() for k, v in net.state_dict().items()}
    torch.save({"state": state, "ref_fg_median": ref_fg, "info": {"n_train": n_train, "epochs": epochs}}, out)
    return out


# ---------------------------------------------------------------------------------------------- eval
def detection_scores(found: np.ndarray, gt: np.ndarray, gate_px: float = 2.5) -> tuple[float, float, int]:
    """(detection rate, mean position error px of the matched pairs, false detections): one-to-one matching of
    detected to true centres within ``gate_px`` (:func:`vtrack.dome.features.gated_assignment`)."""
    from scipy.spatial import cKDTree

    from vtrack.dome.features import gated_assignment

    if len(gt) == 0:
        return 1.0, 0.0, len(found)
    if len(found) == 0:
        return 0.0, float("nan"), 0
    r, c = gated_assignment(np.asarray(found, np.float64), np.asarray(gt, np.float64), cKDTree(gt), gate_px)
    err = np.linalg.norm(found[r] - gt[c], axis=1)
    return len(c) / len(gt), float(err.mean()) if len(err) else float("nan"), len(found) - len(r)


def evaluate_simulated(
    segmenter: MarkerSegmenter | None = None, n: int = 100, seed: int = 777, hard: bool = True
) -> dict[str, dict[str, float]]:
    """Detection rate / position error (px) of U-Net and classic extractors on held-out simulated frames."""
    from vtrack.dome.markers import extract_markers

    seg = segmenter or MarkerSegmenter()
    data = make_seg_dataset(n, seed, hard=hard)
    res: dict[str, dict[str, list]] = {"unet": {}, "classic": {}}
    for d in data:
        for name, ms in (("unet", seg.extract(d["image"])), ("classic", extract_markers(d["image"]))):
            rate, err, fp = detection_scores(ms.centers, d["centers"])
            r = res[name]
            r.setdefault("detection_rate", []).append(rate)
            r.setdefault("position_err_px", []).append(err)
            r.setdefault("false_per_frame", []).append(fp)
    return {k: {m: float(np.nanmean(v)) for m, v in r.items()} | {"frames": n, "hard": hard} for k, r in res.items()}


def evaluate_tactip(segmenter: MarkerSegmenter | None = None, root: Path | None = None) -> dict[str, dict]:
    """Real TacTip frames (no ground-truth positions): markers found vs the known pin count, the fraction of
    frames with the exact count, and track continuity to the no-contact frame, for U-Net and classic."""
    from vtrack.dome.markers import extract_markers
    from vtrack.dome.model import knn_np
    from vtrack.dome.tactip import SETS, load_set, match_to_reference
    from vtrack.paths import shared_data_dir

    seg = segmenter or MarkerSegmenter()
    root = Path(root) if root else shared_data_dir() / "tactip_frames"
    out: dict[str, dict] = {}
    for name, (pins, mask_r) in SETS.items():
        ts = load_set(root, name)
        for method in ("unet", "classic"):

            def ext(img, method=method, mask_r=mask_r):
                if method == "unet":
                    return seg.extract(img, mask_radius=mask_r)
                return extract_markers(img, polarity="bright", mask_radius=mask_r)

            ref = ext(ts.init)
            _, dd = knn_np(ref.centers, ref.centers, 2)
            spacing = float(np.median(dd[:, 1])) if len(ref) > 1 else 1.0
            counts, cont = [], []
            for img in ts.images:
                ms = ext(img)
                counts.append(len(ms))
                m = match_to_reference(ms.centers, ref.centers, 0.6 * spacing)
                cont.append(float((m >= 0).sum()) / pins)
            c = np.array(counts)
            out[f"{name}/{method}"] = {
                "set": name,
                "method": method,
                "pins": pins,
                "init_count": len(ref),
                "count_mean": float(c.mean()),
                "count_std": float(c.std()),
                "detection_rate": float(np.minimum(c, pins).mean() / pins),
                "frac_exact_count": float((c == pins).mean()),
                "track_continuity": float(np.mean(cont)),
            }
    return out
