"""Procedural tactile materials, their simulated contacts and structured descriptions (the data we can make here).

A material is a surface texture family (ridges, bumps, woven, grain, mesh, smooth) with a wavelength
(fine 1.0 / medium 1.7 / coarse 2.8 mm), a relief amplitude (shallow 0.07 / deep 0.18 mm) and a softness
(soft / hard). A contact presses a gently curved patch of the material into the gel: the object surface is a
cap of radius ``R`` (50-150 mm) plus the texture, pushed ``depth`` mm in; the gel's indentation is what rises above the
plane ``max - depth``. Softness is the indentation depth: a soft material yields, so it indents the gel less
(about 0.45x), flattens (2x radius) and its relief is halved. Every contact draws a press force (light / firm),
a texture orientation, a position on the gel and one of four sensor units (optical jitter); the height map is
rendered by the independent optical model :mod:`vtrack.sim.tactile_optics` onto the DIGIT no-contact frame.

Descriptions follow the paper's Mode 2 (anchor attributes of the material + additional attributes of the
contact, present and absent) with a non-tactile distractor clause (colour, shape; and in Mode 3 the material
name in front), e.g. ``"feels soft, finely ridged and shallow; not hard, not smooth. pressed firmly, vertical,
centred. it looks red and square."``. Descriptions come from the true attributes: the model never reads
the height map.

YCB surface patches (:mod:`vtrack.language.ycb`, when the shared meshes are present) join the library as
six more "materials", one per object: the contact presses a random spot of the object's mesh, and its
description says hard, smooth, the curvature of the object and of the contact, with the object's true colour,
shape and name as distractors.

Splits: 10 materials are held out entirely (OOD: each family's (medium, deep, soft) and (coarse, shallow,
hard) combination, so every attribute value is still seen in other families); of the others, contacts 0-15
train, 16-17 validate (choose the steering strength) and 18-23 test.
"""

from __future__ import annotations

import hashlib
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from vtrack.errors import InputError

FAMILIES = ("ridges", "bumps", "woven", "grain", "mesh", "smooth")
WAVELENGTH_MM = {"fine": 1.0, "medium": 1.7, "coarse": 2.8}
AMPLITUDE_MM = {"shallow": 0.07, "deep": 0.18}
SOFTNESS = ("soft", "hard")
#: image size (W, H) px and pitch (mm/px) of the generated frames: a 20 x 15 mm gel patch
IMAGE_W, IMAGE_H, MM_PER_PX = 80, 60, 0.25
CONTACTS_PER_MATERIAL = 24
TRAIN_CONTACTS, VAL_CONTACTS = range(0, 16), range(16, 18)
TEST_CONTACTS = range(18, 24)
#: extra training contacts per (non-OOD) material, drawn and rendered from a separate random stream after the
#: 24 above, so the validation / test / OOD frames are the same as without them (data version 2 + extras)
EXTRA_TRAIN_CONTACTS = 16
SENSOR_UNITS = 4
DATA_VERSION = 2

FAMILY_WORD = {
    "ridges": "ridged",
    "bumps": "bumpy",
    "woven": "woven",
    "grain": "grainy",
    "mesh": "meshed",
    "smooth": "smooth",
}
FAMILY_SYNONYMS = {
    "ridged": ["corrugated", "grooved"],
    "bumpy": ["knobbly", "dotted"],
    "woven": ["knitted", "latticed"],
    "grainy": ["gritty", "sandy"],
    "meshed": ["netted", "gridded"],
    "smooth": ["flat", "featureless"],
}
WAVE_ADVERB = {"fine": "finely", "medium": "moderately", "coarse": "coarsely"}
AMP_WORD = {"shallow": "shallow", "deep": "deep"}
AMP_SYNONYMS = {"shallow": ["faint", "subtle"], "deep": ["pronounced", "strong"]}
SOFT_SYNONYMS = {"soft": ["squishy", "yielding"], "hard": ["rigid", "stiff"]}
NAMES = {
    ("ridges", "soft"): "corduroy",
    ("ridges", "hard"): "grating",
    ("bumps", "soft"): "foam",
    ("bumps", "hard"): "lego",
    ("woven", "soft"): "wool",
    ("woven", "hard"): "wicker",
    ("grain", "soft"): "suede",
    ("grain", "hard"): "sandpaper",
    ("mesh", "soft"): "tulle",
    ("mesh", "hard"): "sieve",
    ("smooth", "soft"): "silicone",
    ("smooth", "hard"): "glass",
}
COLOURS = ("red", "blue", "green", "yellow", "purple", "orange", "white", "black", "grey", "pink")
SHAPES = ("square", "round", "rectangular", "triangular", "oval", "circular")
#: attribute words a description can carry (for attribute F1 of generated descriptions)
ATTRIBUTE_WORDS = frozenset(
    list(FAMILY_WORD.values())
    + list(WAVE_ADVERB.values())
    + list(AMP_WORD.values())
    + list(SOFTNESS)
    + ["lightly", "firmly", "horizontal", "vertical", "diagonal", "aligned", "centred", "edge"]
    + ["flat", "curved", "sharply"]
)
#: OOD materials: (family, wavelength, amplitude, softness)
OOD_COMBOS = {("medium", "deep", "soft"), ("coarse", "shallow", "hard")}


@dataclass(frozen=True)
class Material:
    """One procedural material (its true attributes)."""

    index: int
    family: str
    wavelength: str  # fine | medium | coarse ("-" for smooth)
    amplitude: str  # shallow | deep ("-" for smooth)
    softness: str  # soft | hard
    ood: bool
    obj: str = ""  # YCB file stem (family "ycb")

    @property
    def name(self) -> str:
        if self.family == "ycb":
            from vtrack.language.ycb import YCB_OBJECTS

            return YCB_OBJECTS[self.obj][0]
        return NAMES[(self.family, self.softness)]

    @property
    def key(self) -> str:
        if self.family == "ycb":
            return f"ycb-{self.obj}"
        return f"{self.family}-{self.wavelength}-{self.amplitude}-{self.softness}"


@dataclass(frozen=True)
class Contact:
    """Per-contact draws (the additional attributes)."""

    force: str  # light | firm
    depth_mm: float
    angle_deg: float
    orientation: str  # horizontal | vertical | diagonal | aligned
    centre_px: tuple[float, float]
    position: str  # centred | edge
    radius_mm: float
    unit: int
    curvature: str = "-"  # YCB: flat | curved | sharply curved at the contact
    pose: tuple = ()  # YCB: T_object_sensor (4 x 4, metres) row-major


def materials(ycb: bool = True) -> list[Material]:
    """The material library: 5 textured families x 3 wavelengths x 2 amplitudes x 2 softnesses + 2 smooth
    (indices 0-61), then the YCB objects (62-67; ``ycb`` False leaves them out)."""
    out: list[Material] = []
    for fam in FAMILIES:
        if fam == "smooth":
            for s in SOFTNESS:
                out.append(Material(len(out), fam, "-", "-", s, False))
            continue
        for w in WAVELENGTH_MM:
            for a in AMPLITUDE_MM:
                for s in SOFTNESS:
                    out.append(Material(len(out), fam, w, a, s, (w, a, s) in OOD_COMBOS))
    if ycb:
        from vtrack.language.ycb import YCB_OBJECTS

        for stem in YCB_OBJECTS:
            out.append(Material(len(out), "ycb", "-", "-", "hard", False, stem))
    return out


# ----------------------------------------------------------------------------------------------- height maps
def _texture(m: Material, u: np.ndarray, v: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Relief in [0, 1] of the material at texture coordinates (u, v) in mm (already rotated)."""
    if m.family == "smooth":
        return np.zeros_like(u)
    lam = WAVELENGTH_MM[m.wavelength]
    k = 2 * np.pi / lam
    if m.family == "ridges":
        return (0.5 + 0.5 * np.cos(k * u)) ** 2
    if m.family == "bumps":
        return np.clip(np.cos(k * u) * np.cos(k * v), 0.0, None) ** 1.5
    if m.family == "woven":
        # basket weave: alternating blocks of threads running along u and along v
        cell = (np.floor(u / lam) + np.floor(v / lam)) % 2
        return cell * (0.5 + 0.5 * np.cos(2 * k * v)) + (1 - cell) * (0.5 + 0.5 * np.cos(2 * k * u))
    if m.family == "mesh":
        du = np.abs(((u / lam) % 1.0) - 0.5) * lam
        dv = np.abs(((v / lam) % 1.0) - 0.5) * lam
        w = lam / 7.0
        return np.maximum(np.exp(-((du / w) ** 2)), np.exp(-((dv / w) ** 2)))
    if m.family == "grain":
        import cv2

        H, W = u.shape
        n = rng.standard_normal((H, W)).astype(np.float32)
        g = cv2.GaussianBlur(n, (0, 0), max(0.5, lam / 4.0 / MM_PER_PX))
        g = (g - g.min()) / max(1e-6, float(g.max() - g.min()))
        return g**2
    raise InputError("unknown material family", field="family", expected=" | ".join(FAMILIES), got=m.family)


def draw_contact(m: Material, rng: np.random.Generator) -> Contact:
    """Draw one contact's press force, orientation, position, curvature and sensor unit."""
    force = "firm" if rng.random() < 0.5 else "light"
    if m.family == "ycb":
        return _draw_ycb_contact(m, force, rng)
    base = {"light": 0.35, "firm": 0.65}[force] * (0.45 if m.softness == "soft" else 1.0)
    depth = base * float(rng.uniform(0.85, 1.15))
    k = int(rng.integers(0, 4))
    angle = 45.0 * k + float(rng.uniform(-8, 8))
    if m.family == "ridges":
        orientation = ("vertical", "diagonal", "horizontal", "diagonal")[k]  # ridges run across u
    elif m.family in ("bumps", "woven", "mesh"):
        orientation = ("aligned", "diagonal")[k % 2]
    else:
        orientation = "-"
    edge = rng.random() < 0.4
    if edge:
        ang = rng.uniform(0, 2 * np.pi)
        cx = IMAGE_W / 2 + np.cos(ang) * IMAGE_W * 0.3
        cy = IMAGE_H / 2 + np.sin(ang) * IMAGE_H * 0.3
    else:
        cx = IMAGE_W / 2 + rng.uniform(-4, 4)
        cy = IMAGE_H / 2 + rng.uniform(-4, 4)
    radius = float(rng.uniform(50.0, 150.0)) * (2.0 if m.softness == "soft" else 1.0)
    return Contact(
        force,
        depth,
        angle,
        orientation,
        (float(cx), float(cy)),
        "edge" if edge else "centred",
        radius,
        int(rng.integers(0, SENSOR_UNITS)),
    )


def _draw_ycb_contact(m: Material, force: str, rng: np.random.Generator) -> Contact:
    """A press of a random spot of the YCB object (rigid: the gel takes the full depth)."""
    from vtrack.language.ycb import curvature_word, sensor_pose

    depth = {"light": 0.35, "firm": 0.65}[force] * float(rng.uniform(0.85, 1.15))
    angle = float(rng.uniform(0.0, 360.0))
    edge = rng.random() < 0.4
    off = (0.0, 0.0)
    if edge:
        ang = rng.uniform(0, 2 * np.pi)
        off = (float(np.cos(ang) * IMAGE_W * 0.3), float(np.sin(ang) * IMAGE_H * 0.3))
    T, radius = sensor_pose(m.obj, rng, depth, angle, off, MM_PER_PX)
    centre = (IMAGE_W / 2 + off[0], IMAGE_H / 2 + off[1])
    unit = int(rng.integers(0, SENSOR_UNITS))
    pose = tuple(float(x) for x in T.ravel())
    rad = float(min(radius, 1e6))
    position = "edge" if edge else "centred"
    return Contact(force, depth, angle, "-", centre, position, rad, unit, curvature_word(radius), pose)


def contact_height(m: Material, c: Contact, rng: np.random.Generator) -> np.ndarray:
    """Gel indentation (mm, (IMAGE_H, IMAGE_W) float32) of contact ``c`` on material ``m``."""
    if m.family == "ycb":
        from vtrack.language.ycb import press_height

        T = np.asarray(c.pose, np.float64).reshape(4, 4)
        return press_height(m.obj, T, IMAGE_W, IMAGE_H, MM_PER_PX, c.depth_mm)
    yy, xx = np.mgrid[0:IMAGE_H, 0:IMAGE_W].astype(np.float32)
    x = (xx - c.centre_px[0]) * MM_PER_PX
    y = (yy - c.centre_px[1]) * MM_PER_PX
    a = np.deg2rad(c.angle_deg)
    u = np.cos(a) * x + np.sin(a) * y + rng.uniform(0, 10)
    v = -np.sin(a) * x + np.cos(a) * y + rng.uniform(0, 10)
    amp = 0.0 if m.family == "smooth" else AMPLITUDE_MM[m.amplitude] * (0.5 if m.softness == "soft" else 1.0)
    z = -(x * x + y * y) / (2.0 * c.radius_mm) + amp * _texture(m, u, v, rng)
    h = z - (float(z.max()) - c.depth_mm)
    return np.clip(h, 0.0, None).astype(np.float32)


# ----------------------------------------------------------------------------------------------- descriptions
def _pick(word: str, synonyms: dict[str, list[str]], rng: np.random.Generator | None, p: float) -> str:
    if rng is not None and word in synonyms and rng.random() < p:
        return str(rng.choice(synonyms[word]))
    return word


def description(
    m: Material,
    c: Contact | None,
    *,
    mode: int = 2,
    distractor: bool = True,
    rng: np.random.Generator | None = None,
    augment: bool = False,
    appearance: tuple[str, str] | None = None,
) -> str:
    """Structured description of material ``m`` (and contact ``c``; None = the material-level anchor text).

    Args:
        mode: 2 = anchor + additional attributes (paper Mode 2); 3 = Mode 2 with the material name in front.
        distractor: append a non-tactile clause ("it looks red and square"); needs ``rng``.
        rng: draws the distractor words and, with ``augment``, the synonyms and attribute order.
        augment: synonym replacement (p = 0.3) and attribute shuffling, as the paper's text augmentation, and
            dropping the contact clause (p = 0.25).
        appearance: (colour, shape) of the distractor clause instead of a random draw (the correlated-appearance
            setting, :func:`instance_appearance`); None: random words (YCB: the object's true ones).
    """
    p = 0.3 if augment else 0.0
    r = rng if augment else None
    soft = _pick(m.softness, SOFT_SYNONYMS, r, p)
    fam = _pick(FAMILY_WORD.get(m.family, "smooth"), FAMILY_SYNONYMS, r, p)
    if m.family == "ycb":
        from vtrack.language.ycb import dominant_curvature

        present = [soft, _pick("smooth", FAMILY_SYNONYMS, r, p), dominant_curvature(m.obj)]
        absent = ["rough"]
    elif m.family == "smooth":
        present = [soft, fam]
        absent = ["rough", "bumpy", "ridged"]
    else:
        present = [soft, f"{WAVE_ADVERB[m.wavelength]} {fam}", _pick(AMP_WORD[m.amplitude], AMP_SYNONYMS, r, p)]
        absent = ["smooth"]
    absent.insert(0, "hard" if m.softness == "soft" else "soft")
    if augment and rng is not None:
        rng.shuffle(present)
        rng.shuffle(absent)
    txt = "feels " + ", ".join(present[:-1]) + " and " + present[-1] + "; " + ", ".join(f"not {w}" for w in absent)
    if c is not None and augment and rng is not None and rng.random() < 0.25:
        c = None  # sometimes the material-level text alone (what object-level touch -> text ranks)
    if c is not None:
        extra = ["pressed " + ("firmly" if c.force == "firm" else "lightly")]
        if c.orientation != "-":
            extra.append(c.orientation)
        if c.curvature != "-":
            extra.append(c.curvature)
        extra.append(c.position)
        if augment and rng is not None:
            rng.shuffle(extra)
        txt += ". " + ", ".join(extra)
    if mode == 3:
        txt = f"{m.name}: {txt}"
    if distractor and appearance is not None:
        txt += f". it looks {appearance[0]} and {appearance[1]}"
    elif distractor:
        if rng is None:
            raise InputError("a distractor clause needs a random generator", field="rng")
        colour, shape = rng.choice(COLOURS), rng.choice(SHAPES)
        if m.family == "ycb":
            from vtrack.language.ycb import YCB_OBJECTS

            _, colour, shape = YCB_OBJECTS[m.obj]  # the object's true colour and shape (correlated distractors)
        txt += f". it looks {colour} and {shape}"
    return txt + "."


# ----------------------------------------------------------------------------------------------- dataset
@dataclass
class TactileSet:
    """Rendered contacts: ``images`` (N, 3, H, W) float32 (frame minus no-contact background, /64 so a
    strong contact is about 1), ``material`` (N,) int, ``contact`` (N,) int index within the material,
    ``split`` (N,) str (train | val | test | ood), ``contacts`` the draws, plus the material list."""

    images: np.ndarray
    material: np.ndarray
    contact: np.ndarray
    split: np.ndarray
    contacts: list[Contact]
    materials: list[Material]

    def subset(self, mask: np.ndarray) -> TactileSet:
        idx = np.flatnonzero(mask)
        return TactileSet(
            self.images[idx],
            self.material[idx],
            self.contact[idx],
            self.split[idx],
            [self.contacts[i] for i in idx],
            self.materials,
        )

    def texts(
        self,
        *,
        mode: int = 2,
        seed: int = 0,
        augment: bool = False,
        distractor: bool = True,
        appearance: str = "random",
    ) -> list[str]:
        """One description per contact (a fixed seed gives the evaluation's canonical texts).

        ``appearance`` (the distractor clause; see :data:`APPEARANCES`): "random" colour / shape words per text (the
        canonical texts; YCB: the object's true ones), "instance" the material's own fixed appearance
        (:func:`instance_appearance`: non-tactile words correlated with the material, as in real data), "other" a
        random appearance that is not the material's own (another instance / another annotator)."""
        if appearance not in APPEARANCES:
            raise InputError("unknown appearance scheme", field="appearance", expected=" | ".join(APPEARANCES))
        rng = np.random.default_rng(seed)
        app: list[tuple[str, str] | None] = [None] * len(self.material)
        if appearance != "random":
            own = instance_appearance(self.materials)
            arng = np.random.default_rng([seed, 7])  # its own stream: the augmentation draws stay as they are
            app = [
                own[int(m)] if appearance == "instance" else other_appearance(own[int(m)], arng) for m in self.material
            ]
        return [
            description(self.materials[m], c, mode=mode, distractor=distractor, rng=rng, augment=augment, appearance=a)
            for m, c, a in zip(self.material, self.contacts, app, strict=True)
        ]


#: distractor-clause schemes of :meth:`TactileSet.texts`
APPEARANCES = ("random", "instance", "other")
#: seed of the fixed colour / shape assignment of the correlated-appearance setting
APPEARANCE_SEED = 2511


def instance_appearance(mats: list[Material]) -> dict[int, tuple[str, str]]:
    """Material index -> its fixed (colour, shape): what an annotator sees on *this* sample of the material (a
    given sponge is always yellow). Procedural materials take the 60 colour x shape pairs in a seeded order
    (so the pair nearly identifies the material, the strongest shortcut); YCB objects keep their true ones."""
    from vtrack.language.ycb import YCB_OBJECTS

    pairs = [(c, s) for c in COLOURS for s in SHAPES]
    order = np.random.default_rng(APPEARANCE_SEED).permutation(len(pairs))
    out: dict[int, tuple[str, str]] = {}
    k = 0
    for m in mats:
        if m.family == "ycb":
            _, c, s = YCB_OBJECTS[m.obj]
            out[m.index] = (c, s)
        else:
            out[m.index] = pairs[int(order[k % len(pairs)])]
            k += 1
    return out


def other_appearance(own: tuple[str, str], rng: np.random.Generator) -> tuple[str, str]:
    """A random (colour, shape) other than ``own``: the same material seen on another instance."""
    while True:
        a = (str(rng.choice(COLOURS)), str(rng.choice(SHAPES)))
        if a != own:
            return a


def background() -> np.ndarray:
    """The no-contact DIGIT frame the contacts are rendered onto (uint8 BGR, (IMAGE_H, IMAGE_W, 3))."""
    from vtrack.tactile.sensors import default_background

    return np.asarray(default_background("digit", IMAGE_W, IMAGE_H))


def to_input(frame_bgr: np.ndarray, bg: np.ndarray) -> np.ndarray:
    """Network input (3, H, W) float32 of a uint8 BGR frame: (frame - background) / 64."""
    d = (np.asarray(frame_bgr, np.float32) - np.asarray(bg, np.float32)) / 64.0
    return np.ascontiguousarray(d.transpose(2, 0, 1))


def render_contact(m: Material, c: Contact, rng: np.random.Generator, models=None, bg=None) -> np.ndarray:
    """Tactile frame (uint8 BGR, (IMAGE_H, IMAGE_W, 3)) of one contact, by the independent optical model."""
    from vtrack.sim.tactile_optics import OpticalModel

    bg = background() if bg is None else bg
    model = (models or {}).get(c.unit) or OpticalModel.for_sensor("digit", seed=1000 + c.unit)
    return model.render(contact_height(m, c, rng), MM_PER_PX, bg, rng, 1.0)


def _cache_path(ycb: bool) -> Path:
    from vtrack.paths import cache_dir
    from vtrack.sim.tactile_optics import optics_fingerprint

    h = hashlib.sha1(Path(__file__).read_bytes())
    h.update(Path(__file__).with_name("ycb.py").read_bytes())
    tag = "ycb" if ycb else "noycb"
    return cache_dir() / "language" / f"materials_v{DATA_VERSION}_{h.hexdigest()[:10]}_{optics_fingerprint()}_{tag}.npz"


def ycb_available() -> bool:
    """Whether every YCB mesh of the library is in the shared data folder."""
    from vtrack.language.ycb import YCB_OBJECTS, ycb_dir

    try:
        d = ycb_dir()
    except Exception:  # no shared data folder configured
        return False
    return all((d / f"{s}.ply").exists() for s in YCB_OBJECTS)


def generate(
    seed: int = 0,
    *,
    use_cache: bool = True,
    quick: bool = False,
    ycb: bool | None = None,
    extra_train: int = EXTRA_TRAIN_CONTACTS,
) -> TactileSet:
    """Render every material's contacts (1632 frames with the YCB patches, about 40 s on one core); cached in
    ``cache_dir()``.

    ``quick`` renders only the first 2 test contacts of each training material and the first 2 contacts of
    each OOD material (136 frames, a few seconds, not cached): the same draws, for smoke tests. ``ycb`` None
    includes the YCB patches when the shared meshes are present (False: the 62 procedural materials only;
    True: an InputError naming the missing mesh if they are absent). ``extra_train`` more training contacts
    per training material (contact indices 24, 25, ...) come from their own random stream (seed, 1), so every
    other frame is the same for any ``extra_train``."""
    from vtrack.sim.tactile_optics import OpticalModel

    ycb = ycb_available() if ycb is None else ycb
    mats = materials(ycb=ycb)
    extra_train = 0 if quick else int(extra_train)
    path = _cache_path(ycb).with_name(_cache_path(ycb).stem + f"_s{seed}_x{extra_train}.npz")
    rng = np.random.default_rng(seed)
    contacts: list[Contact] = []
    material, index, split = [], [], []
    for m in mats:
        for i in range(CONTACTS_PER_MATERIAL):
            contacts.append(draw_contact(m, rng))
            material.append(m.index)
            index.append(i)
            split.append("ood" if m.ood else "train" if i in TRAIN_CONTACTS else "val" if i in VAL_CONTACTS else "test")
    if quick:
        keep = [
            i
            for i, (sp, ci) in enumerate(zip(split, index, strict=True))
            if (sp == "test" and ci < TEST_CONTACTS.start + 2) or (sp == "ood" and ci < 2)
        ]
        contacts = [contacts[i] for i in keep]
        material = [material[i] for i in keep]
        index = [index[i] for i in keep]
        split = [split[i] for i in keep]
        use_cache = False
    n_base = len(contacts)
    rng_x = np.random.default_rng([seed, 1])
    for m in mats:
        for i in range(CONTACTS_PER_MATERIAL, CONTACTS_PER_MATERIAL + (0 if m.ood else extra_train)):
            contacts.append(draw_contact(m, rng_x))
            material.append(m.index)
            index.append(i)
            split.append("train")
    if use_cache and path.exists():
        with np.load(path) as z:
            images = z["images"]
    else:
        bg = background()
        models = {u: OpticalModel.for_sensor("digit", seed=1000 + u) for u in range(SENSOR_UNITS)}
        pairs = list(zip(material, contacts, strict=True))
        frames = [render_contact(mats[mi], c, rng, models, bg) for mi, c in pairs[:n_base]]
        frames += [render_contact(mats[mi], c, rng_x, models, bg) for mi, c in pairs[n_base:]]
        images = np.stack([to_input(f, bg) for f in frames]).astype(np.float32)
        if use_cache:
            from vtrack.io.jsonio import atomic_savez

            atomic_savez(path, images=images)
    return TactileSet(images, np.asarray(material), np.asarray(index), np.asarray(split), contacts, mats)


def material_table() -> list[dict]:
    """The material library as rows (for docs and the CLI)."""
    return [asdict(m) | {"name": m.name} for m in materials()]
