"""The paper's evaluation on our generated data: object- / instance-level R@1 / R@5 in both directions,
BLEU-1 and attribute F1 of generated descriptions, silhouette and inter/intra ratio of the cross-modal
similarity vectors (Fig. 6), 2-way / 3-way selection from preference-style queries (Table VI) and
out-of-distribution materials (Table VII).

Definitions (our data has several contacts per material, like HCT's several samples per object):
- instance level: a query's only positive is its own pair (text i <-> contact i);
- object level, text -> touch: any contact of the query's material is a positive; touch -> text: the
  candidates are the material-level descriptions (one per material), the right material is the positive.
  ``r1`` / ``r5`` average the two directions;
- chance R@1 (object level) = 1 / number of materials in the pool.
Evaluation texts are the canonical descriptions (no synonyms) with seeded distractor words, never the
training draws.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from vtrack.eval.language_metrics import attribute_f1, bleu1, inter_intra_ratio, recall_at_k, silhouette
from vtrack.language.materials import ATTRIBUTE_WORDS, TactileSet, description

EVAL_SEED = 12345

#: preference-style queries: (query, positive material predicate, negative material predicate)
QUERIES: list[tuple[str, Callable, Callable]] = [
    ("something soft to wipe a lens with", lambda m: m.softness == "soft", lambda m: m.softness == "hard"),
    ("a squishy cushion to sit on", lambda m: m.softness == "soft", lambda m: m.softness == "hard"),
    ("a rigid surface to press against firmly", lambda m: m.softness == "hard", lambda m: m.softness == "soft"),
    ("a stiff board for a workbench", lambda m: m.softness == "hard", lambda m: m.softness == "soft"),
    ("a ridged grip so my fingers do not slip", lambda m: m.family == "ridges", lambda m: m.family != "ridges"),
    ("a bumpy mat to massage my feet", lambda m: m.family == "bumps", lambda m: m.family != "bumps"),
    ("a woven fabric for a warm sweater", lambda m: m.family == "woven", lambda m: m.family != "woven"),
    ("a gritty surface to sand down wood", lambda m: m.family == "grain", lambda m: m.family != "grain"),
    ("a fine net to strain tea", lambda m: m.family == "mesh", lambda m: m.family != "mesh"),
    ("a perfectly smooth sheet to write on", lambda m: m.family == "smooth", lambda m: m.family != "smooth"),
    ("a coarse texture you can clearly feel", lambda m: m.wavelength == "coarse", lambda m: m.wavelength == "fine"),
    ("a delicate, finely textured surface", lambda m: m.wavelength == "fine", lambda m: m.wavelength == "coarse"),
    ("a surface with deep, pronounced relief", lambda m: m.amplitude == "deep", lambda m: m.amplitude == "shallow"),
    ("barely textured, with faint shallow relief", lambda m: m.amplitude == "shallow", lambda m: m.amplitude == "deep"),
]


def class_texts(data: TactileSet, mats: np.ndarray, mode: int = 2, distractor: bool = True) -> list[str]:
    rng = np.random.default_rng(EVAL_SEED + 1)
    return [description(data.materials[int(m)], None, mode=mode, rng=rng, distractor=distractor) for m in mats]


def retrieval(
    model,
    data: TactileSet,
    *,
    p1: float | None = None,
    p2: float | None = None,
    p1w: float = 0.0,
    mode: int = 2,
    distractor: bool = True,
    texts: tuple[list[str], list[str]] | None = None,
    p1p: float = 0.0,
    pre: float = 0.0,
) -> dict:
    """Retrieval metrics on ``data`` (one split) with P1 / P2 / P1w steering at the given strengths
    (``distractor`` False: the evaluation texts without their non-tactile clause; ``texts``: explicit
    (contact texts, material-level texts of ``np.unique(data.material)``) instead of the canonical ones; ``pre``:
    P1 before the projection, ``s_hat`` added to the pooled frozen vector g(T))."""
    V = model.encode_images(data.images, p2)
    mats = np.unique(data.material)
    if texts is None:
        contact = data.texts(mode=mode, seed=EVAL_SEED, distractor=distractor)
        texts = (contact, class_texts(data, mats, mode, distractor))
    T = model.encode_text(texts[0], p1, p1w, p1p, pre)
    C = model.encode_text(texts[1], p1, p1w, p1p, pre)
    s_ti = T @ V.T
    same = data.material[:, None] == data.material[None]
    eye = np.eye(len(V), dtype=bool)
    obj_t2i = recall_at_k(s_ti, same)
    obj_i2t = recall_at_k(V @ C.T, data.material[:, None] == mats[None])
    ins_t2i = recall_at_k(s_ti, eye)
    ins_i2t = recall_at_k(s_ti.T, eye)
    fam = np.array([data.materials[int(m)].family for m in data.material])
    simvec = V @ C.T  # Fig. 6: each contact's similarity to every material-level description
    return {
        "r1": 0.5 * (obj_t2i[1] + obj_i2t[1]),
        "r5": 0.5 * (obj_t2i[5] + obj_i2t[5]),
        "r1_text2touch": obj_t2i[1],
        "r1_touch2text": obj_i2t[1],
        "r5_text2touch": obj_t2i[5],
        "r5_touch2text": obj_i2t[5],
        "instance_r1": 0.5 * (ins_t2i[1] + ins_i2t[1]),
        "instance_r5": 0.5 * (ins_t2i[5] + ins_i2t[5]),
        "instance_r1_text2touch": ins_t2i[1],
        "instance_r1_touch2text": ins_i2t[1],
        "instance_r5_text2touch": ins_t2i[5],
        "instance_r5_touch2text": ins_i2t[5],
        "silhouette": silhouette(simvec, data.material),
        # the paper's Fig. 6 clusters 20 object categories; our coarse analogue is the texture family
        "silhouette_family": silhouette(simvec, fam) if len(np.unique(fam)) >= 2 else float("nan"),
        "inter_intra": inter_intra_ratio(simvec, data.material),
        "chance_r1": 1.0 / len(mats),
        "n_queries": len(V),
        "n_materials": len(mats),
    }


def _query_subset_recall(model, data: TactileSet, rows: np.ndarray, *, mode: int = 2, **kw) -> dict:
    """Object-level R@1 / R@5 (both directions averaged) of the queries ``rows`` against the whole split."""
    V = model.encode_images(data.images, kw.get("p2"))
    T = model.encode_text(data.texts(mode=mode, seed=EVAL_SEED), kw.get("p1"), kw.get("p1w", 0.0))
    mats = np.unique(data.material)
    C = model.encode_text(class_texts(data, mats, mode), kw.get("p1"), kw.get("p1w", 0.0))
    same = data.material[:, None] == data.material[None]
    t2i = recall_at_k((T @ V.T)[rows], same[rows])
    i2t = recall_at_k((V @ C.T)[rows], (data.material[:, None] == mats[None])[rows])
    return {k: 0.5 * (t2i[k] + i2t[k]) for k in (1, 5)}


def distractor_effect(model, data: TactileSet, *, split: str = "test") -> dict:
    """Do the non-tactile words hurt? Object-level R@1 of the same model with the evaluation texts' distractor
    clause, without it, and in Mode 3 (the material name in front: a distractor never seen in training), plus
    the share of the text pooling's attention that falls on colour / shape words."""
    from vtrack.language.materials import COLOURS, SHAPES
    from vtrack.language.text import token_arrays, tokenize

    torch = __import__("torch")
    sub = data.subset(data.split == split)
    out = {
        "r1_with_distractors": retrieval(model, sub, p1=0.0, p2=0.0)["r1"],
        "r1_without_distractors": retrieval(model, sub, p1=0.0, p2=0.0, distractor=False)["r1"],
        "r1_mode3_names": retrieval(model, sub, p1=0.0, p2=0.0, mode=3)["r1"],
    }
    texts = sub.texts(mode=2, seed=EVAL_SEED)
    tok, mask, sign = (torch.as_tensor(a) for a in token_arrays(texts, signs=True))
    dist = set(COLOURS) | set(SHAPES)
    words = [[w for w, _ in tokenize(t)][: tok.shape[1]] for t in texts]
    is_d = torch.zeros_like(mask)
    for i, ws in enumerate(words):
        for j, w in enumerate(ws):
            is_d[i, j] = float(w in dist)
    with torch.no_grad():
        for name, beta in (("attention_on_distractors", 0.0), ("attention_on_distractors_p1w_0.5", 0.5)):
            w = model.net.word_weights(tok, mask, beta, sign)
            out[name] = float((w * is_d).sum(1).mean())
    out["distractor_token_share"] = float((is_d.sum(1) / mask.sum(1)).mean())
    return out


def distractor_variance(
    model, data: TactileSet, *, split: str = "test", draws: int = 8, seed: int = 0, heavy: bool = False
) -> dict:
    """How much of the (unsteered) text embedding do the non-tactile words move? Every procedural contact text
    of ``split`` is written ``draws`` times with different random colour / shape words (everything else equal);
    the variance of the unit embeddings ``t`` across those draws (within a contact) is the distractors' share of
    the total variance of ``t`` over all texts. Also: the share of that distractor variance along the P1
    direction ``s_proj`` (1 / D_SHARED for a random direction) and the same share for the frozen GloVe mean
    ``g(T)`` before any training (the contamination a frozen sentence encoder would carry). YCB contacts are
    left out: their colour / shape words are the object's true ones, i.e. fixed per material. ``heavy``: the
    draws are :func:`heavy_distractor_texts` (the clause present or not, 1-4 appearance words).

    Why the share along ``s_proj`` matters: P1 adds ``a s_proj`` to every text before the normalisation, which
    (to first order) shrinks every text's variation along the steered direction and leaves the rest; so
    P1 can only suppress the part of the distractor variance that lies along ``s_proj``, and it shrinks the
    tactile (between-contact) variance along ``s_proj`` as well.
    """
    from vtrack.language.materials import description
    from vtrack.language.text import sentence_vectors

    sub = data.subset(np.array([data.materials[int(m)].family != "ycb" for m in data.material]) & (data.split == split))
    if len(sub.material) < 2:
        return {"distractor_variance_share": float("nan")}
    rng = np.random.default_rng(seed)
    if heavy:  # presence and number of appearance words vary (heavy_distractor_texts)
        texts = [heavy_distractor_texts(sub, seed=seed + k)[0] for k in range(draws)]
    else:
        texts = [
            [description(sub.materials[int(m)], c, rng=rng) for m, c in zip(sub.material, sub.contacts, strict=True)]
            for _ in range(draws)
        ]
    flat = [t for row in texts for t in row]
    T = model.encode_text(flat, 0.0).reshape(draws, len(sub.material), -1)
    G = sentence_vectors(flat).reshape(draws, len(sub.material), -1)

    def share(E: np.ndarray) -> float:
        within = float(((E - E.mean(0, keepdims=True)) ** 2).sum(-1).mean())
        total = float(((E - E.reshape(-1, E.shape[-1]).mean(0)) ** 2).sum(-1).mean())
        return within / max(total, 1e-12)

    def along(E: np.ndarray, s: np.ndarray) -> tuple[float, float]:
        """Shares of the within-contact (distractor) and the between-contact variance along unit ``s``."""
        mu = E.mean(0, keepdims=True)
        d = (E - mu).reshape(-1, E.shape[-1])
        b = mu[0] - mu[0].mean(0)
        f = lambda z: float(((z @ s) ** 2).sum() / max(float((z**2).sum()), 1e-12))  # noqa: E731
        return f(d), f(b)

    s_proj = model.net.s_proj().detach().numpy()
    s_hat = model.net.s_hat.detach().numpy()
    t_d, t_b = along(T, s_proj)
    g_d, g_b = along(G, s_hat)
    return {
        "distractor_variance_share": share(T),
        "distractor_variance_along_s_proj": t_d,
        "contact_variance_along_s_proj": t_b,
        "random_direction_share": 1.0 / T.shape[-1],
        "distractor_variance_share_glove_mean": share(G),
        "distractor_variance_along_s_hat_glove_mean": g_d,
        "contact_variance_along_s_hat_glove_mean": g_b,
        "random_direction_share_glove": 1.0 / G.shape[-1],
        "n_texts": len(flat),
    }


def error_breakdown(model, data: TactileSet, *, split: str = "test") -> dict:
    """Where object-level retrieval fails: per direction, the R@1, the share of errors that get the texture
    family / wavelength / relief / softness wrong (a wrong material usually differs in several), that confuse
    two YCB objects or a YCB object with a procedural material; and the same for an image-only 1-NN from the
    split's contacts to the training contacts (the tactile encoder's own ceiling, no text involved), plus how
    often a material-level text is nearest to its own material's mean training image embedding (the text
    side's placement)."""
    sub = data.subset(data.split == split)
    tr = data.subset(data.split == "train")
    mats = np.unique(sub.material)
    V = model.encode_images(sub.images, 0.0)
    Vt = model.encode_images(tr.images, 0.0)
    T = model.encode_text(sub.texts(mode=2, seed=EVAL_SEED), 0.0)
    C = model.encode_text(class_texts(sub, mats), 0.0)
    M = data.materials

    def attrs(i: int) -> tuple:
        m = M[int(i)]
        return (m.family, m.wavelength, m.amplitude, m.softness)

    def rows(pred: np.ndarray, true: np.ndarray) -> dict:
        wrong = [(int(p), int(t)) for p, t in zip(pred, true, strict=True) if p != t]
        n = max(len(wrong), 1)
        out = {"r1": float(np.mean(pred == true)), "n_errors": len(wrong)}
        ycb = [(attrs(p)[0] == "ycb", attrs(t)[0] == "ycb") for p, t in wrong]
        out["err_ycb_ycb"] = sum(a and b for a, b in ycb) / n
        out["err_ycb_procedural"] = sum(a != b for a, b in ycb) / n
        proc = [(p, t) for (p, t), (a, b) in zip(wrong, ycb, strict=True) if not (a or b)]
        for j, k in enumerate(("family", "wavelength", "relief", "softness")):
            out[f"err_{k}"] = sum(attrs(p)[j] != attrs(t)[j] for p, t in proc) / n
        is_y = np.array([attrs(t)[0] == "ycb" for t in true])
        out["r1_ycb_queries"] = float(np.mean(pred[is_y] == true[is_y])) if is_y.any() else float("nan")
        return out

    proto = np.stack([Vt[tr.material == k].mean(0) for k in mats])
    proto /= np.linalg.norm(proto, axis=1, keepdims=True).clip(1e-9)
    return {
        "text2touch": rows(sub.material[(T @ V.T).argmax(1)], sub.material),
        "touch2text": rows(mats[(V @ C.T).argmax(1)], sub.material),
        "image_1nn_to_train": rows(tr.material[(V @ Vt.T).argmax(1)], sub.material),
        "class_text_nearest_own_image_mean": float(np.mean((C @ proto.T).argmax(1) == np.arange(len(mats)))),
    }


#: appearance words of the heavy-distractor texts: the colours / shapes of the training distractors plus
#: appearance words never seen in training (some in the steering lexicon N, some not)
APPEARANCE = (
    *("red", "blue", "green", "yellow", "purple", "orange", "white", "black", "grey", "pink"),
    *("square", "round", "rectangular", "triangular", "oval", "circular"),
    *("shiny", "transparent", "bright", "dark", "striped", "colorful", "glossy", "matte", "patterned", "pale"),
)


def heavy_distractor_texts(
    data: TactileSet, *, seed: int = EVAL_SEED, p: float = 0.5, max_words: int = 4
) -> tuple[list[str], list[str]]:
    """(contact texts, material-level texts of ``np.unique(data.material)``) whose non-tactile content varies:
    the tactile description (no distractor clause) followed, with probability ``p``, by "it looks w1, .. and
    wk." with k = 1..``max_words`` appearance words. Training always shows exactly one colour and one shape,
    so presence and amount vary only here: the variation that lies along mean e(N), i.e. what the paper's
    steering vector can address. YCB texts keep their true colour / shape (object identity) and get the extra
    clause too."""
    rng = np.random.default_rng(seed)

    def add(t: str) -> str:
        if rng.random() >= p:
            return t
        k = int(rng.integers(1, max_words + 1))
        w = [str(x) for x in rng.choice(APPEARANCE, k, replace=False)]
        clause = w[0] if k == 1 else ", ".join(w[:-1]) + " and " + w[-1]
        return t[:-1] + f". it looks {clause}."

    ycb = {int(m) for m in np.unique(data.material) if data.materials[int(m)].family == "ycb"}
    base = data.texts(mode=2, distractor=False)
    true_d = data.texts(mode=2, seed=EVAL_SEED)  # YCB: keep the true colour / shape clause
    contact = [add(true_d[i] if int(m) in ycb else base[i]) for i, m in enumerate(data.material)]
    mats = np.unique(data.material)
    cl = class_texts(data, mats, 2, distractor=False)
    cl_true = class_texts(data, mats, 2, distractor=True)
    return contact, [add(cl_true[j] if int(m) in ycb else cl[j]) for j, m in enumerate(mats)]


P1W_ALPHAS = (0.2, 0.5, 1.0, 2.0)
P1P_ALPHAS = (0.25, 0.5, 0.75, 1.0)


def steering_heavy_distractors(
    model, data: TactileSet, *, alphas=(0.0, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5), split: str = "test", val: str = "val"
) -> dict:
    """P1 steering against variable distractor content (:func:`heavy_distractor_texts`), injected at inference
    into ``model``: the steering vector A-N (the model's) and A-only, each strength chosen on ``val`` (best
    object R@1, ties: the weaker), then scored on ``split``; also the text embedding's distractor variance
    under these texts. Returns the per-vector sweeps, the choices and the test R@1s (none = strength 0)."""
    from vtrack.language.text import LEXICON_A, LEXICON_N, steering_vector

    torch = __import__("torch")
    out: dict = {"sweep_val": {}, "chosen_on_val": {}, "test_r1": {}}
    sv = data.subset(data.split == val)
    st = data.subset(data.split == split)
    tv, tt = heavy_distractor_texts(sv), heavy_distractor_texts(st)
    keep = model.net.s_hat.clone()
    try:
        for name, neg in (("A-N", LEXICON_N), ("A", None)):
            model.net.s_hat.copy_(torch.as_tensor(steering_vector(LEXICON_A, neg)))
            rows = [(a, retrieval(model, sv, p1=a, p2=0.0, texts=tv)["r1"]) for a in alphas]
            out["sweep_val"][name] = rows
            a_best = max(rows, key=lambda r: (r[1], -r[0]))[0]
            out["chosen_on_val"][name] = a_best
            out["test_r1"][name] = retrieval(model, st, p1=a_best, p2=0.0, texts=tt)["r1"]
    finally:
        model.net.s_hat.copy_(keep)
    # ours, not the paper's: P1w (per-word pooling steering, A-N vector)
    rows = [(a, retrieval(model, sv, p1=0.0, p2=0.0, p1w=a, texts=tv)["r1"]) for a in (0.0, *P1W_ALPHAS)]
    out["sweep_val"]["P1w A-N"] = rows
    a_best = max(rows, key=lambda r: (r[1], -r[0]))[0]
    out["chosen_on_val"]["P1w A-N"] = a_best
    out["test_r1"]["P1w A-N"] = retrieval(model, st, p1=0.0, p2=0.0, p1w=a_best, texts=tt)["r1"]
    # ours, not the paper's: P1p, the share ``a`` of each text's component along s_proj (A-N) projected out
    rows = [(a, retrieval(model, sv, p1=0.0, p2=0.0, p1p=a, texts=tv)["r1"]) for a in (0.0, *P1P_ALPHAS)]
    out["sweep_val"]["P1p A-N"] = rows
    a_best = max(rows, key=lambda r: (r[1], -r[0]))[0]
    out["chosen_on_val"]["P1p A-N"] = a_best
    out["test_r1"]["P1p A-N"] = retrieval(model, st, p1=0.0, p2=0.0, p1p=a_best, texts=tt)["r1"]
    out["test_r1"]["none"] = retrieval(model, st, p1=0.0, p2=0.0, texts=tt)["r1"]
    out["test_r1"]["canonical_texts_none"] = retrieval(model, st, p1=0.0, p2=0.0)["r1"]
    out |= {f"heavy_{k}": v for k, v in distractor_variance(model, data, split=split, heavy=True).items()}
    return out


def generation(model, data: TactileSet, *, p3: float | None = None, p4: float | None = None) -> dict:
    """BLEU-1 and attribute F1 of the generated descriptions against the tactile-only canonical ones."""
    hyp = model.describe(data.images, p3, p4)
    ref = data.texts(mode=2, distractor=False)
    return {"bleu1": bleu1(hyp, ref), "attr_f1": attribute_f1(hyp, ref, ATTRIBUTE_WORDS), "example": hyp[0]}


def selection(model, data: TactileSet, *, p1: float | None = None, runs: int = 3, seed: int = 0) -> dict:
    """2-way / 3-way choice among materials of ``data`` for the preference queries (paper Table VI): one
    satisfying material against 1 or 2 that do not, each represented by one random contact, ``runs`` times."""
    rng = np.random.default_rng(seed)
    V = model.encode_images(data.images)
    Q = model.encode_text([q for q, _, _ in QUERIES], p1)
    mats = [data.materials[int(m)] for m in np.unique(data.material)]
    out = {}
    for way in (2, 3):
        hits = []
        for qi, (_, pos, neg) in enumerate(QUERIES):
            P = [m.index for m in mats if pos(m)]
            N = [m.index for m in mats if neg(m)]
            if not P or len(N) < way - 1:
                continue
            for _ in range(runs):
                cand = [int(rng.choice(P)), *rng.choice(N, way - 1, replace=False).tolist()]
                idx = [int(rng.choice(np.flatnonzero(data.material == c))) for c in cand]
                hits.append(int(np.argmax(V[idx] @ Q[qi]) == 0))
        out[f"select_{way}way"] = float(np.mean(hits)) if hits else float("nan")
        out[f"select_{way}way_n"] = len(hits)
    return out


def evaluate(model, data: TactileSet, *, split: str = "test", mode: int = 2, steer: bool = True) -> dict:
    """Every metric of ``model`` on ``split`` (+ OOD retrieval on the held-out materials); ``steer`` False
    evaluates the same weights with every injection off."""
    kw = {} if steer else {"p1": 0.0, "p2": 0.0}
    sub = data.subset(data.split == split)
    res = retrieval(model, sub, mode=mode, **kw)
    ycb = np.array([data.materials[int(m)].family == "ycb" for m in sub.material])
    if ycb.any():
        # the YCB patches alone (their own pool of objects) and the procedural materials alone
        ry = retrieval(model, sub.subset(ycb), mode=mode, **kw)
        rp = retrieval(model, sub.subset(~ycb), mode=mode, **kw)
        res |= {f"ycb_{k}": ry[k] for k in ("r1", "r5", "r1_text2touch", "r1_touch2text", "chance_r1", "n_queries")}
        res |= {f"procedural_{k}": rp[k] for k in ("r1", "r5", "chance_r1")}
        # YCB queries against the whole test gallery (every material of the split)
        full = _query_subset_recall(model, sub, ycb, mode=mode, **kw)
        res |= {"ycb_r1_in_full_pool": full[1], "ycb_r5_in_full_pool": full[5]}
    res |= steering_scale(model, sub)
    res |= generation(model, sub, **({} if steer else {"p3": 0.0, "p4": 0.0}))
    res |= selection(model, sub, **({} if steer else {"p1": 0.0}))
    ood = retrieval(model, data.subset(data.split == "ood"), mode=mode, **kw)
    res |= {"ood_r1": ood["r1"], "ood_r5": ood["r5"], "ood_chance_r1": ood["chance_r1"]}
    return res


def steering_scale(model, data: TactileSet) -> dict:
    """Median norms of what P1 / P2 / P4 are added to (``W_text g(T)``, ``W_img f(I)``, ``f(I)``): the steering
    vectors are unit, so a strength ``a`` is a fraction ``a / norm`` of the embedding it steers."""
    from vtrack.language.text import token_arrays

    torch = __import__("torch")
    tok, mask = (torch.as_tensor(a) for a in token_arrays(data.texts(mode=2, seed=EVAL_SEED)))
    with torch.no_grad():
        t = model.net.w_text(model.net.pool(tok, mask))
        f = torch.as_tensor(model.encode_features(data.images))
        v = model.net.w_img(f)
    med = lambda z: float(z.norm(dim=1).median())  # noqa: E731
    return {"norm_text_proj": med(t), "norm_image_proj": med(v), "norm_feat": med(f)}


def sweep(
    model, data: TactileSet, *, split: str = "val", alphas=(0.0, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0)
) -> list[dict]:
    """Fig. 3-style sweep of injection position and strength at inference on ``split`` (object R@1 and BLEU-1);
    the model's own steering is switched off except at the swept position. The paper's grid (0.01-1.0) plus 2 and
    5: P1 / P2 are added to unnormalised embeddings (see :func:`steering_scale`)."""
    sub = data.subset(data.split == split)
    rows = []
    for pos in ("p1", "p2", "p1w", "p3", "p4"):
        for a in alphas:
            kw = {"p1": 0.0, "p2": 0.0, "p1w": 0.0}
            g = {"p3": 0.0, "p4": 0.0}
            if pos in kw:
                kw[pos] = a
            else:
                g[pos] = a
            r = retrieval(model, sub, **kw)
            b = generation(model, sub, **g) if pos in ("p3", "p4") or a == 0 else {"bleu1": float("nan")}
            rows.append(
                {
                    "position": pos.upper(),
                    "alpha": a,
                    "r1": r["r1"],
                    "instance_r1": r["instance_r1"],
                    "silhouette": r["silhouette"],
                    "bleu1": b["bleu1"],
                }
            )
    return rows


def select_on_val(rows: list[dict]) -> dict:
    """From a :func:`sweep` on the validation split: the retrieval position/strength (P1, P2 or P1w) with the
    best object R@1 and the generation one (P3 or P4) with the best BLEU-1 (ties: the weaker strength)."""
    ret = max((r for r in rows if r["position"] in ("P1", "P2", "P1W")), key=lambda r: (r["r1"], -r["alpha"]))
    gen = max((r for r in rows if r["position"] in ("P3", "P4")), key=lambda r: (r["bleu1"], -r["alpha"]))
    return {"retrieval": (ret["position"].lower(), ret["alpha"]), "generation": (gen["position"].lower(), gen["alpha"])}


def evaluate_inference_steering(model, data: TactileSet, chosen: dict, *, split: str = "test") -> dict:
    """Scores of an unsteered-trained ``model`` with steering injected at inference only, at the positions and
    strengths ``chosen`` on the validation split, for the A-N vector and the A-only vector (Table V rows)."""
    from vtrack.language.text import LEXICON_A, LEXICON_N, steering_vector

    torch = __import__("torch")
    sub = data.subset(data.split == split)
    (rp, ra), (gp, ga) = chosen["retrieval"], chosen["generation"]
    saved = model.net.s_hat.clone()
    out = {}
    try:
        for name, neg in (("A-N", LEXICON_N), ("A", None)):
            model.net.s_hat.copy_(torch.as_tensor(steering_vector(LEXICON_A, neg)))
            kw = {"p1": 0.0, "p2": 0.0, "p1w": 0.0}
            kw[rp] = ra
            g = {"p3": 0.0, "p4": 0.0}
            g[gp] = ga
            r = retrieval(model, sub, **kw)
            b = generation(model, sub, **g)
            out[name] = {k: r[k] for k in ("r1", "r5", "instance_r1", "silhouette", "silhouette_family", "inter_intra")}
            out[name] |= {"bleu1": b["bleu1"], "attr_f1": b["attr_f1"]}
    finally:
        model.net.s_hat.copy_(saved)
    return out


def per_position_on_test(model, data: TactileSet, rows: list[dict], *, split: str = "test") -> dict:
    """For each retrieval position (P1, P2, P1w) on its own: the non-zero strength with the best validation R@1 (from
    the :func:`sweep` ``rows``), then test object / instance R@1 and silhouette of the A-N and A-only vectors
    at that strength, beside no steering."""
    from vtrack.language.text import LEXICON_A, LEXICON_N, steering_vector

    torch = __import__("torch")
    sub = data.subset(data.split == split)
    keys = ("r1", "r5", "instance_r1", "silhouette", "inter_intra")
    base = retrieval(model, sub, p1=0.0, p2=0.0)
    out: dict = {"none": {k: base[k] for k in keys}}
    saved = model.net.s_hat.clone()
    try:
        for pos in ("P1", "P2", "P1W"):
            # the best non-zero strength: this table compares steering with no steering
            cand = [r for r in rows if r["position"] == pos and r["alpha"] > 0]
            best = max(cand, key=lambda r: (r["r1"], -r["alpha"]))
            row: dict = {"alpha_chosen_on_val": best["alpha"], "val_r1": best["r1"]}
            for name, neg in (("A-N", LEXICON_N), ("A", None)):
                model.net.s_hat.copy_(torch.as_tensor(steering_vector(LEXICON_A, neg)))
                kw = {"p1": 0.0, "p2": 0.0, "p1w": 0.0, pos.lower(): best["alpha"]}
                r = retrieval(model, sub, **kw)
                row[name] = {k: r[k] for k in keys}
            out[pos] = row
    finally:
        model.net.s_hat.copy_(saved)
    return out


# ------------------------------------------------------------------------------ free-form queries with distractors
#: non-tactile words that no training text contains (training distractors are COLOURS and SHAPES only)
UNSEEN_APPEARANCE = ("shiny", "transparent", "bright", "dark", "striped", "colorful", "glossy", "matte", "patterned")
UNSEEN_NOUNS = ("thing", "object", "item", "one")


def freeform_queries(*, seed: int = EVAL_SEED, variants: int = 8, distractor: bool = True) -> list[tuple[str, int]]:
    """Preference-style free-form queries (:data:`QUERIES`), each written ``variants`` times with two appearance
    words that never occur in training ("a glossy, striped thing: something soft to wipe a lens with" or "...;
    it should look dark and matte"): the case the paper's steering is meant for, a frozen-vocabulary text whose
    non-tactile words the trained projection never learned to drop. Returns (text, query index) pairs
    (``distractor`` False: each query once, as written)."""
    if not distractor:
        return [(q, i) for i, (q, _, _) in enumerate(QUERIES)]
    rng = np.random.default_rng(seed)
    out = []
    for i, (q, _, _) in enumerate(QUERIES):
        for k in range(variants):
            a, b = (str(w) for w in rng.choice(UNSEEN_APPEARANCE, 2, replace=False))
            n = str(rng.choice(UNSEEN_NOUNS))
            out.append((f"a {a}, {b} {n}: {q}" if k % 2 == 0 else f"{q}; it should look {a} and {b}", i))
    return out


def _auc_ap(scores: np.ndarray, pos: np.ndarray, neg: np.ndarray) -> tuple[float, float]:
    """AUC (= the expected 2-way selection accuracy of one random positive against one random negative
    contact, ties half) and average precision of ``scores`` over the ``pos`` / ``neg`` contacts."""
    sp, sn = scores[pos], scores[neg]
    auc = float(((sp[:, None] > sn[None]).sum() + 0.5 * (sp[:, None] == sn[None]).sum()) / (len(sp) * len(sn)))
    s = np.concatenate([sp, sn])
    lab = np.concatenate([np.ones(len(sp)), np.zeros(len(sn))])[np.argsort(-s, kind="stable")]
    hits = np.cumsum(lab)
    ap = float(np.sum(hits / np.arange(1, len(lab) + 1) * lab) / max(1, len(sp)))
    return auc, ap


def freeform_scores(
    model, data: TactileSet, queries: list[tuple[str, int]], *, p1: float = 0.0, pre: float = 0.0, p2: float = 0.0
) -> dict:
    """Mean AUC (expected 2-way selection) and mAP of free-form ``queries`` ranking the contacts of ``data``
    (positives / negatives from each query's material predicates), with P1 (after the projection), P1 before the
    projection (``pre``) or P2 steering."""
    V = model.encode_images(data.images, p2)
    Q = model.encode_text([q for q, _ in queries], p1, pre=pre)
    S = Q @ V.T
    mats = [data.materials[int(m)] for m in data.material]
    aucs, aps = [], []
    for row, (_, qi) in zip(S, queries, strict=True):
        _, pos_f, neg_f = QUERIES[qi]
        pos = np.array([pos_f(m) for m in mats])
        neg = np.array([neg_f(m) for m in mats]) & ~pos
        if pos.any() and neg.any():
            a, p = _auc_ap(row, pos, neg)
            aucs.append(a)
            aps.append(p)
    return {"auc": float(np.mean(aucs)), "map": float(np.mean(aps)), "n_queries": len(aucs)}


FREEFORM_ALPHAS = {
    "p1": (0.0, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5),
    "pre": (0.0, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0),
    "p2": (0.0, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0),
}


def steering_freeform(
    model, data: TactileSet, *, split: str = "test", val: str = "val", n_random: int = 20, seed: int = 0
) -> dict:
    """Steering against free-form queries with unseen non-tactile words (:func:`freeform_queries`), injected at
    inference into ``model``: for the A-N and the A-only vector and each position (P1 on the projected text
    embedding as the paper, P1 before the projection on the frozen pooled GloVe vector, P2 on the tactile
    embedding) the strength with the best validation AUC (ties: the weaker), then the test AUC / mAP beside no
    steering and beside the same queries without their distractor words. Control: ``n_random`` random unit
    directions of the GloVe space in place of ``s_hat``, chosen and scored the same way ("random" rows: their
    mean and sd), so a gain can be told from that of any fixed offset."""
    from vtrack.language.text import LEXICON_A, LEXICON_N, steering_vector

    torch = __import__("torch")
    sv, st = data.subset(data.split == val), data.subset(data.split == split)
    q = freeform_queries()
    out: dict = {
        "n_query_texts": len(q),
        "none": freeform_scores(model, st, q),
        "no_distractor_words": freeform_scores(model, st, freeform_queries(distractor=False)),
        "sweep_val": {},
        "chosen_on_val": {},
        "test": {},
    }
    keep = model.net.s_hat.clone()
    try:
        rng = np.random.default_rng(seed + 999)
        vectors = [("A-N", steering_vector(LEXICON_A, LEXICON_N)), ("A", steering_vector(LEXICON_A, None))]
        for k in range(n_random):
            r = rng.standard_normal(keep.shape[0])
            vectors.append((f"random{k}", (r / np.linalg.norm(r)).astype(np.float32)))
        for name, vec in vectors:
            model.net.s_hat.copy_(torch.as_tensor(vec))
            for pos, alphas in FREEFORM_ALPHAS.items():
                rows = [(a, freeform_scores(model, sv, q, **{pos: a})["auc"]) for a in alphas]
                best = max(rows, key=lambda r: (r[1], -r[0]))[0]
                key = f"{name} {pos.upper()}"
                out["sweep_val"][key] = rows
                out["chosen_on_val"][key] = best
                out["test"][key] = freeform_scores(model, st, q, **{pos: best})
    finally:
        model.net.s_hat.copy_(keep)
    for pos in FREEFORM_ALPHAS:
        r = np.array([out["test"].pop(f"random{k} {pos.upper()}")["auc"] for k in range(n_random)])
        if len(r):
            P = pos.upper()
            out["test"][f"random {P}"] = {"auc": float(r.mean()), "auc_sd": float(r.std()), "n": len(r)}
            # share of random directions doing at least as well as A-N (a permutation-style p-value)
            out["test"][f"A-N {P}"]["share_random_at_least_as_good"] = float(
                np.mean(r >= out["test"][f"A-N {P}"]["auc"])
            )
    return out


def description_oracle(data: TactileSet) -> dict:
    """Is object-level retrieval well posed by the texts alone? Among the materials of ``data``: how many share
    their tactile-only material-level description (no distractor clause) with another, and the touch -> text
    R@1 of an oracle that knows each contact's true attributes and breaks ties uniformly (mean of 1 / the size
    of its description group); the same with the evaluation's distractor clause (for YCB the object's true
    colour / shape, so it can tell objects apart that touch cannot)."""
    mats = np.unique(data.material)
    out = {"n_materials": len(mats)}
    for key, distractor in (("tactile_only", False), ("with_distractors", True)):
        texts = class_texts(data, mats, 2, distractor)
        groups: dict[str, list[str]] = {}
        for t, m in zip(texts, mats, strict=True):
            groups.setdefault(t, []).append(data.materials[int(m)].key)
        size = np.array([len(groups[t]) for t in texts])
        out[key] = {
            "distinct_descriptions": len(groups),
            "materials_sharing_a_description": int((size > 1).sum()),
            "oracle_r1": float(np.mean(1.0 / size)),
            "shared": [g for g in groups.values() if len(g) > 1],
        }
    return out
