"""Correlated-appearance study: the setting where the paper's steering is meant to help, built on our data.

In real tactile-language data the non-tactile words of a description are correlated with the object: a given
sponge is always yellow, a given mug always red, and annotators write what they see. A model trained on such
texts can lean on the appearance words (they identify the training material as well as the tactile words do),
and is misled when a held-out contact is described with other non-tactile words (another instance of the
material, another annotator). TouchSteer's steering vector ``s = mean e(A) - mean e(N)`` is meant to pull the
text side toward tactile meaning there.

Here: training texts carry each material's fixed instance appearance (``train(..., appearance="instance")``,
:func:`vtrack.language.materials.instance_appearance`); validation and test texts of the held-out contacts are
written with another appearance (``appearance="other"``: never the material's own colour / shape pair, so
the clause points to a wrong training material or to none). The steering strength is chosen on the validation
contacts, which see the same shift, never on the test ones. The canonical texts (random colour / shape in
training and test) stay the project's evaluation; this module adds rows beside them.

Compared, for the A-N vector, the A-only vector and ``n_random`` random unit directions of the GloVe space:
P1 (the paper's, on the projected text embedding), P1 before the projection (``s_hat`` on the pooled frozen
vector g(T)), P1w (ours: each word's pooling logit ``+ a e(w).s_hat``), and for generation P4 (the describer's
tactile input) and P3 (its input word vectors); retrieval R@1 / R@5, silhouette and inter/intra of the Fig. 6
similarity vectors, BLEU-1 against references that carry the other appearance.
"""

from __future__ import annotations

import numpy as np

from vtrack.eval.language_metrics import bleu1
from vtrack.language.evaluate import EVAL_SEED, retrieval
from vtrack.language.materials import (
    COLOURS,
    SHAPES,
    TactileSet,
    description,
    instance_appearance,
    other_appearance,
)

#: inference strengths swept on the validation split per retrieval position (0 = no steering, always a candidate)
RETRIEVAL_ALPHAS: dict[str, tuple[float, ...]] = {
    "p1": (0.0, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5),
    "pre": (0.0, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0),
    "p1w": (0.0, 0.2, 0.5, 1.0, 2.0, 5.0),
}
#: strengths of the generation positions (P4 on f(I), 27-31 in norm; P3 on the GloVe input words)
GENERATION_ALPHAS: dict[str, tuple[float, ...]] = {
    "p4": (0.0, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0),
    "p3": (0.0, 0.1, 0.2, 0.5, 1.0, 2.0),
}
_KEYS = ("r1", "r5", "r1_text2touch", "r1_touch2text", "instance_r1", "silhouette", "inter_intra")


def appearance_texts(data: TactileSet, appearance: str, *, seed: int = EVAL_SEED) -> tuple[list[str], list[str]]:
    """(contact texts, material-level texts of ``np.unique(data.material)``) with the distractor clause of
    ``appearance`` ("instance": each material's own colour / shape; "other": another instance's; "random": the
    canonical texts)."""
    contact = data.texts(mode=2, seed=seed, appearance=appearance)
    mats = np.unique(data.material)
    if appearance == "random":
        from vtrack.language.evaluate import class_texts

        return contact, class_texts(data, mats)
    own = instance_appearance(data.materials)
    rng = np.random.default_rng([seed + 1, 7])
    cls = []
    for m in mats:
        a = own[int(m)] if appearance == "instance" else other_appearance(own[int(m)], rng)
        cls.append(description(data.materials[int(m)], None, mode=2, appearance=a))
    return contact, cls


def appearance_share(texts: list[str]) -> float:
    """Share of generated texts that name a colour or shape (the describer's non-tactile output)."""
    words = set(COLOURS) | set(SHAPES)
    return float(np.mean([any(w in words for w in t.replace(".", " ").replace(",", " ").split()) for t in texts]))


def attention_on_appearance(model, texts: list[str]) -> float:
    """Mean share of the text pooling's attention on colour / shape words (how much the text side leans on
    appearance)."""
    from vtrack.language.text import token_arrays, tokenize

    torch = __import__("torch")
    tok, mask, sign = (torch.as_tensor(a) for a in token_arrays(texts, signs=True))
    dist = set(COLOURS) | set(SHAPES)
    is_d = torch.zeros_like(mask)
    for i, t in enumerate(texts):
        for j, (w, _) in enumerate(tokenize(t)[: tok.shape[1]]):
            is_d[i, j] = float(w in dist)
    with torch.no_grad():
        w = model.net.word_weights(tok, mask, 0.0, sign)
    return float((w * is_d).sum(1).mean())


def _best(rows: list[tuple[float, float]]) -> float:
    """Strength with the best validation score (ties: the weaker one)."""
    return max(rows, key=lambda r: (r[1], -r[0]))[0]


def steering_correlated(
    model, data: TactileSet, *, split: str = "test", val: str = "val", n_random: int = 20, seed: int = 0
) -> dict:
    """Steering injected at inference into ``model`` (trained on instance-appearance texts) against held-out
    contacts described with another appearance; strengths chosen on ``val``. Returns the unsteered rows (texts
    with the other / the instance / no appearance, canonical texts), per vector x position the validation sweep,
    the chosen strength and the test metrics, the random directions' mean / sd and the share of them at least
    as good as A-N, and the generation rows (BLEU-1 against other-appearance references and tactile-only ones,
    share of descriptions naming a colour / shape)."""
    from vtrack.language.text import LEXICON_A, LEXICON_N, steering_vector

    torch = __import__("torch")
    sv, st = data.subset(data.split == val), data.subset(data.split == split)
    tv, tt = appearance_texts(sv, "other"), appearance_texts(st, "other")
    ret = lambda sub, texts, **kw: retrieval(model, sub, **({"p1": 0.0, "p2": 0.0} | kw), texts=texts)  # noqa: E731
    pick = lambda r: {k: r[k] for k in _KEYS}  # noqa: E731
    out: dict = {
        "meta": dict(model.meta),
        "none": {
            "other_appearance": pick(ret(st, tt)),
            "instance_appearance": pick(ret(st, appearance_texts(st, "instance"))),
            "no_appearance": pick(retrieval(model, st, p1=0.0, p2=0.0, distractor=False)),
            "canonical_texts": pick(retrieval(model, st, p1=0.0, p2=0.0)),
        },
        "attention_on_appearance": attention_on_appearance(model, tt[0]),
        "val_none_r1": ret(sv, tv)["r1"],
        "sweep_val": {},
        "chosen_on_val": {},
        "test": {},
    }
    keep = model.net.s_hat.clone()
    rng = np.random.default_rng(seed + 999)
    vectors = [("A-N", steering_vector(LEXICON_A, LEXICON_N)), ("A", steering_vector(LEXICON_A, None))]
    for k in range(n_random):
        r = rng.standard_normal(keep.shape[0])
        vectors.append((f"random{k}", (r / np.linalg.norm(r)).astype(np.float32)))
    try:
        for name, vec in vectors:
            model.net.s_hat.copy_(torch.as_tensor(vec))
            for pos, alphas in RETRIEVAL_ALPHAS.items():
                rows = [(a, ret(sv, tv, **{pos: a})["r1"]) for a in alphas]
                key = f"{name} {pos.upper()}"
                a = _best(rows)
                out["sweep_val"][key] = rows
                out["chosen_on_val"][key] = a
                out["test"][key] = pick(ret(st, tt, **{pos: a}))
        # generation: BLEU-1 against the held-out contacts' other-appearance descriptions
        ref_v, ref_t = tv[0], tt[0]
        ref_tactile = st.texts(mode=2, distractor=False)
        hyp0 = model.describe(st.images, 0.0, 0.0)
        out["none"]["generation"] = {
            "bleu1": bleu1(hyp0, ref_t),
            "bleu1_tactile_refs": bleu1(hyp0, ref_tactile),
            "appearance_share": appearance_share(hyp0),
            "example": hyp0[0],
        }
        gen_vectors = vectors[: 2 + min(n_random, 5)]
        for name, vec in gen_vectors:
            model.net.s_hat.copy_(torch.as_tensor(vec))
            for pos, alphas in GENERATION_ALPHAS.items():
                rows = [
                    (a, bleu1(model.describe(sv.images, **{pos: a, ("p3" if pos == "p4" else "p4"): 0.0}), ref_v))
                    for a in alphas
                ]
                key = f"{name} {pos.upper()}"
                a = _best(rows)
                out["sweep_val"][key] = rows
                out["chosen_on_val"][key] = a
                hyp = model.describe(st.images, **{pos: a, ("p3" if pos == "p4" else "p4"): 0.0})
                out["test"][key] = {
                    "bleu1": bleu1(hyp, ref_t),
                    "bleu1_tactile_refs": bleu1(hyp, ref_tactile),
                    "appearance_share": appearance_share(hyp),
                }
    finally:
        model.net.s_hat.copy_(keep)
    # random directions: mean / sd of their test scores, and how many do at least as well as A-N
    for pos in (*RETRIEVAL_ALPHAS, *GENERATION_ALPHAS):
        P = pos.upper()
        names = [k for k in out["test"] if k.startswith("random") and k.endswith(f" {P}")]
        if not names:
            continue
        metric = "bleu1" if pos in GENERATION_ALPHAS else "r1"
        vals = {m: np.array([out["test"][k][m] for k in names]) for m in out["test"][names[0]]}
        for k in names:
            out["test"].pop(k)
        out["test"][f"random {P}"] = {m: float(v.mean()) for m, v in vals.items()}
        out["test"][f"random {P}"] |= {f"{m}_sd": float(v.std()) for m, v in vals.items()} | {"n": len(names)}
        out["test"][f"A-N {P}"]["share_random_at_least_as_good"] = float(
            np.mean(vals[metric] >= out["test"][f"A-N {P}"][metric])
        )
    return out


def trained_design_rows(model, data: TactileSet, *, split: str = "test") -> dict:
    """A model trained with its steering active (the paper's Table V designs: P1 0.02 + P4 0.5 in training and
    inference) scored as trained on the held-out contacts: retrieval with the other / the instance appearance
    and BLEU-1 against the other-appearance references, its own injections on (compare with
    :func:`steering_correlated`'s ``none`` rows of the unsteered model trained alike)."""
    st = data.subset(data.split == split)
    pick = lambda r: {k: r[k] for k in _KEYS}  # noqa: E731
    tt = appearance_texts(st, "other")
    hyp = model.describe(st.images)
    return {
        "steering": dict(model.steering.__dict__),
        "other_appearance": pick(retrieval(model, st, texts=tt)),
        "instance_appearance": pick(retrieval(model, st, texts=appearance_texts(st, "instance"))),
        "no_appearance": pick(retrieval(model, st, distractor=False)),
        "attention_on_appearance": attention_on_appearance(model, tt[0]),
        "generation": {
            "bleu1": bleu1(hyp, tt[0]),
            "bleu1_tactile_refs": bleu1(hyp, st.texts(mode=2, distractor=False)),
            "appearance_share": appearance_share(hyp),
        },
    }
