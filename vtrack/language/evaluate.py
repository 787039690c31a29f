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


def class_texts(data: TactileSet, mats: np.ndarray, mode: int = 2) -> list[str]:
    rng = np.random.default_rng(EVAL_SEED + 1)
    return [description(data.materials[int(m)], None, mode=mode, rng=rng) for m in mats]


def retrieval(model, data: TactileSet, *, p1: float | None = None, p2: float | None = None, mode: int = 2) -> dict:
    """Retrieval metrics on ``data`` (one split) with P1 / P2 steering at the given strengths."""
    V = model.encode_images(data.images, p2)
    T = model.encode_text(data.texts(mode=mode, seed=EVAL_SEED), p1)
    mats = np.unique(data.material)
    C = model.encode_text(class_texts(data, mats, mode), p1)
    s_ti = T @ V.T
    same = data.material[:, None] == data.material[None]
    eye = np.eye(len(V), dtype=bool)
    obj_t2i = recall_at_k(s_ti, same)
    obj_i2t = recall_at_k(V @ C.T, data.material[:, None] == mats[None])
    ins_t2i = recall_at_k(s_ti, eye)
    ins_i2t = recall_at_k(s_ti.T, eye)
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
        "silhouette": silhouette(simvec, data.material),
        # the paper's Fig. 6 clusters 20 object categories; our coarse analogue is the texture family
        "silhouette_family": silhouette(simvec, np.array([data.materials[int(m)].family for m in data.material])),
        "inter_intra": inter_intra_ratio(simvec, data.material),
        "chance_r1": 1.0 / len(mats),
        "n_queries": len(V),
        "n_materials": len(mats),
    }


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
    res |= generation(model, sub, **({} if steer else {"p3": 0.0, "p4": 0.0}))
    res |= selection(model, sub, **({} if steer else {"p1": 0.0}))
    ood = retrieval(model, data.subset(data.split == "ood"), mode=mode, **kw)
    res |= {"ood_r1": ood["r1"], "ood_r5": ood["r5"], "ood_chance_r1": ood["chance_r1"]}
    return res


def sweep(
    model, data: TactileSet, *, split: str = "val", alphas=(0.0, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0)
) -> list[dict]:
    """Fig. 3-style sweep of injection position and strength at inference on ``split`` (object R@1 and BLEU-1);
    the model's own steering is switched off except at the swept position."""
    sub = data.subset(data.split == split)
    rows = []
    for pos in ("p1", "p2", "p3", "p4"):
        for a in alphas:
            kw = {"p1": 0.0, "p2": 0.0}
            g = {"p3": 0.0, "p4": 0.0}
            if pos in kw:
                kw[pos] = a
            else:
                g[pos] = a
            r = retrieval(model, sub, **kw)
            b = generation(model, sub, **g)
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
    """From a :func:`sweep` on the validation split: the retrieval position/strength (P1 or P2) with the best
    object R@1 and the generation one (P3 or P4) with the best BLEU-1 (ties: the weaker strength)."""
    ret = max((r for r in rows if r["position"] in ("P1", "P2")), key=lambda r: (r["r1"], -r["alpha"]))
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
            kw = {"p1": 0.0, "p2": 0.0}
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
