"""Metrics of tactile-language models (numpy only): Recall@K, corpus BLEU-1, attribute F1, silhouette and the
inter/intra-class distance ratio (as the TouchSteer paper reports them)."""

from __future__ import annotations

import re
from collections import Counter

import numpy as np

from vtrack.errors import InputError


def recall_at_k(sim: np.ndarray, positives: np.ndarray, ks: tuple[int, ...] = (1, 5)) -> dict[int, float]:
    """Fraction of queries (rows of ``sim``, (Q, C) similarities) whose top-k candidates hold a positive.

    Args:
        sim: (Q, C) similarity, higher is closer.
        positives: (Q, C) bool, which candidates are correct for each query (at least one per row).
    """
    sim = np.asarray(sim, np.float64)
    pos = np.asarray(positives, bool)
    if sim.shape != pos.shape or sim.ndim != 2 or sim.shape[0] == 0:
        raise InputError("similarity and positives must be (Q, C) alike", field="sim", got=(sim.shape, pos.shape))
    if not np.isfinite(sim).all():
        raise InputError("non-finite similarity", field="sim")
    if not pos.any(1).all():
        raise InputError("every query needs a positive candidate", field="positives")
    order = np.argsort(-sim, axis=1, kind="stable")
    hit = np.take_along_axis(pos, order, axis=1)
    first = hit.argmax(1)  # rank of the first positive
    return {k: float((first < k).mean()) for k in ks}


_W = re.compile(r"[a-z]+")


def words(text: str) -> list[str]:
    return _W.findall(text.lower())


def bleu1(hypotheses: list[str], references: list[str]) -> float:
    """Corpus BLEU-1 (clipped unigram precision x brevity penalty), in [0, 1]; punctuation ignored."""
    if len(hypotheses) != len(references) or not hypotheses:
        raise InputError("need as many hypotheses as references (>= 1)", got=(len(hypotheses), len(references)))
    match = total = ref_len = 0
    for h, r in zip(hypotheses, references, strict=True):
        hw, rw = words(h), words(r)
        rc = Counter(rw)
        match += sum(min(c, rc[w]) for w, c in Counter(hw).items())
        total += len(hw)
        ref_len += len(rw)
    if total == 0:
        return 0.0
    bp = 1.0 if total > ref_len else float(np.exp(1.0 - ref_len / total))
    return float(bp * match / total)


def attribute_f1(hypotheses: list[str], references: list[str], vocabulary: frozenset[str] | set[str]) -> float:
    """Micro F1 of the attribute words (those in ``vocabulary``) present in each hypothesis vs its reference;
    words after "not" count as absent attributes (a separate label ``not_<word>``)."""
    tp = fp = fn = 0

    def labels(t: str) -> set[str]:
        out, neg = set(), False
        for w in words(t):
            if w == "not":
                neg = True
                continue
            if w in vocabulary:
                out.add(("not_" if neg else "") + w)
            neg = False
        return out

    for h, r in zip(hypotheses, references, strict=True):
        hs, rs = labels(h), labels(r)
        tp += len(hs & rs)
        fp += len(hs - rs)
        fn += len(rs - hs)
    return float(2 * tp / max(1, 2 * tp + fp + fn))


def silhouette(x: np.ndarray, labels: np.ndarray) -> float:
    """Mean silhouette coefficient (Euclidean), as ``sklearn.metrics.silhouette_score``; needs >= 2 classes."""
    x = np.asarray(x, np.float64)
    lab = np.asarray(labels)
    classes = np.unique(lab)
    if len(classes) < 2 or len(classes) >= len(x):
        raise InputError("silhouette needs 2 <= classes < samples", field="labels", got=len(classes))
    d = np.sqrt(np.clip(((x[:, None] - x[None]) ** 2).sum(-1), 0.0, None))
    s = np.zeros(len(x))
    for i in range(len(x)):
        same = lab == lab[i]
        n_same = same.sum() - 1
        if n_same == 0:
            continue  # sklearn: 0 for singletons
        a = d[i, same].sum() / n_same
        b = min(d[i, lab == c].mean() for c in classes if c != lab[i])
        s[i] = (b - a) / max(a, b, 1e-12)
    return float(s.mean())


def inter_intra_ratio(x: np.ndarray, labels: np.ndarray) -> float:
    """Mean distance between class centroids / mean distance of samples to their own centroid."""
    x = np.asarray(x, np.float64)
    lab = np.asarray(labels)
    classes = np.unique(lab)
    cent = np.stack([x[lab == c].mean(0) for c in classes])
    intra = np.mean([np.linalg.norm(x[lab == c] - cent[i], axis=1).mean() for i, c in enumerate(classes)])
    dc = np.linalg.norm(cent[:, None] - cent[None], axis=-1)
    inter = dc[np.triu_indices(len(classes), 1)].mean()
    return float(inter / max(intra, 1e-12))
