"""Object classification from tactile images with geometric, colour or generated augmentation (the ControlTac
paper's Table 3 analogue, at CPU scale), on SIMULATED presses of the shared YCB meshes.

Data: presses of random surface spots of the six shared YCB objects (:mod:`vtrack.language.ycb`: area-weighted
spot, gel facing the local surface normal, random in-plane angle and offset, pushed 0.2-0.7 mm deep), ray cast
by the simulator and rendered by the independent optical model (GelSight preset) on the shipped GelSight
background at the generator's 320x240, 0.059 mm/px. The class is the object. Everything here is simulated;
nothing reads a real object.

Augmentations of a few labelled "real" presses per class (all keep the label; the paper's recipe, section E.4):
- ``G`` geometric: rotation by a multiple of 45 deg, flips, scale 0.8 / 1 / 1.2, translation by -20 / 0 / 20 px
  along each axis, applied to the colour change (the gel outside the moved image shows no change);
- ``G+C``: the same, plus a hue shift (one of six) of the image and of its background, i.e. the same contact
  seen by a sensor with other LED colours;
- ``Gen``: the two-stage generator (:class:`~vtrack.tactile.generate.generator.TactileGenerator`) from each
  reference press to random contact positions, rotations and depths.

Models (from scratch): :class:`SmallCNN` (the paper's four conv blocks + two linear layers, narrower) and
:class:`SmallViT` (patch embedding, class token, pre-norm transformer encoder). Inputs are the colour change
(image - background) at 80x60, / 32 grey levels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vtrack.errors import InputError

#: classifier input size (W, H) and the image size / pitch the presses are rendered at (the generator's)
IN_W, IN_H = 80, 60
W, H, MM_PER_PX = 320, 240, 0.059
#: colour-change scale of the inputs (grey levels)
INPUT_SCALE = 32.0
#: press depths (mm) of the data and of the generated targets
DEPTH_RANGE_MM = (0.2, 0.7)
#: a press counts only if at least this fraction of the frame is in contact (a grazing touch of a rim is not
#: an observation of the object)
MIN_FOOTPRINT_FRAC = 0.005
AUGMENTATIONS = ("none", "G", "G+C", "Gen")
#: bump when :func:`ycb_patch_set` changes what it renders (part of the cache key)
DATA_VERSION = 1
#: the six hue offsets of the colour augmentation (OpenCV hue units: 180 = a full turn)
HUE_SHIFTS = (-30, -20, -10, 10, 20, 30)


# ----------------------------------------------------------------------------------------------- data
@dataclass
class PatchSet:
    """Simulated YCB patch presses.

    Attributes:
        images: (N, H, W, 3) uint8 BGR tactile images.
        labels: (N,) int class index into ``classes``.
        masks: (N, H, W) uint8 contact footprints (indentation > 0.02 mm; the simulator's, used only as the
            generator's reference footprint, as the paper gives its generator the contact mask).
        depths: (N,) press depth, mm.
        classes: object file stems.
    """

    images: np.ndarray
    labels: np.ndarray
    masks: np.ndarray
    depths: np.ndarray
    classes: tuple[str, ...]

    def __len__(self) -> int:
        return len(self.labels)


def ycb_patch_set(
    n_per_class: int,
    seed: int,
    unit_seed: int = 4242,
    background: np.ndarray | None = None,
    objects: tuple[str, ...] | None = None,
) -> PatchSet:
    """Render ``n_per_class`` presses of each shared YCB object (``objects``: file stems, default all six; see
    the module doc); ``unit_seed`` picks the optical-model sensor unit (4242 is not one of the generator's
    training units). Needs the shared meshes
    (:func:`vtrack.language.ycb.ycb_dir`); raises :class:`InputError` when they are missing."""
    from vtrack.language.ycb import YCB_OBJECTS, press_height, sensor_pose
    from vtrack.sim.tactile_optics import OpticalModel
    from vtrack.tactile.sensors import default_background

    bg = default_background("gelsight", W, H) if background is None else background
    model = OpticalModel.for_sensor("gelsight", seed=unit_seed)
    rng = np.random.default_rng(seed)
    imgs, labels, masks, depths = [], [], [], []
    classes = tuple(YCB_OBJECTS) if objects is None else tuple(objects)
    for stem in classes:
        if stem not in YCB_OBJECTS:
            raise InputError("unknown YCB object", field="objects", expected=" | ".join(YCB_OBJECTS), got=stem)
    for c, stem in enumerate(classes):
        got, tries = 0, 0
        while got < n_per_class:
            tries += 1
            if tries > 20 * n_per_class + 20:
                raise InputError("could not draw enough YCB contacts", field=stem, expected=n_per_class, got=got)
            d = float(rng.uniform(*DEPTH_RANGE_MM))
            off = (float(rng.uniform(-0.25, 0.25) * W), float(rng.uniform(-0.25, 0.25) * H))
            T, _ = sensor_pose(stem, rng, d, float(rng.uniform(0, 360)), off, MM_PER_PX)
            h = press_height(stem, T, W, H, MM_PER_PX, d)
            m = (h > 0.02).astype(np.uint8)
            if m.mean() < MIN_FOOTPRINT_FRAC:
                continue
            imgs.append(model.render(h, MM_PER_PX, bg, rng, noise=1.0))
            masks.append(m)
            labels.append(c)
            depths.append(d)
            got += 1
    return PatchSet(np.stack(imgs), np.array(labels), np.stack(masks), np.array(depths, np.float32), classes)


def cached_patch_set(n_per_class: int, seed: int, unit_seed: int = 4242) -> PatchSet:
    """:func:`ycb_patch_set` through an ``.npz`` cache in :func:`vtrack.paths.cache_dir` (keyed by the
    arguments, :data:`DATA_VERSION`, the data constants and the YCB module's source)."""
    import hashlib
    from pathlib import Path

    from vtrack.io.jsonio import atomic_savez
    from vtrack.language import ycb
    from vtrack.paths import cache_dir

    h = hashlib.sha1(f"{DATA_VERSION}:{n_per_class}:{seed}:{unit_seed}:{DEPTH_RANGE_MM}:{MIN_FOOTPRINT_FRAC}".encode())

    h.update(Path(ycb.__file__).read_bytes())
    path = cache_dir() / "generate_classify" / f"ycb_{h.hexdigest()[:16]}.npz"
    if path.is_file():
        z = np.load(path)
        return PatchSet(z["images"], z["labels"], z["masks"], z["depths"], tuple(str(s) for s in z["classes"]))
    ps = ycb_patch_set(n_per_class, seed, unit_seed)
    atomic_savez(
        path, images=ps.images, labels=ps.labels, masks=ps.masks, depths=ps.depths, classes=np.array(ps.classes)
    )
    return ps


def to_input(images: np.ndarray, background: np.ndarray) -> np.ndarray:
    """(N, 3, IN_H, IN_W) float32 network input: colour change against ``background``, area-resized, /
    :data:`INPUT_SCALE`. ``images`` uint8 (N, H, W, 3) or float colour changes when ``background`` is None."""
    import cv2

    bgf = None if background is None else background.astype(np.float32)
    out = []
    for im in images:
        d = im.astype(np.float32) - bgf if bgf is not None else np.asarray(im, np.float32)
        out.append(cv2.resize(d, (IN_W, IN_H), interpolation=cv2.INTER_AREA).transpose(2, 0, 1) / INPUT_SCALE)
    return np.ascontiguousarray(np.stack(out), np.float32)


# ----------------------------------------------------------------------------------------------- augmentation
def geometric(delta: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One random geometric variant (paper E.4: rotation k*45 deg, flip none/h/v/both, scale 0.8/1/1.2,
    translation -20/0/20 px per axis at 320x240, scaled to the image) of a colour change (float (H, W, 3));
    zero change where the moved image does not reach."""
    import cv2

    h, w = delta.shape[:2]
    ang = 45.0 * int(rng.integers(0, 8))
    sc = float(rng.choice([0.8, 1.0, 1.2]))
    tx, ty = (float(rng.choice([-20, 0, 20])) * w / W for _ in range(2))
    flip = int(rng.integers(0, 4))  # 0 none, 1 horizontal, 2 vertical, 3 both
    d = delta
    if flip & 1:
        d = d[:, ::-1]
    if flip & 2:
        d = d[::-1]
    M = cv2.getRotationMatrix2D((w / 2, h / 2), ang, sc)
    M[:, 2] += (tx, ty)
    return cv2.warpAffine(np.ascontiguousarray(d, np.float32), M, (w, h), flags=cv2.INTER_LINEAR, borderValue=0)


def hue_shift(image: np.ndarray, shift: int) -> np.ndarray:
    """uint8 BGR image with its hue rotated by ``shift`` OpenCV hue units (180 = a full turn)."""
    import cv2

    hsv = cv2.cvtColor(np.asarray(image, np.uint8), cv2.COLOR_BGR2HSV)
    hsv[..., 0] = ((hsv[..., 0].astype(np.int32) + int(shift)) % 180).astype(np.uint8)
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)


def colour(delta: np.ndarray, background: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Colour variant of a colour change: the image (background + change) and the background are both
    hue-shifted by one of :data:`HUE_SHIFTS` (another sensor's LED colours); returns the new change."""
    s = int(rng.choice(HUE_SHIFTS))
    bgf = background.astype(np.float32)
    img = np.clip(np.rint(bgf + delta), 0, 255).astype(np.uint8)
    return hue_shift(img, s).astype(np.float32) - hue_shift(background, s).astype(np.float32)


def augment_set(
    kind: str,
    images: np.ndarray,
    masks: np.ndarray,
    depths: np.ndarray,
    background: np.ndarray,
    n_per_ref: int,
    seed: int = 0,
    generator=None,
) -> np.ndarray:
    """(len(images) * n_per_ref, 3, IN_H, IN_W) network inputs augmented from each reference in turn (so the
    label of output row ``k`` is that of reference ``k // n_per_ref``). ``kind``: ``G``, ``G+C`` or ``Gen``
    (``generator``: a :class:`TactileGenerator`, default the shipped two-stage one)."""
    from vtrack.tactile.generate import data as gd

    if kind not in AUGMENTATIONS[1:]:
        raise InputError("unknown augmentation", field="augmentation", expected=" | ".join(AUGMENTATIONS[1:]), got=kind)
    rng = np.random.default_rng(seed)
    bgf = background.astype(np.float32)
    out = []
    if kind in ("G", "G+C"):
        for im in images:
            d = im.astype(np.float32) - bgf
            for _ in range(n_per_ref):
                a = geometric(d, rng)
                out.append(colour(a, background, rng) if kind == "G+C" else a)
        return to_input(np.stack(out), None)
    if generator is None:
        from vtrack.tactile.generate.generator import TactileGenerator

        generator = TactileGenerator(threads=0)
    h, w = background.shape[:2]
    for im, m, dep in zip(images, masks, depths, strict=True):
        rp = gd.mask_pose(m)
        reqs, tries = [], 0
        while len(reqs) < n_per_ref:
            tries += 1
            # a footprint too large to move anywhere on the gel (a flat face): only its depth changes
            stay = tries > 20 * n_per_ref
            tp = rp if stay else gd.Pose(
                float(rng.uniform(0.25, 0.75) * w),
                float(rng.uniform(0.25, 0.75) * h),
                rp.theta_deg + float(rng.uniform(0, 360)),
            )  # fmt: skip
            try:
                req = generator.prepare(
                    im,
                    background,
                    ref_depth_mm=float(dep),
                    target_depth_mm=float(rng.uniform(*DEPTH_RANGE_MM)),
                    target_pose=tp,
                    ref_mask=m,
                )
            except InputError:
                if stay:
                    raise
                continue  # the move would push most of the footprint off the gel: draw another target
            reqs.append(req)
        out += generator.generate_many(reqs, background)
    return to_input(np.stack(out), background)


# ----------------------------------------------------------------------------------------------- models
def small_cnn(n_classes: int):
    """The paper's CNN classifier (four conv3x3 + BatchNorm + ReLU + 2x2 max-pool blocks, then Linear-ReLU-
    Dropout 0.5-Linear), narrowed to 8/16/32/64 channels for 80x60 inputs (CPU budget)."""
    from torch import nn

    def blk(i: int, o: int) -> nn.Module:
        return nn.Sequential(nn.Conv2d(i, o, 3, padding=1), nn.BatchNorm2d(o), nn.ReLU(inplace=True), nn.MaxPool2d(2))

    return nn.Sequential(
        blk(3, 8), blk(8, 16), blk(16, 32), blk(32, 64), nn.Flatten(),
        nn.Linear(64 * (IN_H // 16) * (IN_W // 16), 128), nn.ReLU(inplace=True), nn.Dropout(0.5),
        nn.Linear(128, n_classes),
    )  # fmt: skip


def _vit_class():
    import torch
    from torch import nn

    class SmallViT(nn.Module):
        """A small vision transformer from scratch: ``patch`` x ``patch`` patch embedding (strided conv),
        class token, learned position embedding, ``depth`` pre-norm encoder layers of width ``dim`` with
        ``heads`` heads (MLP 2x), LayerNorm, linear head on the class token. Input (B, 3, IN_H, IN_W)."""

        def __init__(self, n_classes: int, patch: int = 10, dim: int = 48, depth: int = 3, heads: int = 4):
            super().__init__()
            if IN_H % patch or IN_W % patch:
                raise InputError("patch size must divide the input size", field="patch", got=patch)
            self.n_tokens = (IN_H // patch) * (IN_W // patch)
            self.embed = nn.Conv2d(3, dim, patch, stride=patch)
            self.cls = nn.Parameter(torch.zeros(1, 1, dim))
            self.pos = nn.Parameter(torch.randn(1, self.n_tokens + 1, dim) * 0.02)
            layer = nn.TransformerEncoderLayer(
                dim, heads, 2 * dim, dropout=0.1, activation="gelu", batch_first=True, norm_first=True
            )
            self.encoder = nn.TransformerEncoder(layer, depth, enable_nested_tensor=False)
            self.norm = nn.LayerNorm(dim)
            self.head = nn.Linear(dim, n_classes)

        def tokens(self, x: torch.Tensor) -> torch.Tensor:
            """(B, n_tokens + 1, dim) encoded tokens, class token first."""
            t = self.embed(x).flatten(2).transpose(1, 2)
            t = torch.cat([self.cls.expand(len(t), -1, -1), t], 1) + self.pos
            return self.encoder(t)

        def forward(self, x: torch.Tensor) -> torch.Tensor:
            return self.head(self.norm(self.tokens(x)[:, 0]))

    return SmallViT


def small_vit(n_classes: int, **kw):
    """:class:`SmallViT` (defined lazily: torch is imported only when a model is built)."""
    return _vit_class()(n_classes, **kw)


def build_model(arch: str, n_classes: int):
    if arch == "cnn":
        return small_cnn(n_classes)
    if arch == "vit":
        return small_vit(n_classes)
    raise InputError("unknown classifier", field="arch", expected="cnn | vit", got=arch)


def train_classifier(
    arch: str,
    X: np.ndarray,
    y: np.ndarray,
    n_classes: int,
    steps: int,
    seed: int = 0,
    batch: int = 32,
    lr: float = 1e-3,
):
    """Train ``arch`` (``cnn`` | ``vit``) for exactly ``steps`` AdamW steps of ``batch`` samples drawn
    uniformly from ``(X, y)`` (cosine learning rate, weight decay 0.05); returns the model in eval mode."""
    import torch

    if len(X) == 0 or len(X) != len(y):
        raise InputError("empty or mismatched training set", field="X", expected="len(X) == len(y) > 0", got=len(X))
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    net = build_model(arch, n_classes)
    opt = torch.optim.AdamW(net.parameters(), lr=lr, weight_decay=0.05)
    warm = max(1, steps // 20)
    sched = torch.optim.lr_scheduler.LambdaLR(
        opt, lambda s: min(1.0, (s + 1) / warm) * 0.5 * (1 + math.cos(math.pi * min(s, steps) / steps))
    )
    Xt, yt = torch.from_numpy(np.ascontiguousarray(X, np.float32)), torch.from_numpy(np.asarray(y, np.int64))
    net.train()
    for _ in range(steps):
        idx = torch.from_numpy(rng.integers(0, len(Xt), batch))
        loss = torch.nn.functional.cross_entropy(net(Xt[idx]), yt[idx])
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
    return net.eval()


def accuracy(net, X: np.ndarray, y: np.ndarray, batch: int = 128) -> float:
    """Top-1 accuracy of ``net`` on ``(X, y)``."""
    import torch

    pred = []
    with torch.inference_mode():
        for i in range(0, len(X), batch):
            pred.append(net(torch.from_numpy(X[i : i + batch])).argmax(1).numpy())
    return float(np.mean(np.concatenate(pred) == np.asarray(y)))
