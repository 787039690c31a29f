"""vtrack.language, session 2026-11-26 (late morning): the texture-statistics branch of the tactile encoder, the
MLP text projection (model version 3), P1 before vs after the projection, free-form queries with unseen
distractor words and the description oracle."""

from __future__ import annotations

import numpy as np
import pytest

from vtrack.testing.language import LANGUAGE_EXTRA_MISSING, have_language_extra, procedural_set

HAVE_EXTRA = have_language_extra()
needs_extra = pytest.mark.skipif(not HAVE_EXTRA, reason=LANGUAGE_EXTRA_MISSING)


def _ridges(period_px: float, angle_deg: float, h: int = 60, w: int = 80):
    """A (1, 3, h, w) float32 batch of a sinusoidal ridge pattern of the given period and orientation."""
    import torch

    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    a = np.deg2rad(angle_deg)
    img = 0.5 * np.cos(2 * np.pi * (np.cos(a) * xx + np.sin(a) * yy) / period_px)
    return torch.as_tensor(np.repeat(img[None, None], 3, 1))


def test_texture_stats_see_wavelength_and_are_rotation_normalised() -> None:
    import torch

    from vtrack.language.model import N_RADIAL, N_TEXTURE, texture_stats

    fine, coarse = texture_stats(_ridges(4.0, 0.0)), texture_stats(_ridges(11.2, 0.0))
    assert fine.shape == (1, N_TEXTURE) and bool(torch.isfinite(fine).all())
    # the radial band holding most energy: 1/4 cycles/px vs 1/11.2 cycles/px (band width 0.5 / N_RADIAL)
    band = lambda f: int(f[0, :N_RADIAL].argmax())  # noqa: E731
    assert band(fine) == int(0.25 / 0.5 * N_RADIAL)
    assert band(coarse) == int(1 / 11.2 / 0.5 * N_RADIAL)
    # the orientation bands are rolled to the strongest: a ridge pattern turned by 90 degrees looks the same
    a0 = texture_stats(_ridges(6.0, 0.0))[0, N_RADIAL : N_TEXTURE - 4]
    a90 = texture_stats(_ridges(6.0, 90.0))[0, N_RADIAL : N_TEXTURE - 4]
    assert float(a0[0]) > 0.8 and torch.allclose(a0, a90, atol=0.05)
    # a blank frame (no contact) gives finite numbers, not NaN
    assert bool(torch.isfinite(texture_stats(torch.zeros(2, 3, 60, 80))).all())


@needs_extra
def test_version3_architecture_round_trips_and_p1_before_projection() -> None:
    """A model with the texture branch and the MLP text projection trains, saves and loads (arch recorded);
    with a linear projection, P1 before the projection (s_hat added to the frozen pooled g(T)) is P1 after it
    at the strength a |W_text s_hat|; with the MLP it is not a fixed offset (it depends on the text)."""
    import torch

    from vtrack.language.model import Steering, TouchSteer, build, train
    from vtrack.language.text import token_arrays

    torch.set_num_threads(1)
    per = 4
    imgs = np.random.default_rng(0).normal(0, 0.3, (4 * per, 3, 60, 80)).astype(np.float32)
    data = procedural_set(per_material=per, n_materials=4, split="train", images=imgs)
    texts = ["feels soft and smooth; not hard. it looks red.", "feels hard, coarsely ridged and deep; not soft."]
    tok, mask = (torch.as_tensor(a) for a in token_arrays(texts))
    vocab = ["<bos>", "<eos>", "soft"]
    wv = np.random.default_rng(1).normal(0, 0.4, (3, 50)).astype(np.float32)
    s_hat = (wv[2] / np.linalg.norm(wv[2])).astype(np.float32)
    torch.manual_seed(0)
    lin, mlp = build(vocab, wv, s_hat, texture=True), build(vocab, wv, s_hat, text_mlp=True)
    with torch.no_grad():
        k = float(lin.w_text(lin.s_hat[None]).norm())
        assert torch.allclose(lin.text_embed(tok, mask, pre=0.7), lin.text_embed(tok, mask, 0.7 * k), atol=1e-5)
        # the offset that P1-pre makes in the MLP's output differs between the two texts
        g = mlp.pool(tok, mask)
        d = mlp.w_text(g + 0.7 * mlp.s_hat[None]) - mlp.w_text(g)
        assert float((d[0] - d[1]).norm()) > 1e-4
    m = train(data, steering=Steering(design="none"), epochs=1, batch=16, seed=0, texture=True, text_mlp=True)
    assert m.net.arch == {"texture": True, "text_mlp": True}
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        p = m.save(Path(tmp) / "m.pt")
        back = TouchSteer.load(p)
        assert back.net.arch == {"texture": True, "text_mlp": True}
        assert np.allclose(back.encode_images(imgs[:3]), m.encode_images(imgs[:3]), atol=2e-2)  # fp16 weights


def test_auc_is_the_pairwise_selection_rate_and_ap_is_exact() -> None:
    from vtrack.language.evaluate import _auc_ap

    s = np.array([0.9, 0.1, 0.5, 0.3, 0.5])
    pos = np.array([True, False, True, False, False])
    neg = ~pos
    auc, ap = _auc_ap(s, pos, neg)
    # pairs (pos, neg): 0.9 beats all 3; 0.5 beats 0.1 and 0.3, ties 0.5 -> (3 + 2.5) / 6
    assert auc == pytest.approx(5.5 / 6)
    # ranking 0.9(+) 0.5(+) 0.5(-) 0.3 0.1 (stable sort keeps the positive first): AP = (1/1 + 2/2) / 2
    assert ap == pytest.approx(1.0)


@needs_extra
def test_freeform_queries_carry_only_unseen_distractor_words() -> None:
    from vtrack.language.evaluate import QUERIES, UNSEEN_APPEARANCE, UNSEEN_NOUNS, freeform_queries
    from vtrack.language.materials import COLOURS, SHAPES
    from vtrack.language.model import words_of

    q = freeform_queries(variants=4)
    assert len(q) == 4 * len(QUERIES) and {i for _, i in q} == set(range(len(QUERIES)))
    seen = set(COLOURS) | set(SHAPES)
    for text, i in q:
        extra = set(words_of(text)) - set(words_of(QUERIES[i][0])) - {"a", "it", "should", "look", "and"}
        extra -= {",", ";", ":", "."}
        assert extra and extra <= set(UNSEEN_APPEARANCE) | set(UNSEEN_NOUNS)
        assert not extra & seen
    assert freeform_queries(distractor=False)[0] == (QUERIES[0][0], 0)


def test_description_oracle_counts_shared_descriptions() -> None:
    from vtrack.language.evaluate import description_oracle

    data = procedural_set(per_material=2, n_materials=12)
    o = description_oracle(data)
    # procedural materials differ in at least one tactile attribute: every description is distinct
    assert o["n_materials"] == 12
    assert o["tactile_only"]["distinct_descriptions"] == 12 and o["tactile_only"]["oracle_r1"] == 1.0
    # two materials given the same description (a copy of material 0 under another index) halve their oracle
    from dataclasses import replace

    mats = list(data.materials)
    twin = replace(mats[int(data.material[0])], index=len(mats))
    data.materials = [*mats, twin]
    data.material = data.material.copy()
    data.material[-2:] = twin.index
    o2 = description_oracle(data)
    assert o2["tactile_only"]["materials_sharing_a_description"] == 2
    assert o2["tactile_only"]["oracle_r1"] == pytest.approx((10 + 0.5 + 0.5) / 12)
