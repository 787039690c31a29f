"""vtrack.language diagnostics of session 2026-11-26: the steering vector is the paper's mean e(A) - mean e(N)
in the space it steers; how much of the text embedding the distractor words move (and along which direction);
the heavy-distractor texts; the class-text loss trains."""

from __future__ import annotations

import numpy as np
import pytest

from vtrack.testing.language import LANGUAGE_EXTRA_MISSING, have_language_extra, procedural_set

HAVE_EXTRA = have_language_extra()
needs_extra = pytest.mark.skipif(not HAVE_EXTRA, reason=LANGUAGE_EXTRA_MISSING)


@needs_extra
def test_steering_vector_is_the_encoded_lexicon_difference_in_the_steered_space() -> None:
    """Paper Sec. III-B/C: s = mean e(A) - mean e(N) with e(w) the text encoder's token embedding, then
    s_proj = W_text s_hat / |W_text s_hat|. Encoding each lexicon word alone with our text side (attention
    pooling over one token is that token's GloVe vector) and averaging in the projected space gives the same
    unit vector as the stored s_proj."""
    import torch

    from vtrack.language.api import load
    from vtrack.language.text import LEXICON_A, LEXICON_N, token_arrays

    model, _ = load(None, "none")  # stores the A-N vector (injected only at inference)
    net = model.net
    if getattr(net, "arch", {}).get("text_mlp"):
        # a non-linear projection: s_proj is its response to s_hat from the origin, normalize(mlp(s) - mlp(0))
        # (for a linear W_text the same vector as the encoded lexicon difference checked below)
        with torch.no_grad():
            d = net.w_text(net.s_hat[None])[0] - net.w_text(torch.zeros_like(net.s_hat)[None])[0]
            assert float((d / d.norm()) @ net.s_proj()) > 0.9999
        return
    with torch.no_grad():
        enc = []
        for lex in (LEXICON_A, LEXICON_N):
            tok, mask = (torch.as_tensor(a) for a in token_arrays(list(lex)))
            assert int(mask.sum()) == len(lex)  # every lexicon word is in the GloVe vocabulary
            enc.append(net.w_text(net.pool(tok, mask)).mean(0))
        s = enc[0] - enc[1]
        s = s / s.norm()
        assert float(s @ net.s_proj()) > 0.9999


@needs_extra
def test_distractor_variance_small_after_training_large_in_frozen_glove() -> None:
    """The trained text side has learned to ignore the colour / shape clause (share of the text embedding's
    variance well under the frozen GloVe mean's); with variable distractor content (heavy texts) the share
    grows and concentrates along the A-N steering direction (far above a random direction's share)."""
    from vtrack.language.api import load
    from vtrack.language.evaluate import distractor_variance, heavy_distractor_texts

    model, _ = load(None, "none")
    data = procedural_set()
    contact, cls = heavy_distractor_texts(data)
    assert len(contact) == len(data.material) and len(cls) == len(np.unique(data.material))
    with_clause = [t for t in contact if "it looks" in t]
    assert 0.3 < len(with_clause) / len(contact) < 0.7
    assert all(t.endswith(".") and ".." not in t for t in contact)
    d = distractor_variance(model, data, draws=4)
    h = distractor_variance(model, data, draws=4, heavy=True)
    # measured on the shipped weights (60 contacts, 4 draws): canonical 0.02 vs GloVe mean 0.17; heavy 0.09,
    # half of it along s_proj (random direction 1/64)
    assert d["distractor_variance_share"] < 0.05 < 0.1 < d["distractor_variance_share_glove_mean"]
    assert h["distractor_variance_share"] > 2 * d["distractor_variance_share"]
    assert h["distractor_variance_along_s_proj"] > 10 * h["random_direction_share"]
    for v in (*d.values(), *h.values()):
        assert np.isfinite(v)


@needs_extra
def test_p1p_projection_removes_the_component_along_s_proj() -> None:
    import torch

    from vtrack.language.api import load
    from vtrack.language.text import token_arrays

    model, _ = load(None, "none")
    net = model.net
    tok, mask = (torch.as_tensor(a) for a in token_arrays(["feels soft and smooth; not hard. it looks red, shiny."]))
    with torch.no_grad():
        full = net.text_embed(tok, mask, proj=1.0)
        half = net.w_text(net.pool(tok, mask))
        half = half - 0.5 * (half @ net.s_proj())[:, None] * net.s_proj()[None]
        assert abs(float(full @ net.s_proj())) < 1e-5
        assert torch.allclose(net.text_embed(tok, mask, proj=0.5), half / half.norm(dim=1, keepdim=True), atol=1e-6)


@needs_extra
def test_class_text_loss_runs_and_is_recorded() -> None:
    """Training with the class-text loss (every image against all training materials' texts) on a tiny set:
    finite unit embeddings and the weight recorded in the model's meta (its effect on R@1, measured over three
    seeds, is in docs/language.md: not shipped)."""
    import torch

    from vtrack.language.model import Steering, train

    torch.set_num_threads(1)
    per = 4
    rng = np.random.default_rng(0)
    imgs = rng.normal(0, 0.3, (4 * per, 3, 60, 80)).astype(np.float32)
    data = procedural_set(per_material=per, n_materials=4, split="train", images=imgs)
    model = train(data, steering=Steering(design="none"), epochs=2, batch=16, seed=0, class_text_weight=1.0)
    assert model.meta["class_text_weight"] == 1.0
    v = model.encode_images(imgs[:4])
    assert np.isfinite(v).all() and np.allclose(np.linalg.norm(v, axis=1), 1, atol=1e-4)
