"""Cached small synthetic sessions for tests of the downstream stages (fusion, tracking, viewer)."""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

from vtrack.paths import cache_dir, default_scene_path


def _complete(path: Path) -> bool:
    try:
        return bool(json.loads((path / "manifest.json").read_text()).get("complete"))
    except (OSError, ValueError):
        return False


def tiny_session_path(occlusion: str = "none", seconds: float = 1.0, object: str | Path | None = None,
                      seed: int = 0) -> Path:
    """A small synthetic session of the default scene (generated once into ``cache_dir()``).

    Keyed by the parameters and the default scene's content, so a changed scene regenerates.
    ``object`` is an optional mesh path overriding the scene's object.
    """
    scene_file = default_scene_path()
    key = json.dumps({"occ": occlusion, "s": seconds, "obj": str(object) if object else None, "seed": seed,
                      "scene": hashlib.sha1(scene_file.read_bytes()).hexdigest(), "v": 2}, sort_keys=True)
    digest = hashlib.sha1(key.encode()).hexdigest()[:12]
    path = cache_dir() / "sessions" / f"tiny-{occlusion}-{seconds:g}s-{digest}"
    if _complete(path):
        return path
    from vtrack.sim.generate import generate_session

    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + f".tmp{os.getpid()}")
    generate_session(scene_file, tmp, seconds=seconds, seed=seed, occlusion=occlusion, object_mesh=object,
                     overwrite=True)
    if not _complete(path):
        try:
            tmp.rename(path)
        except OSError:  # another process won the race; use theirs
            import shutil

            shutil.rmtree(tmp, ignore_errors=True)
    else:
        import shutil

        shutil.rmtree(tmp, ignore_errors=True)
    return path
