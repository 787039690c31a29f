"""Convert a Taxim ``dataPack*.npz`` (imgs, f0, touch_center, touch_radius) into a vtrack press-set folder.

    python data_tools/convert_taxim_npz.py SRC.npz OUT_DIR --mm-per-px 0.1245 --ball-radius-mm 2.0

Writes ``OUT_DIR/press_NN.png`` (BGR, lossless), ``background.png``, ``labels.csv`` and ``meta.json``.
For the shared ``taxim_datapack_small`` pack the defaults come from the preset
``vtrack/tactile/presets/taxim_datapack_small.json`` when ``--mm-per-px``/``--ball-radius-mm`` are omitted.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from vtrack.errors import InputError
from vtrack.tactile.pressset import PRESETS_DIR

KEYS = ("imgs", "f0", "touch_center", "touch_radius")


def convert(
    src: str | Path,
    out: str | Path,
    *,
    mm_per_px: float | None = None,
    ball_radius_mm: float | None = None,
    sensor: str | None = None,
) -> Path:
    """Write the press-set folder ``out`` from the Taxim pack ``src``; returns ``out``."""
    import cv2

    src, out = Path(src), Path(out)
    if not src.is_file():
        raise InputError("Taxim pack not found", path=src)
    with np.load(src, allow_pickle=False) as z:
        missing = [k for k in KEYS if k not in z.files]
        if missing:
            raise InputError("not a Taxim dataPack", path=src, field=",".join(missing), expected=str(KEYS))
        imgs, bg, centers, radii = (z[k] for k in KEYS)
    if imgs.ndim != 4 or imgs.shape[1:] != bg.shape or len(centers) != len(imgs) or len(radii) != len(imgs):
        raise InputError("inconsistent array shapes", path=src, got=(imgs.shape, bg.shape, centers.shape, radii.shape))
    preset = PRESETS_DIR / f"{src.stem.replace('dataPack', 'taxim_datapack').lower()}.json"
    meta = json.loads(preset.read_text()) if preset.is_file() else {}
    meta.update(
        {
            k: v
            for k, v in {"sensor": sensor, "mm_per_px": mm_per_px, "ball_radius_mm": ball_radius_mm}.items()
            if v is not None
        }
    )
    meta.setdefault("sensor", "gelsight")
    if "mm_per_px" not in meta or "ball_radius_mm" not in meta:
        raise InputError("give --mm-per-px and --ball-radius-mm (no preset for this pack)", path=src)
    meta["source"] = str(src)
    out.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out / "background.png"), np.ascontiguousarray(bg, np.uint8))
    lines = ["file,center_x_px,center_y_px,contact_radius_px"]
    for i, (img, c, r) in enumerate(zip(imgs, centers, radii, strict=True)):
        name = f"press_{i:02d}.png"
        cv2.imwrite(str(out / name), np.ascontiguousarray(img, np.uint8))
        lines.append(f"{name},{float(c[0]):g},{float(c[1]):g},{float(r):g}")
    (out / "labels.csv").write_text("\n".join(lines) + "\n")
    (out / "meta.json").write_text(json.dumps(meta, indent=1))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("src", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--mm-per-px", type=float, default=None)
    ap.add_argument("--ball-radius-mm", type=float, default=None)
    ap.add_argument("--sensor", default=None)
    a = ap.parse_args()
    print(convert(a.src, a.out, mm_per_px=a.mm_per_px, ball_radius_mm=a.ball_radius_mm, sensor=a.sensor))


if __name__ == "__main__":
    main()
