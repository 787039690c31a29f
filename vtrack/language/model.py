"""The TouchSteer-style model on CPU: a small CNN over tactile images, a trainable projection of the frozen
GloVe sentence vector, symmetric InfoNCE with a learnable temperature, and a GRU describer; steering vector
``s_hat`` injected at P1-P4 (paper Sec. III, Fig. 2 / Fig. 4).

Spaces: ``g(T)`` and ``s_hat`` live in the 50-d GloVe space; the CNN gives ``f(I)`` (96-d); both are
projected into the shared, unit-norm retrieval space (``D_SHARED`` = 64). Steering positions:

- P1: ``t~ = normalize(W_text g(T) + a * s_proj)``, ``s_proj = normalize(W_text s_hat)``, added to the
  *unnormalised* projection as the paper's equation (Sec. III-C; model version 1 normalised first);
- P1w (ours, not in the paper): ``s_hat`` scores every word of the text, ``e(w) . s_hat``, and the pooling's
  attention logit of the word gets ``+ a * e(w) . s_hat``: words near the N end (colours, shapes) lose weight
  and tactile ones gain, so the steering acts per text (a constant offset like P1 cannot: see
  docs/language.md, "Why P1 cannot suppress a distractor");
- P2: ``v~ = normalize(W_img f(I) + a * s_proj)`` (the tactile embedding, same space, same place);
- P3: the describer's input word vectors (frozen GloVe, so ``s_hat`` itself) get ``+ a * s_hat``;
- P4: the describer's conditioning input, ``f~(I) = f(I) + a * s_hat`` in the tactile encoder's feature space
  (paper Sec. III-D: the ViT features before the retrieval projection). The paper's ``s_hat`` and ``f(I)``
  share the dimension d; ours are 50-d and 96-d, so ``s_hat`` is zero-padded to 96-d (a fixed unit direction
  of the feature space, as the paper's is: nothing aligns the ViT space with the text encoder's). Our decoder
  is a GRU whose initial state and every step see ``f~(I)`` (the paper's cross-attends to it).

Training (``train``) keeps the chosen injection active during training and inference, as the paper does.
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError

#: on-disk version of a saved model (``.pt`` key ``"version"``); another version is refused (2: the describer
#: conditions on f(I), P1 / P2 are added before the normalisation, as the paper)
MODEL_VERSION = 3
#: versions this code reads (3 adds the optional texture branch and MLP text projection, recorded in "arch";
#: a version-2 file has neither)
READABLE_VERSIONS = (2, 3)
D_FEAT = 96
D_SHARED = 64
D_HIDDEN = 128
#: texture-statistics branch: radial and orientation bands of the power spectrum (+ 4 intensity terms)
N_RADIAL, N_ANGLE = 16, 12
N_TEXTURE = N_RADIAL + N_ANGLE + 4
MAX_LEN = 24
_WORDS = re.compile(r"[a-z]+|[.;,]")


def _torch():
    import torch

    return torch


POOLINGS = ("attention", "mean")


def texture_stats(x, n_radial: int = N_RADIAL, n_angle: int = N_ANGLE):
    """Texture statistics of network inputs ``x`` (B, 3, H, W) (torch): the windowed power spectrum of the
    channel mean binned by radial frequency (log share of the energy per band: the texture's wavelength) and by
    orientation above 0.06 cycles/px (share per band, rolled so the strongest band comes first: rotation-normalised
    anisotropy, which tells ridges from a 2-axis weave / mesh / bumps from isotropic grain), plus the contact's
    mean / max |change|, contact area share and log total energy (press depth, softness). (B, N_TEXTURE).

    Why: the CNN's errors are mostly texture family and wavelength (docs/language.md); these are the spectrum's
    two axes, invariant to the texture's phase and to the 180-degree rotation used in training."""
    torch = _torch()
    g = x.mean(1)
    B, H, W = g.shape
    win = torch.hann_window(H, periodic=False)[:, None] * torch.hann_window(W, periodic=False)[None]
    g = (g - g.mean((1, 2), keepdim=True)) * win
    P = torch.fft.fftshift(torch.fft.fft2(g).abs() ** 2, dim=(1, 2)).reshape(B, -1)
    fy = torch.fft.fftshift(torch.fft.fftfreq(H))[:, None].expand(H, W)
    fx = torch.fft.fftshift(torch.fft.fftfreq(W))[None].expand(H, W)
    r = (fx**2 + fy**2).sqrt().reshape(-1)
    th = (torch.atan2(fy, fx) % np.pi).reshape(-1)
    rb = torch.clamp((r / 0.5 * n_radial).long(), max=n_radial - 1)
    ab = torch.clamp((th / np.pi * n_angle).long(), max=n_angle - 1)
    tot = P.sum(1, keepdim=True) + 1e-9
    radial = torch.zeros(B, n_radial, dtype=P.dtype).index_add_(1, rb, P)
    hi = r > 0.06
    ang = torch.zeros(B, n_angle, dtype=P.dtype).index_add_(1, ab[hi], P[:, hi])
    ang = ang / (ang.sum(1, keepdim=True) + 1e-9)
    k = ang.argmax(1)
    ang = torch.gather(ang, 1, (torch.arange(n_angle)[None] + k[:, None]) % n_angle)
    a = x.abs()
    inten = torch.stack([a.mean((1, 2, 3)), a.amax((1, 2, 3)), (a.mean(1) > 0.1).float().mean((1, 2))], 1)
    return torch.cat([torch.log(radial / tot + 1e-6), ang, inten, torch.log(tot)], 1)


def build(
    vocab: list[str],
    word_vecs: np.ndarray,
    s_hat: np.ndarray,
    pooling: str = "attention",
    texture: bool = False,
    text_mlp: bool = False,
):
    """The torch module (created lazily so importing this file does not import torch).

    ``pooling`` "attention" learns a weight per word vector (it can learn to ignore distractor words);
    "mean" is the plain signed mean of the frozen word vectors (it cannot: only ``W_text`` is trained).
    ``texture`` adds the texture-statistics branch (:func:`texture_stats`, batch-normalised, 32-d) to the CNN's
    pooled features before its head; ``text_mlp`` makes the text projection a 2-layer MLP (50 -> 128 -> 64)
    instead of the linear ``W_text`` (model version 3; both off = version 2's architecture)."""
    if pooling not in POOLINGS:
        raise InputError("unknown text pooling", field="pooling", expected=" | ".join(POOLINGS), got=pooling)
    torch = _torch()
    nn = torch.nn

    class TactileEncoder(nn.Module):
        """4 strided conv blocks + global average and max pooling -> f(I) (D_FEAT)."""

        def __init__(self) -> None:
            super().__init__()
            ch = [3, 24, 48, 64, 96]
            layers: list[nn.Module] = []
            for i in range(4):
                k = 5 if i == 0 else 3
                layers += [nn.Conv2d(ch[i], ch[i + 1], k, 2, k // 2), nn.BatchNorm2d(ch[i + 1]), nn.ReLU()]
            self.conv = nn.Sequential(*layers)
            self.tex = (
                nn.Sequential(nn.BatchNorm1d(N_TEXTURE), nn.Linear(N_TEXTURE, 32), nn.ReLU()) if texture else None
            )
            self.head = nn.Linear(2 * ch[-1] + (32 if texture else 0), D_FEAT)

        def forward(self, x):
            y = self.conv(x)
            z = [y.mean((2, 3)), y.amax((2, 3))]
            if self.tex is not None:
                z.append(self.tex(texture_stats(x)))
            return self.head(torch.cat(z, 1))

    class TouchSteerNet(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.enc = TactileEncoder()
            self.w_img = nn.Linear(D_FEAT, D_SHARED, bias=False)
            # trainable text side: attention pooling over the frozen word vectors (a learned per-word weight, so
            # words that say nothing about touch can be down-weighted) + the projection W_text
            self.att = nn.Linear(word_vecs.shape[1], 1)
            d_w = word_vecs.shape[1]
            self.w_text = (
                nn.Sequential(nn.Linear(d_w, 128), nn.GELU(), nn.Linear(128, D_SHARED, bias=False))
                if text_mlp
                else nn.Linear(d_w, D_SHARED, bias=False)
            )
            self.logit_scale = nn.Parameter(torch.tensor(float(np.log(1 / 0.07))))
            self.register_buffer("s_hat", torch.as_tensor(s_hat, dtype=torch.float32))
            # describer: frozen GloVe input embeddings (so P3 lives in the steering vector's own space)
            self.register_buffer("word_emb", torch.as_tensor(word_vecs, dtype=torch.float32))
            self.cond = nn.Linear(D_FEAT, D_HIDDEN)
            self.gru = nn.GRU(word_vecs.shape[1] + D_FEAT, D_HIDDEN, batch_first=True)
            self.out = nn.Linear(D_HIDDEN, len(vocab))

        # ---- retrieval
        def s_proj(self):
            """``normalize(W_text s_hat)``; with the MLP projection its response to ``s_hat`` from the origin,
            ``normalize(mlp(s_hat) - mlp(0))`` (the same vector for a linear map)."""
            p = self.w_text(self.s_hat[None])[0]
            if text_mlp:
                p = p - self.w_text(torch.zeros_like(self.s_hat)[None])[0]
            return p / p.norm().clamp_min(1e-9)

        def s_feat(self):
            """P4 direction in the feature space of f(I): ``s_hat`` zero-padded to D_FEAT (module docstring)."""
            return torch.nn.functional.pad(self.s_hat, (0, D_FEAT - self.s_hat.shape[0]))

        def image_embed(self, x, alpha_p2: float = 0.0, with_feat: bool = False):
            """v (B, D_SHARED) unit; with ``with_feat`` also f(I) (B, D_FEAT), the describer's input."""
            f = self.enc(x)
            v = self.w_img(f)
            if alpha_p2:  # P2, added before the normalisation like P1
                v = v + alpha_p2 * self.s_proj()[None]
            v = v / v.norm(dim=1, keepdim=True).clamp_min(1e-9)
            return (v, f) if with_feat else v

        def word_weights(self, tok, mask, beta_w: float = 0.0, sign=None):
            """(B, L) pooling weights of the (signed) word vectors ``tok`` (B, L, 50); ``beta_w`` > 0 adds P1w
            steering (``beta_w * e(w) . s_hat`` to each word's logit; ``sign`` (B, L) undoes the negation sign
            so "not hard" scores as the tactile word it is)."""
            a = self.att(tok)[..., 0] if pooling == "attention" else torch.zeros_like(mask)
            if beta_w:
                a = a + beta_w * (tok @ self.s_hat) * (sign if sign is not None else 1.0)
            return torch.softmax(a.masked_fill(mask <= 0, -1e4), 1)

        def pool(self, tok, mask, beta_w: float = 0.0, sign=None):
            """g(T): weighted mean of the (signed) word vectors (B, L, 50) -> (B, 50)."""
            return (self.word_weights(tok, mask, beta_w, sign)[..., None] * tok).sum(1)

        def text_embed(
            self, tok, mask, alpha_p1: float = 0.0, beta_w: float = 0.0, sign=None, proj: float = 0.0, pre: float = 0.0
        ):
            g = self.pool(tok, mask, beta_w, sign)
            if pre:  # P1 before the projection: s_hat added to the frozen encoder's pooled output g(T)
                g = g + pre * self.s_hat[None]
            t = self.w_text(g)
            if proj:  # P1p (ours): remove a share ``proj`` of each text's component along s_proj
                sp = self.s_proj()
                t = t - proj * (t @ sp)[:, None] * sp[None]
            if alpha_p1:  # the paper's P1: added to the projected, not yet normalised text embedding
                t = t + alpha_p1 * self.s_proj()[None]
            return t / t.norm(dim=1, keepdim=True).clamp_min(1e-9)

        # ---- description
        def decode_logits(self, f, tokens, alpha_p3: float = 0.0, alpha_p4: float = 0.0):
            """Next-word logits (B, L, V) given the tactile features f(I) (B, D_FEAT) and input ids (B, L)."""
            c = f + alpha_p4 * self.s_feat()[None] if alpha_p4 else f
            e = self.word_emb[tokens]
            if alpha_p3:
                e = e + alpha_p3 * self.s_hat[None, None]
            inp = torch.cat([e, c[:, None].expand(-1, e.shape[1], -1)], 2)
            h0 = torch.tanh(self.cond(c))[None]
            y, _ = self.gru(inp, h0.contiguous())
            return self.out(y)

        @torch.no_grad()
        def generate(self, f, alpha_p3: float = 0.0, alpha_p4: float = 0.0, max_len: int = MAX_LEN):
            """Greedy decoding from f(I) (B, D_FEAT); returns (B, <= max_len) token ids (end token id 1)."""
            B = f.shape[0]
            c = f + alpha_p4 * self.s_feat()[None] if alpha_p4 else f
            h = torch.tanh(self.cond(c))[None].contiguous()
            tok = torch.zeros(B, dtype=torch.long)  # <bos> = 0
            outs = []
            for _ in range(max_len):
                e = self.word_emb[tok]
                if alpha_p3:
                    e = e + alpha_p3 * self.s_hat[None]
                y, h = self.gru(torch.cat([e, c], 1)[:, None], h)
                tok = self.out(y[:, 0]).argmax(1)
                outs.append(tok)
            return torch.stack(outs, 1)

    net = TouchSteerNet()
    net.pooling = pooling
    net.arch = {"texture": bool(texture), "text_mlp": bool(text_mlp)}
    return net


@dataclass
class Steering:
    """Which steering is active (during training and inference) and how strong."""

    design: str = "A-N"  # none | A | A-N
    p1: float = 0.02
    p2: float = 0.0
    p3: float = 0.0
    p4: float = 0.5

    def off(self) -> Steering:
        return Steering("none", 0.0, 0.0, 0.0, 0.0)


@dataclass
class TouchSteer:
    """A trained model with its vocabulary, steering and the gallery of embedded tactile samples."""

    net: Any
    vocab: list[str]
    steering: Steering
    meta: dict = field(default_factory=dict)

    # ------------------------------------------------------------------ helpers
    def encode_text(
        self, texts: list[str], alpha: float | None = None, beta_w: float = 0.0, proj: float = 0.0, pre: float = 0.0
    ) -> np.ndarray:
        """(N, D_SHARED) unit text embeddings (P1 steering at ``alpha``, default the model's own; P1w at
        ``beta_w``, P1p at ``proj`` (0-1) and P1 before the projection (``s_hat`` added to the frozen pooled
        GloVe vector g(T)) at ``pre``, inference only)."""
        from vtrack.language.text import token_arrays

        torch = _torch()
        a = self.steering.p1 if alpha is None else alpha
        tok, mask, sign = token_arrays(texts, signs=True)
        with torch.no_grad():
            t = self.net.text_embed(
                torch.as_tensor(tok), torch.as_tensor(mask), a, beta_w, torch.as_tensor(sign), proj, pre
            )
            return t.numpy()

    def _features(self, images: np.ndarray, batch: int = 256):
        """f(I) of ``images`` and of their 180-degree rotation ((N, D_FEAT) tensors each). The last array's
        features are kept (the evaluation sweeps steer the same images many times; P2 acts after f(I))."""
        torch = _torch()
        c = self.__dict__.get("_feat_cache")
        if c is not None and c[0] is images:
            return c[1], c[2]
        self.net.eval()
        f, g = [], []
        with torch.no_grad():
            for i in range(0, len(images), batch):
                x = torch.as_tensor(images[i : i + batch])
                f.append(self.net.enc(x))
                g.append(self.net.enc(x.flip(2, 3)))
        z = torch.zeros(0, D_FEAT)
        f, g = (torch.cat(f) if f else z), (torch.cat(g) if g else z)
        self.__dict__["_feat_cache"] = (images, f, g)
        return f, g

    def encode_images(self, images: np.ndarray, alpha: float | None = None) -> np.ndarray:
        """(N, D_SHARED) unit tactile embeddings of network inputs (N, 3, H, W) (P2 at ``alpha``), averaged
        with the 180-degree rotation (a training augmentation that keeps every attribute)."""
        torch = _torch()
        a = self.steering.p2 if alpha is None else alpha
        f, g = self._features(images)
        with torch.no_grad():
            sp = self.net.s_proj()[None] if a else 0.0
            v = [self.net.w_img(h) + a * sp for h in (f, g)]
            v = sum(u / u.norm(dim=1, keepdim=True).clamp_min(1e-9) for u in v)
            return (v / v.norm(dim=1, keepdim=True).clamp_min(1e-9)).numpy()

    def encode_features(self, images: np.ndarray) -> np.ndarray:
        """(N, D_FEAT) tactile features f(I) (the describer's input), averaged with the 180-degree rotation."""
        f, g = self._features(images)
        return (0.5 * (f + g)).numpy()

    def describe(self, images: np.ndarray, p3: float | None = None, p4: float | None = None) -> list[str]:
        """Generated description of each image (network inputs (N, 3, H, W))."""
        torch = _torch()
        v = torch.as_tensor(self.encode_features(images))
        a3 = self.steering.p3 if p3 is None else p3
        a4 = self.steering.p4 if p4 is None else p4
        ids = self.net.generate(v, a3, a4, int(self.meta.get("max_len", MAX_LEN))).numpy()
        return [detokenize(row, self.vocab) for row in ids]

    # ------------------------------------------------------------------ persistence
    def save(self, path: str | Path) -> Path:
        from vtrack.io.jsonio import atomic_torch_save

        state = {
            k: v.half() if v.is_floating_point() and k != "word_emb" else v for k, v in self.net.state_dict().items()
        }
        state.pop("word_emb")  # rebuilt from the GloVe wheel on load (the wheel is a dependency, not shipped)
        blob = {"version": MODEL_VERSION, "state": state, "vocab": self.vocab, "pooling": self.net.pooling}
        blob["arch"] = dict(getattr(self.net, "arch", {}))
        return atomic_torch_save(path, blob | {"steering": self.steering.__dict__, "meta": self.meta})

    @classmethod
    def load(cls, path: str | Path) -> TouchSteer:
        from vtrack.language.text import word_vectors

        torch = _torch()
        path = Path(path)
        if not path.exists():
            raise InputError("no language model here", path=path, expected="a file written by 'vtrack language train'")
        try:
            blob = torch.load(path, map_location="cpu", weights_only=True)
        except Exception as e:  # a truncated / foreign file
            raise InputError("cannot read the language model", path=path, got=type(e).__name__) from None
        keys = ("state", "vocab", "steering")
        if not isinstance(blob, dict) or any(k not in blob for k in keys) or "s_hat" not in blob["state"]:
            raise InputError("not a vtrack language model", path=path, expected="keys state, vocab, steering")
        if int(blob.get("version", 1)) not in READABLE_VERSIONS:
            raise InputError(
                "language model from another vtrack version (retrain with 'vtrack language train')",
                path=path,
                expected=" or ".join(map(str, READABLE_VERSIONS)),
                got=blob.get("version", 1),
            )
        vocab = list(blob["vocab"])
        s_hat = blob["state"]["s_hat"].float().numpy()
        arch = {k: bool(v) for k, v in dict(blob.get("arch", {})).items() if k in ("texture", "text_mlp")}
        net = build(vocab, vocab_vectors(vocab, word_vectors), s_hat, str(blob.get("pooling", "attention")), **arch)
        state = {k: v.float() if v.is_floating_point() else v for k, v in blob["state"].items()}
        state["word_emb"] = net.word_emb
        net.load_state_dict(state)
        net.eval()
        return cls(net, vocab, Steering(**blob["steering"]), dict(blob.get("meta", {})))


# ---------------------------------------------------------------------------------------- vocabulary
SPECIAL = ["<bos>", "<eos>", ",", ";", "."]


def words_of(text: str) -> list[str]:
    """Decoder tokens of a description: words and , ; . punctuation."""
    return _WORDS.findall(text.lower())


def make_vocab(texts: list[str]) -> list[str]:
    seen = dict.fromkeys(SPECIAL)
    for t in texts:
        for w in words_of(t):
            seen.setdefault(w)
    return list(seen)


def vocab_vectors(vocab: list[str], word_vectors) -> np.ndarray:
    """Frozen input vectors of the decoder's vocabulary: GloVe for words, fixed small random for specials."""
    rng = np.random.default_rng(7)
    out = np.zeros((len(vocab), 50), np.float32)
    words = [i for i, w in enumerate(vocab) if w not in SPECIAL]
    out[words] = word_vectors([vocab[i] for i in words])
    for i, w in enumerate(vocab):
        if w in SPECIAL:
            out[i] = rng.normal(0, 0.5, 50)
    return out


def encode_tokens(texts: list[str], vocab: list[str], max_len: int = MAX_LEN) -> np.ndarray:
    """(N, max_len + 1) ids: <bos> w1 .. wn <eos> padded with <eos>."""
    idx = {w: i for i, w in enumerate(vocab)}
    out = np.ones((len(texts), max_len + 1), np.int64)
    out[:, 0] = 0
    for r, t in enumerate(texts):
        ids = [idx[w] for w in words_of(t)][:max_len]
        out[r, 1 : 1 + len(ids)] = ids
    return out


def detokenize(ids, vocab: list[str]) -> str:
    words = []
    for i in ids:
        if int(i) == 1:
            break
        if int(i) > 0:
            words.append(vocab[int(i)])
    s = " ".join(words)
    return re.sub(r" ([,;.])", r"\1", s)


# ---------------------------------------------------------------------------------------- training
def train(
    data,
    *,
    steering: Steering | None = None,
    epochs: int = 60,
    batch: int = 64,
    lr: float = 2e-3,
    lm_weight: float = 0.5,
    mode: int = 2,
    seed: int = 0,
    pooling: str = "attention",
    cls_weight: float = 0.0,
    same_weight: float = 0.5,
    shift_px: int = 0,
    class_text_weight: float = 0.0,
    texture: bool = False,
    text_mlp: bool = False,
    appearance: str = "random",
    lm_appearance: bool = False,
    log=None,
) -> TouchSteer:
    """Train on the ``train`` split of a :class:`~vtrack.language.materials.TactileSet`.

    The retrieval texts are the Mode ``mode`` descriptions with distractors, re-drawn with augmentation
    (synonyms p = 0.3, shuffled attributes, new distractor words) from 8 pre-drawn variants per sample; the
    describer learns the tactile-only canonical description. Images are randomly rotated by 180 degrees
    (which keeps every attribute, orientation included).

    Args:
        cls_weight: weight of an auxiliary material-classification loss on f(I) (a linear head over the
            training materials, used only in training and not saved): a global signal that the in-batch
            InfoNCE (a batch of 64 holds ~1 other contact of a material) gives only weakly.
        same_weight: share of the InfoNCE target mass on the batch's other contacts of the same material (the
            rest on the own pair).
        shift_px: random circular shift of the image by up to this many pixels (0: none); the position
            word of a contact is coarse (centred / edge), so a few pixels keep it.
        class_text_weight: weight of a class-text contrastive loss: every image of the batch against the
            material-level descriptions of *all* training materials (re-drawn with augmentation and new
            distractor words each epoch), cross-entropy on its material, at the InfoNCE temperature. The
            in-batch InfoNCE sees ~1 same-material contact and a random handful of the 57 other materials per
            step; this term shows every material's text as a negative at every step (the hard negatives that
            object-level touch -> text ranking meets), and places each material's text where its images are.
        appearance: distractor clause of the training texts (:meth:`TactileSet.texts`): "random" words (the
            canonical recipe: independent of the material) or "instance", each material's fixed colour / shape
            (correlated with the material, as in real data: the correlated-appearance study, docs/language.md).
        lm_appearance: the describer's targets carry the material's instance appearance clause too ("...; it
            looks yellow and round"), as an annotator who also writes what he sees; default tactile-only.
    """
    from vtrack.language.text import LEXICON_A, LEXICON_N, steering_vector, token_arrays, word_vectors

    torch = _torch()
    steering = steering or Steering()
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    tr = data.subset(data.split == "train")
    n = len(tr.images)
    if n < 8:
        raise InputError("too few training contacts", field="data", expected=">= 8", got=n)
    variants = [
        token_arrays(tr.texts(mode=mode, seed=seed * 100 + k + 1, augment=True, appearance=appearance))
        for k in range(8)
    ]
    # describer targets: the canonical tactile-only description (all splits share the vocabulary)
    canon = data.texts(mode=2, distractor=False)
    if lm_appearance:
        from vtrack.language.materials import COLOURS, SHAPES, instance_appearance

        extra = [f"it looks {c} and {s}." for c in COLOURS for s in SHAPES]
        extra += [f"{c} {s}" for c, s in instance_appearance(data.materials).values()]
        vocab = make_vocab(canon + extra)
        # the appearance clause adds 6 tokens: room for them (the canonical recipe keeps MAX_LEN)
        tgt = torch.as_tensor(encode_tokens(tr.texts(mode=2, appearance="instance"), vocab, MAX_LEN + 8))
    else:
        vocab = make_vocab(canon)
        tgt = torch.as_tensor(encode_tokens(tr.texts(mode=2, distractor=False), vocab))
    if steering.design == "none":
        s_hat = steering_vector(LEXICON_A, LEXICON_N)  # stored for inference sweeps; not injected
        steering = steering.off()
    else:
        s_hat = steering_vector(LEXICON_A, LEXICON_N if steering.design == "A-N" else None)
    net = build(vocab, vocab_vectors(vocab, word_vectors), s_hat, pooling, texture, text_mlp)
    n_mat = int(tr.material.max()) + 1
    cls_head = torch.nn.Linear(D_FEAT, n_mat) if cls_weight > 0 else None
    params = [p for p in net.parameters() if p.requires_grad]
    params += list(cls_head.parameters()) if cls_head is not None else []
    opt = torch.optim.AdamW(params, lr=lr, weight_decay=1e-4)
    steps = epochs * int(np.ceil(n / batch))
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lr, total_steps=steps, pct_start=0.1)
    x_all = torch.as_tensor(tr.images)
    mat_all = torch.as_tensor(tr.material)
    if class_text_weight > 0:
        # material-level texts of every training material (8 augmented draws, as the contact texts)
        from vtrack.language.materials import description

        tmats = np.unique(tr.material)
        col = torch.full((n_mat,), -1, dtype=torch.long)
        col[torch.as_tensor(tmats)] = torch.arange(len(tmats))
        crng = np.random.default_rng(seed * 100 + 77)
        class_vars = [
            token_arrays([description(tr.materials[int(k)], None, mode=mode, rng=crng, augment=True) for k in tmats])
            for _ in range(8)
        ]
    t0 = time.perf_counter()
    for ep in range(epochs):
        net.train()
        perm = rng.permutation(n)
        tok_all, mask_all = (torch.as_tensor(a) for a in variants[ep % len(variants)])
        tot = 0.0
        for i in range(0, n, batch):
            b = perm[i : i + batch]
            if len(b) < 4:
                continue
            x = x_all[b]
            flip = torch.as_tensor(rng.random(len(b)) < 0.5)
            x = torch.where(flip[:, None, None, None], x.flip(2, 3), x)
            if shift_px:
                dy, dx = (int(d) for d in rng.integers(-shift_px, shift_px + 1, 2))
                x = torch.roll(x, (dy, dx), (2, 3))
            x = x + 0.03 * torch.randn_like(x)  # camera-noise augmentation
            v, f = net.image_embed(x, steering.p2, with_feat=True)
            t = net.text_embed(tok_all[b], mask_all[b], steering.p1)
            logits = net.logit_scale.exp().clamp(max=100) * v @ t.T
            # InfoNCE targets: half on the own pair, half spread over the batch's other contacts of the same
            # material (they are not negatives: the object-level task counts them as matches)
            same = mat_all[b][:, None] == mat_all[b][None]
            target = (1 - same_weight) * torch.eye(len(b)) + same_weight * same.float() / same.sum(1, keepdim=True)
            loss = 0.5 * (
                torch.nn.functional.cross_entropy(logits, target) + torch.nn.functional.cross_entropy(logits.T, target)
            )
            if cls_head is not None:
                loss = loss + cls_weight * torch.nn.functional.cross_entropy(cls_head(f), mat_all[b])
            if class_text_weight > 0:
                ct, cm = (torch.as_tensor(a) for a in class_vars[(ep * 31 + i // batch) % len(class_vars)])
                c_emb = net.text_embed(ct, cm, steering.p1)
                c_logits = net.logit_scale.exp().clamp(max=100) * v @ c_emb.T
                loss = loss + class_text_weight * torch.nn.functional.cross_entropy(c_logits, col[mat_all[b]])
            tok = tgt[b]
            lm = net.decode_logits(f, tok[:, :-1], steering.p3, steering.p4)
            loss = loss + lm_weight * torch.nn.functional.cross_entropy(
                lm.reshape(-1, lm.shape[-1]), tok[:, 1:].reshape(-1)
            )
            opt.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(params, 1.0)
            opt.step()
            sched.step()
            tot += float(loss.detach()) * len(b)
        if log is not None and (ep % 10 == 0 or ep == epochs - 1):
            log(
                f"epoch {ep + 1}/{epochs} loss {tot / n:.3f} tau {1 / float(net.logit_scale.detach().exp()):.3f} "
                f"({time.perf_counter() - t0:.0f} s)"
            )
    net.eval()
    meta = {"epochs": epochs, "mode": mode, "seed": seed, "pooling": pooling, "n_train": n}
    meta |= {"cls_weight": cls_weight, "same_weight": same_weight, "shift_px": shift_px}
    meta |= {"class_text_weight": class_text_weight, "texture": texture, "text_mlp": text_mlp}
    meta |= {"appearance": appearance, "lm_appearance": lm_appearance}
    if lm_appearance:
        meta["max_len"] = MAX_LEN + 8
    meta["train_s"] = round(time.perf_counter() - t0, 1)
    return TouchSteer(net, vocab, steering, meta)
