"""Cached small synthetic sessions for tests of the downstream stages (fusion, tracking, viewer)."""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

from vtrack.io.session import is_complete
from vtrack.paths import cache_dir, default_scene_path

#: Bump when the simulator's output format or content changes (cached sessions are then regenerated).
SIM_CACHE_VERSION = 3

#: The default scene's object (its sessions are shared by tests and benchmarks).
DEFAULT_OBJECT = "005_tomato_soup_can"


def tiny_session_path(
    occlusion: str = "none",
    seconds: float = 1.0,
    object: str | Path | None = None,
    seed: int = 0,
    depth_noise: float | None = None,
    contact_mode: str = "slide",
) -> Path:
    """A small synthetic session of the default scene (generated once into ``cache_dir()``).

    Keyed by the parameters, the default scene's content and :data:`SIM_CACHE_VERSION`, so a changed
    scene or simulator regenerates. ``object`` is an optional mesh path overriding the scene's object;
    ``depth_noise`` overrides the scene's ``sim.depth_noise`` scale.
    """
    scene_file = default_scene_path()
    spec = {
        "occ": occlusion,
        "s": float(seconds),  # 2 and 2.0 are one session (json writes them apart)
        "obj": str(object) if object else None,
        "seed": seed,
        "scene": hashlib.sha1(scene_file.read_bytes()).hexdigest(),
        "v": SIM_CACHE_VERSION,
    }
    if depth_noise is not None:
        spec["noise"] = float(depth_noise)
    if contact_mode != "slide":  # the default mode is not in the key: its sessions keep their cache keys
        spec["contact"] = contact_mode
    key = json.dumps(spec, sort_keys=True)
    digest = hashlib.sha1(key.encode()).hexdigest()[:12]
    mode = "" if contact_mode == "slide" else f"{contact_mode}-"
    path = cache_dir() / "sessions" / f"tiny-{mode}{occlusion}-{seconds:g}s-{digest}"
    if is_complete(path):
        return path
    from vtrack.sim.generate import generate_session

    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + f".tmp{os.getpid()}")
    scene: Any = scene_file
    if depth_noise is not None or contact_mode != "slide":
        from vtrack.scene import load_scene

        scene = load_scene(scene_file)
        if depth_noise is not None:
            scene.sim.depth_noise = float(depth_noise)
        if contact_mode != "slide":
            scene.sim.contact_mode = contact_mode
    generate_session(scene, tmp, seconds=seconds, seed=seed, occlusion=occlusion, object_mesh=object, overwrite=True)
    if not is_complete(path):
        try:
            tmp.rename(path)
        except OSError:  # another process won the race; use theirs
            import shutil

            shutil.rmtree(tmp, ignore_errors=True)
    else:
        import shutil

        shutil.rmtree(tmp, ignore_errors=True)
    return path


def ycb_objects() -> list[str]:
    """Names of the shared YCB objects (``shared/data/objects/ycb/*.ply``), sorted."""
    from vtrack.errors import InputError
    from vtrack.paths import shared_data_dir

    names = sorted(p.stem for p in (shared_data_dir() / "objects" / "ycb").glob("*.ply"))
    if not names:
        raise InputError(
            "no YCB meshes in the shared data", path=shared_data_dir() / "objects" / "ycb", expected="*.ply"
        )
    return names


def ycb_session(
    name: str,
    occlusion: str = "none",
    seconds: float = 2.0,
    depth_noise: float | None = None,
    contact_mode: str = "slide",
    seed: int = 0,
) -> Path:
    """Cached session of the default scene holding the shared YCB object ``name`` (e.g. ``006_mustard_bottle``);
    the default object's sessions are the tests' ones. Used by the benchmarks. ``contact_mode``: the simulator's
    ``sim.contact_mode`` (``slide`` default, ``stick``: fingers follow the object, see :mod:`vtrack.sim.grasp`).
    ``seed``: the simulator's seed (the fingers' pressure schedule, hence the joints and contacts, and the noise of
    the joints, tactile images and camera; the object's trajectory is the scene's and does not change); 0 is every
    benchmark's session, other seeds repeat a benchmark on other sessions of the same object and occlusion."""
    from vtrack.errors import InputError
    from vtrack.paths import shared_data_dir

    mesh = shared_data_dir() / "objects" / "ycb" / f"{name}.ply"
    if not mesh.exists():
        raise InputError("no such YCB object in the shared data", path=mesh, expected="<name>.ply")
    return tiny_session_path(
        occlusion=occlusion,
        seconds=seconds,
        object=None if name == DEFAULT_OBJECT else mesh,
        depth_noise=depth_noise,
        contact_mode=contact_mode,
        seed=seed,
    )
