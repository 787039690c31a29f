"""Object classification with generated / geometric / colour augmentation (vtrack.tactile.generate.classify,
issue #24 downstream study): model shapes, augmentations keep the label, a tiny run learns, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from vtrack.errors import InputError
from vtrack.tactile.generate import classify as cl

W, H, MPP = cl.W, cl.H, cl.MM_PER_PX


@pytest.fixture(scope="module")
def presses():
    """Two simulated presses (independent optical model, shipped GelSight background): a shallow small ball
    and a deep large ball, with their footprints and depths."""
    from vtrack.sim.presses import ball_height
    from vtrack.sim.tactile_optics import OpticalModel
    from vtrack.tactile.sensors import default_background

    bg = default_background("gelsight", W, H)
    model = OpticalModel.for_sensor("gelsight", seed=7)
    rng = np.random.default_rng(0)
    hs = [ball_height((H, W), (150.0, 120.0), 1.5, 0.25, MPP), ball_height((H, W), (170.0, 110.0), 4.0, 1.2, MPP)]
    imgs = np.stack([model.render(h, MPP, bg, rng) for h in hs])
    masks = np.stack([(h > 0.02).astype(np.uint8) for h in hs])
    return imgs, masks, np.array([0.25, 1.2], np.float32), bg


def test_model_output_shapes():
    import torch

    x = torch.zeros(2, 3, cl.IN_H, cl.IN_W)
    vit = cl.small_vit(6)
    assert vit.tokens(x).shape == (2, vit.n_tokens + 1, 48)
    assert vit.n_tokens == (cl.IN_H // 10) * (cl.IN_W // 10)
    assert vit(x).shape == (2, 6)
    assert cl.small_cnn(5).eval()(x).shape == (2, 5)
    with pytest.raises(InputError):
        cl.small_vit(6, patch=7)  # 7 divides neither 60 nor 80
    with pytest.raises(InputError):
        cl.build_model("resnet", 6)


def test_colour_augmentation_of_no_change_is_no_change(presses):
    _, _, _, bg = presses
    out = cl.colour(np.zeros((H, W, 3), np.float32), bg, np.random.default_rng(0))
    assert np.abs(out).max() == 0.0
    # and a hue shift really changes the colour of a press
    d = presses[0][1].astype(np.float32) - bg.astype(np.float32)
    shifted = cl.colour(d, bg, np.random.default_rng(1))
    assert np.abs(shifted - d).mean() > 0.5


@pytest.mark.parametrize("kind", ["G", "G+C"])
def test_geometric_and_colour_augmentation_keep_each_reference_apart(presses, kind):
    """Row k of the augmented set comes from reference k // n: the shallow small ball's variants all carry
    far less colour change than the deep large ball's (scale <= 1.2 and a hue shift cannot swap them)."""
    imgs, masks, depths, bg = presses
    n = 12
    X = cl.augment_set(kind, imgs, masks, depths, bg, n, seed=3)
    assert X.shape == (2 * n, 3, cl.IN_H, cl.IN_W) and np.isfinite(X).all()
    energy = np.abs(X).sum((1, 2, 3))
    assert energy[:n].max() < energy[n:].min()
    # geometric variants differ from each other (not n copies)
    assert np.abs(X[0] - X[1]).mean() + np.abs(X[1] - X[2]).mean() > 0.01


def test_generated_augmentation_keeps_each_reference_apart(presses):
    imgs, masks, depths, bg = presses
    n = 4
    X = cl.augment_set("Gen", imgs, masks, depths, bg, n, seed=0)
    assert X.shape == (2 * n, 3, cl.IN_H, cl.IN_W) and np.isfinite(X).all()
    # generated targets are drawn at 0.2-0.7 mm from both references: the 4 mm ball keeps a much larger
    # footprint than the 1.5 mm one at any of those depths
    area = (np.abs(X).sum(1) > 0.3).sum((1, 2))
    assert area[:n].max() < area[n:].min()
    with pytest.raises(InputError):
        cl.augment_set("mixup", imgs, masks, depths, bg, n)


def _toy_set(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """An easy split (80x60 colour changes): a blob of random size and position whose colour change is mostly
    red (class 0), green (1) or blue (2), on noise."""
    yy, xx = np.mgrid[0 : cl.IN_H, 0 : cl.IN_W]
    X, y = [], []
    for i in range(n):
        c = i % 3
        cx, cy, r = rng.uniform(20, 60), rng.uniform(15, 45), rng.uniform(4, 10)
        m = ((xx - cx) ** 2 + (yy - cy) ** 2 < r * r).astype(np.float32)
        col = np.full(3, 0.2, np.float32)
        col[c] = 1.0
        X.append((col[:, None, None] * m + rng.normal(0, 0.1, (3, cl.IN_H, cl.IN_W))).astype(np.float32))
        y.append(c)
    return np.stack(X), np.array(y)


@pytest.mark.parametrize("arch", ["cnn", "vit"])
def test_tiny_training_run_beats_chance(arch):
    import torch

    torch.set_num_threads(1)
    rng = np.random.default_rng(0)
    Xtr, ytr = _toy_set(48, rng)
    Xte, yte = _toy_set(60, rng)
    net = cl.train_classifier(arch, Xtr, ytr, 3, steps=40, batch=16, lr=3e-3)
    acc = cl.accuracy(net, Xte, yte)
    assert acc >= 0.7, acc  # chance 0.33
    with pytest.raises(InputError):
        cl.train_classifier(arch, Xtr[:0], ytr[:0], 3, steps=1)


def test_ycb_patch_set_renders_labelled_presses(shared_data):
    objs = ("025_mug", "055_baseball")
    ps = cl.ycb_patch_set(2, seed=5, objects=objs)
    assert ps.classes == objs and len(ps) == 4
    assert ps.images.shape == (4, H, W, 3) and ps.images.dtype == np.uint8
    assert list(ps.labels) == [0, 0, 1, 1]
    assert all(m.mean() >= cl.MIN_FOOTPRINT_FRAC for m in ps.masks)
    lo, hi = cl.DEPTH_RANGE_MM
    assert ((ps.depths >= lo) & (ps.depths <= hi)).all()
