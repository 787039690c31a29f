"""vtrack.language: YCB surface patches (geometry, press, descriptions) and per-word (P1w) steering."""

from __future__ import annotations

import numpy as np
import pytest

from vtrack.testing.language import LANGUAGE_EXTRA_MISSING, have_language_extra

HAVE_EXTRA = have_language_extra()
needs_extra = pytest.mark.skipif(not HAVE_EXTRA, reason=LANGUAGE_EXTRA_MISSING)


@pytest.fixture(scope="module")
def ycb(shared_data):
    from vtrack.language.materials import ycb_available

    if not ycb_available():
        pytest.skip(f"YCB meshes not found under {shared_data / 'objects' / 'ycb'}")
    return shared_data / "objects" / "ycb"


def test_ycb_curvature_matches_the_known_shapes(ycb) -> None:
    """The quadric fit gives the soup can's side radius (about 33 mm) and the baseball's (about 37 mm)."""
    from vtrack.language.ycb import local_surface, sample_surface

    rng = np.random.default_rng(3)
    for stem, lo, hi in (("005_tomato_soup_can", 25.0, 45.0), ("055_baseball", 28.0, 50.0)):
        radii = []
        for _ in range(40):
            p, n = sample_surface(stem, rng)
            nf, r, frame = local_surface(stem, p, n)
            assert abs(np.linalg.norm(nf) - 1) < 1e-6 and np.allclose(frame @ frame.T, np.eye(3), atol=1e-6)
            assert float(nf @ n) > 0.5  # the fitted normal stays on the outward side
            radii.append(r)
        assert lo <= float(np.median(radii)) <= hi, (stem, np.median(radii))


def test_ycb_press_depth_and_descriptions(ycb) -> None:
    from vtrack.language.materials import ATTRIBUTE_WORDS, contact_height, description, draw_contact, materials

    mats = [m for m in materials() if m.family == "ycb"]
    assert len(mats) == 6 and [m.index for m in mats] == list(range(62, 68))
    rng = np.random.default_rng(0)
    seen_curv = set()
    for m in mats:
        for _ in range(3):
            c = draw_contact(m, rng)
            h = contact_height(m, c, rng)
            assert h.shape == (60, 80) and np.isfinite(h).all()
            assert h.max() == pytest.approx(c.depth_mm, abs=1e-4)  # the deepest point is the press depth
            assert (h > 0.02).sum() >= 1
            seen_curv.add(c.curvature)
            d = description(m, c, rng=np.random.default_rng(1))
            assert d.startswith("feels hard") and "not soft" in d and c.curvature in d
            from vtrack.language.ycb import YCB_OBJECTS

            _, colour, shape = YCB_OBJECTS[m.obj]
            assert d.endswith(f"it looks {colour} and {shape}.")  # true, object-correlated distractors
            assert description(m, c, mode=3, rng=np.random.default_rng(1)).startswith(m.name + ":")
    assert seen_curv <= {"flat", "curved", "sharply curved"} and len(seen_curv) >= 2
    assert {"flat", "curved", "sharply"} <= ATTRIBUTE_WORDS


@needs_extra
def test_p1w_steering_moves_attention_off_distractor_words() -> None:
    """P1w (per-word steering in the pooling) takes attention away from colour / shape words, and more so with
    a stronger strength; the additive P1 offset leaves every text->touch ranking's text-specific part alone."""
    import torch

    from vtrack.language.api import load
    from vtrack.language.text import token_arrays

    model, gal = load(None, "none")
    texts = [
        "feels soft, finely ridged and shallow; not hard, not smooth. it looks red and square.",
        "feels hard and smooth; not soft, not rough. pressed firmly, centred. it looks blue and round.",
    ]
    tok, mask, sign = (torch.as_tensor(a) for a in token_arrays(texts, signs=True))
    share = []
    for beta in (0.0, 0.5, 2.0):
        with torch.no_grad():
            w = model.net.word_weights(tok, mask, beta, sign)
        # the last two known tokens of each text are its colour and shape words
        n = mask.sum(1).long()
        share.append(float(sum(w[i, n[i] - 2 : n[i]].sum() for i in range(len(texts))) / len(texts)))
    assert share[0] > share[1] > share[2]
    assert share[2] < 0.5 * share[0]
    # P1 (additive, text-independent) changes a query's image ranking only by the image prior s_proj . v
    v = torch.as_tensor(gal["emb"][:200]).float()
    with torch.no_grad():
        t_raw = model.net.w_text(model.net.pool(tok, mask))  # W_text g(T), before the normalisation
        t1 = model.net.text_embed(tok, mask, 0.5)
        prior = v @ model.net.s_proj()
        s1 = v @ t1.T  # (200, 2) steered scores
        s0 = v @ t_raw.T + 0.5 * prior[:, None]  # unnormalised unsteered scores + the image-only prior
    # per query, one is the other times a positive constant (the normalisation): the same ranking
    scale = s0 / s1
    assert torch.allclose(scale, scale[:1].expand_as(scale), rtol=1e-4) and bool((scale > 0).all())


@needs_extra
def test_steering_positions_follow_the_paper() -> None:
    """P1 / P2 add the projected steering vector before the normalisation; P3 shifts the describer's input
    word vectors by ``s_hat``; P4 shifts the tactile features f(I) (not the retrieval embedding) by ``s_hat``
    zero-padded to the feature dimension."""
    import torch

    from vtrack.language.api import load
    from vtrack.language.model import D_FEAT
    from vtrack.language.text import token_arrays

    model, _ = load(None, "none")
    net = model.net
    # the identities hold for any input: a fixed random batch shaped like the network input (3, 60, 80)
    x = 0.3 * torch.randn(6, 3, 60, 80, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        s_proj = net.s_proj()
        assert abs(float(s_proj.norm()) - 1) < 1e-5
        raw = net.w_img(net.enc(x))
        want = raw + 0.3 * s_proj
        assert torch.allclose(net.image_embed(x, 0.3), want / want.norm(dim=1, keepdim=True), atol=1e-5)
        tok, mask = (torch.as_tensor(a) for a in token_arrays(["feels soft and smooth; not hard. it looks red."]))
        t_raw = net.w_text(net.pool(tok, mask))
        want = t_raw + 0.02 * s_proj
        assert torch.allclose(net.text_embed(tok, mask, 0.02), want / want.norm(dim=1, keepdim=True), atol=1e-5)
        f = net.enc(x)
        s_feat = net.s_feat()
        assert s_feat.shape == (D_FEAT,) and torch.allclose(s_feat[:50], net.s_hat)
        assert float(s_feat[50:].abs().sum()) == 0
        ids = torch.zeros(6, 5, dtype=torch.long)
        steered = net.decode_logits(f, ids, 0.0, 0.5)
        assert torch.allclose(steered, net.decode_logits(f + 0.5 * s_feat, ids), atol=1e-5)
        assert not torch.allclose(steered, net.decode_logits(f, ids), atol=1e-3)
        # P3: the describer's input word vectors move along s_hat
        p3 = net.decode_logits(f, ids, 0.2)
        net.word_emb += 0.2 * net.s_hat
        try:
            assert torch.allclose(p3, net.decode_logits(f, ids), atol=1e-5)
        finally:
            net.word_emb -= 0.2 * net.s_hat
