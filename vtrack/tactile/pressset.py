"""Press-set format: ball-press calibration images with labelled contact circles.

A press set is a folder holding
- ``background.png``: a no-contact frame (BGR, as ``cv2.imread`` returns it);
- the press images, and optionally ``labels.csv`` (without it the contact circles are detected
  automatically, :mod:`vtrack.tactile.autolabel`) with columns ``file,center_x_px,center_y_px,contact_radius_px``
  (x = column, y = row, origin top-left; the radius is the visible contact circle, not the ball);
- ``meta.json`` with ``sensor``, ``mm_per_px`` and ``ball_radius_mm``. ``mm_per_px`` may be left out for a
  known sensor type (:data:`vtrack.tactile.sensors.SENSOR_PRESETS`): the preset's nominal pitch, rescaled to the
  background's size, is used and flagged (``PressSet.mm_per_px_source == "preset"``).

When the folder is read-only and has no ``meta.json``, the metadata comes (in order of precedence) from
explicit overrides (CLI flags), a ``--meta`` JSON file, ``meta.json`` in the folder, or a preset shipped in
``vtrack/tactile/presets/<folder name>.json`` for the known shared sets.
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError

PRESETS_DIR = Path(__file__).resolve().parent / "presets"
META_FIELDS = ("sensor", "mm_per_px", "ball_radius_mm")
LABEL_COLUMNS = ("file", "center_x_px", "center_y_px", "contact_radius_px")


@dataclass
class Press:
    """One labelled press: image file, contact-circle centre (x = col, y = row) and radius in px."""

    file: str
    center_xy_px: tuple[float, float]
    contact_radius_px: float
    index: int = 0


@dataclass
class PressSet:
    """A loaded press set; images are read lazily and cached (uint8 BGR, (H, W, 3))."""

    root: Path
    presses: list[Press]
    sensor: str
    mm_per_px: float
    ball_radius_mm: float
    background_file: str = "background.png"
    labels_source: str = "hand"  # hand (labels.csv) | auto (vtrack.tactile.autolabel)
    #: where mm_per_px came from: "given" (meta/flags) | "preset" (the sensor type's nominal pitch, unverified)
    mm_per_px_source: str = "given"
    detections: list = field(default_factory=list, repr=False)  # autolabel Detections (auto sets only)
    _cache: dict[str, np.ndarray] = field(default_factory=dict, repr=False)

    @classmethod
    def from_meta(cls, root: Path, presses: list[Press], meta: dict, **kw: Any) -> PressSet:
        """A press set whose sensor, pitch (and its source) and ball radius come from a checked ``meta.json``
        dict (:func:`load_press_set`)."""
        keys = ("sensor", "mm_per_px", "ball_radius_mm", "mm_per_px_source")
        return cls(root, presses, **{k: meta[k] for k in keys}, **kw)

    @property
    def ball_radius_px(self) -> float:
        return self.ball_radius_mm / self.mm_per_px

    def meta(self) -> dict:
        return {"sensor": self.sensor, "mm_per_px": self.mm_per_px, "ball_radius_mm": self.ball_radius_mm}

    def read(self, name: str) -> np.ndarray:
        if name not in self._cache:
            self._cache[name] = read_bgr(self.root / name)
        return self._cache[name]

    def background(self) -> np.ndarray:
        return _not_blank(
            self.read(self.background_file),
            self.root / self.background_file,
            "background image",
            "the sensor's no-contact tactile image",
        )

    def image(self, press: Press) -> np.ndarray:
        img = self.read(press.file)
        bg = self.background()
        if img.shape != bg.shape:
            raise InputError(
                "press image size differs from the background",
                path=self.root / press.file,
                expected=str(bg.shape),
                got=img.shape,
            )
        return _not_blank(img, self.root / press.file, "press image", "a tactile image of a ball press")

    @property
    def shape(self) -> tuple[int, int]:
        return self.background().shape[:2]

    def split(self, holdout: str | None) -> tuple[list[Press], list[Press]]:
        """(train, test) presses from a hold-out spec (see :func:`parse_holdout`)."""
        test_idx = parse_holdout(holdout, self.presses)
        train = [p for p in self.presses if p.index not in test_idx]
        test = [p for p in self.presses if p.index in test_idx]
        return train, test


def _not_blank(img: np.ndarray, path: Path, what: str, expected: str) -> np.ndarray:
    """``img`` unless it is blank (all-black, all-white, constant: colour std < 2 levels). A blank frame carries
    no press; calibrating on it gives a calibration that looks fine but is ~40 degrees off (issue #22)."""
    if float(img.std()) < 2.0:
        raise InputError(
            f"{what} is blank (constant colour)", path=path, expected=expected, got=f"std {float(img.std()):.2f}"
        )
    return img


def read_bgr(path: str | Path) -> np.ndarray:
    """Read an 8-bit 3-channel image (BGR) with a clear error when it is missing or unreadable."""
    from vtrack.io.images import read_image

    path = Path(path)
    img = read_image(path)
    # Tactile calibration maps colour to surface slope: a grey image has lost that information and
    # would give a confidently wrong contact, so it is refused rather than silently expanded to BGR.
    if img.ndim == 2 or img.shape[2] == 1:
        raise InputError(
            "tactile image is greyscale; the calibration needs the colour channels",
            path=path,
            expected="an 8-bit colour (BGR) image",
            got=f"{img.shape[1]}x{img.shape[0]} grey",
        )
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    elif img.dtype != np.uint8:
        raise InputError("unsupported pixel type", path=path, expected="8- or 16-bit", got=str(img.dtype))
    img = np.ascontiguousarray(img[..., :3])
    if img.size > 64 and not (np.any(img[..., 0] != img[..., 1]) or np.any(img[..., 1] != img[..., 2])):
        raise InputError(
            "tactile image has no colour (all three channels are equal)",
            path=path,
            expected="a colour (BGR) tactile image",
            got="grey stored as colour",
        )
    return img


DEFAULT_HOLDOUT = "every:4:3"


def parse_holdout(spec: str | None, presses: list[Press]) -> set[int]:
    """Indices of held-out presses.

    ``spec``: ``every:K[:OFFSET]`` (every K-th press from OFFSET; default ``every:4:3``, i.e. 25 %),
    ``idx:1,5,9`` (press indices), ``files:press_03.png,press_07.png``, ``last:N``, ``none``.
    """
    spec = DEFAULT_HOLDOUT if spec in (None, "") else spec.strip()
    n = len(presses)
    kind, _, rest = spec.partition(":")
    try:
        if kind == "none":
            return set()
        if kind == "every":
            parts = [int(x) for x in rest.split(":") if x]
            k = parts[0]
            off = parts[1] if len(parts) > 1 else k - 1
            if k < 2:
                raise ValueError
            return {p.index for p in presses if p.index % k == off % k}
        if kind == "idx":
            want = {int(x) for x in rest.split(",") if x.strip()}
            bad = want - {p.index for p in presses}
            if bad:
                raise InputError(
                    "hold-out index out of range", field="holdout", expected=f"0..{n - 1}", got=sorted(bad)
                )
            return want
        if kind == "files":
            names = {x.strip() for x in rest.split(",") if x.strip()}
            found = {p.index for p in presses if p.file in names}
            missing = names - {p.file for p in presses}
            if missing:
                raise InputError("hold-out file not in labels.csv", field="holdout", got=sorted(missing))
            return found
        if kind == "last":
            k = int(rest)
            return {p.index for p in presses[n - k :]} if k > 0 else set()
    except (ValueError, IndexError):
        pass
    raise InputError(
        "bad hold-out spec",
        field="holdout",
        expected="every:K[:OFFSET] | idx:i,j | files:a.png,b.png | last:N | none",
        got=spec,
    )


def _read_meta_file(path: Path) -> dict:
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError("meta file not found", path=path) from None
    except json.JSONDecodeError as e:
        raise InputError(f"meta file is not valid JSON ({e})", path=path) from None
    if not isinstance(data, dict):
        raise InputError("meta file must hold a JSON object", path=path, expected="{sensor, mm_per_px, ...}")
    return data


def resolve_meta(root: Path, meta_file: str | Path | None = None, **overrides) -> dict:
    """Merge metadata: preset < folder meta.json < --meta file < explicit overrides (None = unset)."""
    meta: dict = {}
    preset = PRESETS_DIR / f"{root.name}.json"
    if preset.is_file():
        meta.update(_read_meta_file(preset))
    if (root / "meta.json").is_file():
        meta.update(_read_meta_file(root / "meta.json"))
    if meta_file is not None:
        meta.update(_read_meta_file(Path(meta_file)))
    # a recorder that used the preset's nominal pitch says so ("preset"); a pitch given on the command line
    # (or a file without the field) counts as given
    source = "preset" if meta.get("mm_per_px_source") == "preset" and "mm_per_px" in meta else "given"
    meta.update({k: v for k, v in overrides.items() if v is not None})
    meta["mm_per_px_source"] = "given" if overrides.get("mm_per_px") is not None else source
    if "mm_per_px" not in meta and "sensor" in meta:
        # a known sensor type without a measured pitch: its preset's nominal pitch at this image size (flagged)
        from vtrack.tactile.sensors import SENSOR_PRESETS

        preset = SENSOR_PRESETS.get(str(meta["sensor"]))
        bg = root / "background.png"
        if preset is not None and bg.is_file():
            h, w = read_bgr(bg).shape[:2]
            meta["mm_per_px"] = preset.pitch_at(w, h)
            meta["mm_per_px_source"] = "preset"
    missing = [k for k in META_FIELDS if k not in meta]
    if missing:
        raise InputError(
            "press-set metadata missing (add meta.json, pass --meta FILE or the flags "
            "--sensor/--mm-per-px/--ball-radius-mm)",
            path=root,
            field=",".join(missing),
        )
    for k in ("mm_per_px", "ball_radius_mm"):
        try:
            v = float(meta[k])
        except (TypeError, ValueError):
            raise InputError("not a number", path=root, field=k, got=meta[k]) from None
        if not (np.isfinite(v) and v > 0):
            raise InputError("must be a positive number", path=root, field=k, expected="> 0", got=meta[k])
        meta[k] = v
    meta["sensor"] = str(meta["sensor"])
    return meta


def load_press_set(
    path: str | Path,
    meta_file: str | Path | None = None,
    *,
    sensor: str | None = None,
    mm_per_px: float | None = None,
    ball_radius_mm: float | None = None,
    labels: str = "hand_or_auto",
    autolabel_opts=None,
) -> PressSet:
    """Load a press-set folder (see module docstring). Images are read on first use.

    ``labels``: ``hand`` (``labels.csv`` required), ``auto`` (contact circles detected by
    :mod:`vtrack.tactile.autolabel`, any ``labels.csv`` ignored) or ``hand_or_auto`` (hand labels when
    ``labels.csv`` exists, else automatic). An automatically labelled set carries its detections (used and
    dropped, with reasons) in ``PressSet.detections``; fewer than ``MIN_PRESSES`` usable presses is an error.
    """
    root = Path(path)
    if not root.is_dir():
        raise InputError(
            "press-set folder not found",
            path=root,
            expected="folder with background.png and press images (labels.csv optional)",
        )
    if labels not in ("hand", "auto", "hand_or_auto"):
        raise InputError("unknown label source", field="labels", expected="hand | auto | hand_or_auto", got=labels)
    meta = resolve_meta(root, meta_file, sensor=sensor, mm_per_px=mm_per_px, ball_radius_mm=ball_radius_mm)
    if not (root / "background.png").is_file():
        raise InputError("background.png not found in the press set", path=root / "background.png")
    csv_path = root / "labels.csv"
    if labels == "auto" or (labels == "hand_or_auto" and not csv_path.is_file()):
        return _auto_press_set(root, meta, autolabel_opts)
    if not csv_path.is_file():
        raise InputError("labels.csv not found in the press set", path=csv_path)
    presses = read_labels(csv_path)
    return PressSet.from_meta(root, presses, meta)


def read_labels(labels: Path) -> list[Press]:
    """Presses of a ``labels.csv`` (hand labels; see module docstring)."""
    presses: list[Press] = []
    with open(labels, newline="") as f:
        reader = csv.DictReader(f)
        cols = reader.fieldnames or []
        if any(c not in cols for c in LABEL_COLUMNS):
            raise InputError("labels.csv header", path=labels, expected=",".join(LABEL_COLUMNS), got=cols)
        for i, row in enumerate(reader):
            try:
                cx, cy, r = (float(row[c]) for c in LABEL_COLUMNS[1:])
            except (TypeError, ValueError):
                raise InputError(f"row {i + 2}: non-numeric label", path=labels, got=row) from None
            if not (np.isfinite([cx, cy, r]).all() and r > 0):
                raise InputError(
                    f"row {i + 2}: bad contact circle", path=labels, expected="finite, radius > 0", got=row
                )
            presses.append(Press(row["file"], (cx, cy), r, index=i))
    if not presses:
        raise InputError("labels.csv has no presses", path=labels)
    return presses


def _auto_press_set(root: Path, meta: dict, opts) -> PressSet:
    from vtrack.tactile.autolabel import MIN_PRESSES, auto_label

    dets = auto_label(root, meta["ball_radius_mm"] / meta["mm_per_px"], opts)
    presses = [
        Press(d.file, (d.center_x_px, d.center_y_px), d.contact_radius_px, index=i)
        for i, d in enumerate(x for x in dets if x.ok)
    ]
    if len(presses) < MIN_PRESSES:
        reasons: dict[str, int] = {}
        for d in dets:
            if not d.ok:
                key = d.reason.split(" (")[0]
                reasons[key] = reasons.get(key, 0) + 1
        why = "; ".join(f"{n} x {k}" for k, n in sorted(reasons.items(), key=lambda kv: -kv[1]))
        raise InputError(
            f"only {len(presses)} usable presses of {len(dets)} (dropped: {why})",
            path=root,
            expected=f">= {MIN_PRESSES} ball presses with a clear contact",
        )
    return PressSet.from_meta(root, presses, meta, labels_source="auto", detections=dets)


def sphere_truth(
    press: Press, shape: tuple[int, int], ball_radius_px: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Analytic ball-press surface of one press.

    Returns ``(height_px, gx, gy, inside)``: the indentation (px units) of a sphere of radius
    ``ball_radius_px`` whose intersection with the undeformed gel is the labelled contact circle, its slopes
    dh/dx, dh/dy (px/px = mm/mm) and the boolean contact disc. Outside the disc the gel is flat.
    """
    H, W = shape
    cx, cy = press.center_xy_px
    r = min(press.contact_radius_px, 0.999 * ball_radius_px)
    yy, xx = np.mgrid[0:H, 0:W]
    dx, dy = xx - cx, yy - cy
    rho2 = dx * dx + dy * dy
    inside = rho2 < r * r
    R2 = ball_radius_px**2
    s = np.sqrt(np.clip(R2 - rho2, 1e-12, None))
    base = np.sqrt(R2 - r * r)
    h = np.where(inside, s - base, 0.0)
    gx = np.where(inside, -dx / s, 0.0)
    gy = np.where(inside, -dy / s, 0.0)
    return h, gx, gy, inside


def scaled_press_set(ps: PressSet, factor: int) -> PressSet:
    """The press set with images, background and labels downscaled by ``factor`` (INTER_AREA, held in memory;
    pitch x ``factor``): what the tactile pipeline sees at its working resolution."""
    import cv2

    if factor == 1:
        return ps
    H, W = ps.shape
    size = (W // factor, H // factor)
    cache = {
        name: cv2.resize(ps.read(name), size, interpolation=cv2.INTER_AREA)
        for name in [ps.background_file] + [p.file for p in ps.presses]
    }
    # pixel centres: x_small = (x + 0.5) / f - 0.5
    presses = [
        Press(p.file, tuple((c + 0.5) / factor - 0.5 for c in p.center_xy_px), p.contact_radius_px / factor, p.index)
        for p in ps.presses
    ]
    return PressSet(
        ps.root, presses, ps.sensor, ps.mm_per_px * factor, ps.ball_radius_mm, ps.background_file, _cache=cache
    )
