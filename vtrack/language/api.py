"""User-facing entry points over a trained model folder (default: the weights shipped in the package):
``query(text, k)`` ranks the gallery of generated tactile samples, ``describe(image)`` writes a description
of one tactile frame, ``train_all`` trains the three steering designs, ``evaluate_all`` scores them.

A model folder holds ``none.pt``, ``A.pt``, ``A-N.pt`` (one per steering design, trained alike) and
``gallery_<design>.npz`` (unit embeddings of the generated test + OOD contacts, with their material ids).
"""

from __future__ import annotations

import time
from dataclasses import asdict
from functools import lru_cache
from pathlib import Path

import numpy as np

from vtrack.errors import InputError

DESIGNS = ("none", "A", "A-N")
#: the design query / describe use: "none" (model version 3 ships only it; version 2's trained A-N tied with it
#: on validation and gave no test gain, docs/language.md)
DEFAULT_DESIGN = "none"
#: training recipe of ``train`` / the shipped weights (keyword arguments of vtrack.language.model.train;
#: chosen on the validation contacts, docs/language.md)
RECIPE: dict = {"cls_weight": 1.0, "same_weight": 0.5, "shift_px": 0, "texture": True, "text_mlp": True}


def shipped_dir() -> Path:
    """The weights shipped inside the package (a few hundred kB)."""
    return Path(__file__).resolve().parent / "weights"


def default_train_dir() -> Path:
    from vtrack.paths import cache_dir

    return cache_dir() / "language" / "models"


def _model_file(models: Path, design: str) -> Path:
    return Path(models) / f"{design}.pt"


@lru_cache(maxsize=8)
def _load(models: str, design: str):
    from vtrack.language.text import require_extra

    require_extra()
    try:
        import torch  # noqa: F401
    except ImportError:
        raise InputError(
            "the language component needs torch", field="dependency", expected="pip install vtrack"
        ) from None
    from vtrack.language.model import TouchSteer

    m = TouchSteer.load(_model_file(Path(models), design))
    g = Path(models) / f"gallery_{design}.npz"
    if not g.exists():
        raise InputError("model folder has no gallery", path=g, expected="written by 'vtrack language train'")
    with np.load(g) as z:
        gallery = {k: z[k] for k in z.files}
    gallery["emb"] = gallery["emb"].astype(np.float32)
    return m, gallery


def load(models: str | Path | None = None, design: str = DEFAULT_DESIGN):
    """(TouchSteer model, gallery dict) of ``design`` in folder ``models`` (default: shipped), cached."""
    if design not in DESIGNS:
        raise InputError("unknown steering design", field="design", expected=" | ".join(DESIGNS), got=design)
    return _load(str(Path(models) if models is not None else shipped_dir()), design)


def query(text: str, k: int = 5, models: str | Path | None = None, design: str = DEFAULT_DESIGN) -> list[dict]:
    """The ``k`` gallery contacts nearest to ``text`` (cosine score in [-1, 1]) with their material."""
    from vtrack.language.materials import materials

    if not isinstance(text, str) or not text.strip():
        raise InputError("empty query", field="query", expected="a description, e.g. 'soft and finely ridged'")
    if k < 1:
        raise InputError("k must be >= 1", field="k", got=k)
    model, gal = load(models, design)
    t = model.encode_text([text])[0]
    s = gal["emb"] @ t
    top = np.argsort(-s)[:k]
    mats = materials()
    out = []
    for r, i in enumerate(top):
        m = mats[int(gal["material"][i])]
        out.append(
            {
                "rank": r + 1,
                "score": round(float(s[i]), 4),
                "sample": int(i),
                "material": m.key,
                "name": m.name,
                "contact": int(gal["contact"][i]),
                "split": str(gal["split"][i]),
            }
        )
    return out


def query_latency_ms(text: str = "soft and finely ridged", repeat: int = 50, models=None) -> float:
    """Median wall time (ms) of one warm :func:`query` (model and GloVe already loaded)."""
    query(text, 5, models)
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        query(text, 5, models)
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts) * 1000)


# ---------------------------------------------------------------------------------------------- image gate
def tactile_input(frame_bgr: np.ndarray, background_bgr: np.ndarray | None = None, source: str = "image"):
    """Network input (1, 3, 60, 80) of a tactile frame, after a plausibility gate.

    The frame must be a colour image with the 4:3 aspect of our frames (any size; resized to 80 x 60), not
    constant, with a visible contact (a smooth colour change against the no-contact ``background_bgr``,
    default the DIGIT frame the model was trained on), not noise (the change must be spatially smooth, as
    the gel makes it) and not a foreign picture (the change stays within what a press can do).
    """
    import cv2

    from vtrack.language.materials import IMAGE_H, IMAGE_W, background, to_input

    f = np.asarray(frame_bgr)
    if f.ndim != 3 or f.shape[2] != 3 or f.dtype != np.uint8:
        raise InputError(
            "not a tactile frame", path=source, expected="8-bit colour image (H, W, 3)", got=f"{f.dtype} {f.shape}"
        )
    h, w = f.shape[:2]
    if h < 30 or w < 40 or abs(w / h - IMAGE_W / IMAGE_H) > 0.12:
        raise InputError(
            "not a tactile frame", path=source, expected="a 4:3 frame of at least 40 x 30 px", got=f"{w} x {h}"
        )
    if float(f.std()) < 1.0:
        raise InputError("not a tactile frame: the image is constant", path=source, got=f"std {float(f.std()):.2f}")
    f = cv2.resize(f, (IMAGE_W, IMAGE_H), interpolation=cv2.INTER_AREA)
    bg = background() if background_bgr is None else np.asarray(background_bgr)
    if bg.shape[:2] != (IMAGE_H, IMAGE_W):
        bg = cv2.resize(bg, (IMAGE_W, IMAGE_H), interpolation=cv2.INTER_AREA)
    d = f.astype(np.float32) - bg.astype(np.float32)
    smooth = cv2.GaussianBlur(d, (0, 0), 1.5)
    signal = float(np.abs(smooth).max())
    if signal < GATE["min_signal"]:
        raise InputError(
            "no contact visible in the tactile frame",
            path=source,
            expected=f"colour change >= {GATE['min_signal']}",
            got=round(signal, 1),
        )
    resid = float(np.sqrt(((d - smooth) ** 2).mean()))
    if resid > GATE["max_residual_rms"]:
        raise InputError(
            "not a tactile frame: the change is noise-like",
            path=source,
            expected=f"pixel-scale residual <= {GATE['max_residual_rms']} grey levels",
            got=round(resid, 1),
        )
    p95 = float(np.percentile(np.abs(smooth), 95))
    if p95 > GATE["max_p95"]:
        raise InputError(
            "not a tactile frame: too far from the gel's no-contact image",
            path=source,
            expected=f"95th percentile change <= {GATE['max_p95']}",
            got=round(p95, 1),
        )
    return to_input(f, bg)[None]


#: gate thresholds (grey levels), set with margin from 150 generated contacts (docs/language.md): their
#: strongest smoothed change is >= 3.1 (a no-contact frame: 1.4), their pixel-scale residual (camera noise)
#: <= 4.7 (uniform noise: 70, Gaussian noise of std 20: 19), their 95th-percentile change <= 12
GATE = {"min_signal": 2.5, "max_residual_rms": 8.0, "max_p95": 40.0}


def describe(image: str | Path | np.ndarray, models=None, background: str | Path | None = None) -> dict:
    """Description of one tactile frame (a file or a uint8 BGR array), plus the nearest material."""
    import cv2

    src = str(image) if not isinstance(image, np.ndarray) else "image"
    if isinstance(image, np.ndarray):
        frame = image
    else:
        p = Path(image)
        if not p.exists():
            raise InputError("image not found", path=p)
        frame = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        if frame is None:
            raise InputError("cannot read the image", path=p, expected="PNG / JPEG")
    bg = None
    if background is not None:
        bg = cv2.imread(str(background), cv2.IMREAD_COLOR)
        if bg is None:
            raise InputError("cannot read the background image", path=background)
    x = tactile_input(frame, bg, src)
    model, gal = load(models, DEFAULT_DESIGN)
    text = model.describe(x)[0]
    v = model.encode_images(x)[0]
    i = int(np.argmax(gal["emb"] @ v))
    from vtrack.language.materials import materials

    m = materials()[int(gal["material"][i])]
    return {"description": text, "nearest_material": m.key, "nearest_name": m.name}


# ---------------------------------------------------------------------------------------------- train / eval
def train_all(
    out: str | Path | None = None,
    *,
    epochs: int = 60,
    seed: int = 0,
    designs=DESIGNS,
    pooling: str = "attention",
    recipe: dict | None = None,
    extra_train: int | None = None,
    log=print,
) -> Path:
    """Train the three steering designs alike on the generated data; write ``<design>.pt`` + galleries.

    ``recipe``: keyword arguments of :func:`vtrack.language.model.train` (default :data:`RECIPE`);
    ``extra_train``: extra training contacts per material (default
    :data:`vtrack.language.materials.EXTRA_TRAIN_CONTACTS`)."""
    from vtrack.language.materials import generate
    from vtrack.language.model import Steering, train
    from vtrack.language.text import require_extra

    require_extra()
    out = Path(out) if out is not None else default_train_dir()
    out.mkdir(parents=True, exist_ok=True)
    data = generate(seed) if extra_train is None else generate(seed, extra_train=extra_train)
    for d in designs:
        log(f"training design {d}")
        kw = RECIPE | (recipe or {})
        m = train(data, steering=Steering(design=d), epochs=epochs, seed=seed, pooling=pooling, log=log, **kw)
        m.save(_model_file(out, d))
        write_gallery(m, data, out / f"gallery_{d}.npz")
    _load.cache_clear()
    return out


def write_gallery(model, data, path: Path) -> Path:
    """Unit embeddings (float16) of the test + OOD contacts with their ids."""
    sub = data.subset(np.isin(data.split, ["test", "ood"]))
    emb = model.encode_images(sub.images)
    tmp = path.with_suffix(".tmp.npz")
    np.savez_compressed(
        tmp,
        emb=emb.astype(np.float16),
        material=sub.material.astype(np.int16),
        contact=sub.contact.astype(np.int16),
        split=sub.split.astype("U5"),
    )
    tmp.replace(path)
    return path


def evaluate_all(
    models: str | Path | None = None,
    *,
    seed: int = 0,
    split: str = "test",
    sweep: bool = False,
    quick: bool = False,
    appearance_study: bool = False,
) -> dict:
    """Scores of every design in ``models`` on ``split``; the top-level keys compare no steering (design
    "none") with A-N steering: design "A-N" (trained and evaluated with its injection on) when the folder has it,
    else the A-N vector injected at inference into "none" at the position / strength chosen on the validation
    split (then ``select_*``, ``ood_r1`` and ``instance_r5`` "_steered" are the unsteered values; ``steered_source``
    says which). ``appearance_study``: also the correlated-appearance steering study of the "none" model
    (:func:`vtrack.language.appearance.steering_correlated`, key ``appearance_study``)."""
    from vtrack.language import evaluate as E
    from vtrack.language.materials import generate

    if quick and (split != "test" or sweep or appearance_study):
        raise InputError("--quick evaluates the test split only, without the sweeps", field="quick")
    data = generate(seed, quick=quick)
    res: dict = {"split": split, "quick": quick, "designs": {}}
    loaded = {}
    for d in DESIGNS:
        if quick and d == "A":
            continue  # the smoke run compares the two designs the top-level keys need
        f = _model_file(Path(models) if models is not None else shipped_dir(), d)
        if not f.exists():
            continue
        loaded[d], _ = load(models, d)
        r = E.evaluate(loaded[d], data, split=split)
        r["steering"] = asdict(loaded[d].steering)
        res["designs"][d] = r
    if "none" not in res["designs"]:
        raise InputError(
            "model folder lacks none.pt", path=models or shipped_dir(), expected="'vtrack language train' output"
        )
    base, m = res["designs"]["none"], loaded["none"]

    def inference_steering() -> dict:
        # steering injected at inference only into the unsteered model, position and strength chosen on the
        # validation contacts (never on the test split), then scored on ``split`` (``data`` is the full set here:
        # not ``quick``)
        if "inference_steering" not in res:
            res["sweep_val"] = E.sweep(m, data, split="val")
            chosen = E.select_on_val(res["sweep_val"])
            res["inference_steering"] = {"chosen_on_val": chosen} | E.evaluate_inference_steering(
                m, data, chosen, split=split
            )
        return res["inference_steering"]

    if "A-N" in res["designs"]:
        st = res["designs"]["A-N"]
        res["steered_source"] = "A-N design (trained with its injection, paper P1 0.02 + P4 0.5)"
    elif quick:
        # the smoke run has no validation split: the A-N vector at the paper's strengths (P1 0.02 + P4 0.5)
        from dataclasses import replace

        from vtrack.language.model import Steering

        st = E.evaluate(replace(m, steering=Steering("A-N", 0.02, 0.0, 0.0, 0.5)), data, split=split)
        res["steered_source"] = "A-N injected at inference into none at the paper's P1 0.02 + P4 0.5 (--quick)"
    else:
        st = dict(base) | inference_steering()["A-N"]
        res["steered_source"] = (
            f"A-N injected at inference into none, chosen on val: {res['inference_steering']['chosen_on_val']}"
        )
    for k in (
        "r1",
        "r5",
        "bleu1",
        "silhouette",
        "instance_r1",
        "inter_intra",
        "attr_f1",
        "select_2way",
        "select_3way",
        "silhouette_family",
        "instance_r5",
    ):
        res[k] = base[k]
        res[k + "_steered"] = st[k]
    res["ood_r1"], res["ood_r1_steered"] = base["ood_r1"], st["ood_r1"]
    res["chance_r1"] = base["chance_r1"]
    res["ood_chance_r1"] = base["ood_chance_r1"]
    res["query_ms"] = query_latency_ms(models=models)
    if not quick:
        res["description_oracle"] = E.description_oracle(data.subset(data.split == split))
    if appearance_study:
        from vtrack.language.appearance import steering_correlated

        res["appearance_study"] = steering_correlated(m, data, split=split)
    if sweep:
        res["distractor_effect"] = E.distractor_effect(m, data, split=split)
        inference_steering()
        res["freeform_steering"] = E.steering_freeform(m, data, split=split)
        res["inference_steering_per_position"] = E.per_position_on_test(m, data, res["sweep_val"], split=split)
        res["error_breakdown"] = E.error_breakdown(m, data, split=split)
        res["distractor_variance"] = E.distractor_variance(m, data, split=split)
        res["heavy_distractors"] = E.steering_heavy_distractors(m, data, split=split)
    return res


def diagnostics(models: str | Path | None = None, *, seed: int = 0, split: str = "test") -> dict:
    """What limits retrieval and what steering could remove, for the unsteered model in ``models``: the error
    breakdown by attribute (:func:`vtrack.language.evaluate.error_breakdown`), the distractors' share of the text
    embedding's variance (canonical and heavy-distractor texts) and P1 / P1w / P1p steering (A-N and A-only)
    against heavy-distractor texts, strengths chosen on the validation split."""
    from vtrack.language import evaluate as E
    from vtrack.language.materials import generate

    m, _ = load(models, "none")
    data = generate(seed)
    return {
        "seed": seed,
        "split": split,
        "error_breakdown": E.error_breakdown(m, data, split=split),
        "distractor_variance": E.distractor_variance(m, data, split=split),
        "heavy_distractors": E.steering_heavy_distractors(m, data, split=split),
    }
