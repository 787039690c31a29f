#!/usr/bin/env python
"""Generate synthetic sessions in bulk (e.g. the benchmark sweeps) into a folder.

Usage:
    python data_tools/generate.py scenes/occlusion_none.yaml --out /tmp/sessions --seconds 5 \
        --occlusion none medium heavy --seeds 0 1 [--object MESH ...]

Writes ``OUT/<scene>-<object>-<occlusion>-s<seed>/`` per combination (skips complete ones).
"""

from __future__ import annotations

import argparse
import itertools
import json
import time
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene", type=Path)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--seconds", type=float, default=None)
    ap.add_argument("--occlusion", nargs="+", default=[None])
    ap.add_argument("--seeds", nargs="+", type=int, default=[None])
    ap.add_argument("--object", nargs="+", type=Path, default=[None], dest="objects")
    ap.add_argument("--force", action="store_true")
    args = ap.parse_args(argv)

    from vtrack.scene import load_scene
    from vtrack.sim.generate import generate_session

    scene = load_scene(args.scene)
    args.out.mkdir(parents=True, exist_ok=True)
    for obj, occ, seed in itertools.product(args.objects, args.occlusion, args.seeds):
        name = "-".join(
            [
                scene.name,
                obj.stem if obj else scene.object.name,
                occ or "scene",
                f"s{seed if seed is not None else 'scene'}",
            ]
        )
        dst = args.out / name
        man = dst / "manifest.json"
        if man.exists() and json.loads(man.read_text()).get("complete") and not args.force:
            print(f"skip {dst} (complete)")
            continue
        t0 = time.perf_counter()
        generate_session(scene, dst, seconds=args.seconds, seed=seed, occlusion=occ, object_mesh=obj, overwrite=True)
        print(f"{dst}  {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
