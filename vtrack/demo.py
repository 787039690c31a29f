"""The main job (``vtrack demo``): run a scene end to end and write a results folder.

Stages, each run only when its component exists and the scene asks for it:
1. generate a synthetic session from the scene (``vtrack.sim``), cached by scene content, and strip it of
   every trace of ground truth (``vtrack.io.strip``): the pipeline below sees only what a real recording has;
2. reconstruct the object (``vtrack.fusion``) from the blind session: SLAM poses (the shape is not given),
   segmentation and touch without ground truth -> mesh, poses, fused cloud, metrics;
3. track the object pose (``vtrack.tracking``) on the blind session with the scene's mesh as the user's
   known shape (no initial pose: global registration) -> poses, metrics;
4. score both against the ORIGINAL session's ground truth (``vtrack.eval``), and screenshot (``vtrack.viz``).
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import time
from pathlib import Path
from typing import Any

from vtrack.paths import cache_dir, default_scene_path
from vtrack.registry import required_components
from vtrack.scene import load_scene


def _available(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except ModuleNotFoundError:
        return False


def scene_digest(scene) -> str:
    """Short hash of a scene's content and of the generator's code (cache key for generated sessions):
    a changed simulator must not silently reuse sessions it would no longer produce."""
    h = hashlib.sha1(json.dumps(scene.to_dict(), sort_keys=True).encode())
    root = Path(__file__).resolve().parent
    for sub in ("sim", "kinematics", "tactile"):
        for f in sorted((root / sub).glob("*.py")):
            h.update(f.read_bytes())
    return h.hexdigest()[:12]


def run_demo(scene_path: str | Path | None = None, out_dir: str | Path = "results/demo",
             seconds: float | None = None, progress: bool = True) -> dict[str, Any]:
    """Run the demo pipeline on a scene (default: the embedded default scene).

    Returns a summary dict that is also written to ``out_dir/summary.json``.
    """
    t0 = time.perf_counter()
    scene = load_scene(scene_path or default_scene_path())
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    summary: dict[str, Any] = {
        "scene": scene.name,
        "scene_file": str(scene.source),
        "components": required_components(scene),
        "modalities": scene.effective_modalities,
        "stages": {},
    }
    session_dir: Path | None = None
    if scene.sim is not None and _available("vtrack.sim.generate"):
        from vtrack.sim.generate import generate_session

        key = scene_digest(scene) + (f"-{seconds:g}s" if seconds else "")
        session_dir = cache_dir() / "sessions" / f"{scene.name}-{key}"
        ts = time.perf_counter()
        if not (session_dir / "manifest.json").exists() or not _session_complete(session_dir):
            generate_session(scene, session_dir, seconds=seconds, overwrite=True, progress=progress)
        summary["stages"]["generate"] = {"session": str(session_dir), "seconds": time.perf_counter() - ts}
    blind_dir: Path | None = None
    if session_dir is not None:
        from vtrack.io.strip import strip_gt

        blind_dir = session_dir.with_name(session_dir.name + "-blind")
        ts = time.perf_counter()
        if not _session_complete(blind_dir):
            strip_gt(session_dir, blind_dir, overwrite=blind_dir.exists())
        summary["stages"]["strip_gt"] = {"session": str(blind_dir), "seconds": time.perf_counter() - ts}
    if blind_dir is not None and scene.pipeline.reconstruction != "off" and _available("vtrack.fusion.reconstruct"):
        from vtrack.fusion.reconstruct import reconstruct_session

        summary["stages"]["reconstruct"] = reconstruct_session(blind_dir, out / "reconstruction",
                                                               method=scene.pipeline.reconstruction,
                                                               modalities=tuple(scene.effective_modalities),
                                                               poses="track", gt=session_dir)
    if blind_dir is not None and scene.pipeline.tracking != "off" and _available("vtrack.tracking.run"):
        from vtrack.tracking.run import track_session

        known = scene.pipeline.tracking == "known_shape" and scene.object.mesh is not None
        summary["stages"]["track"] = track_session(blind_dir, out / "tracking", shape="known" if known else "slam",
                                                   mesh=scene.object.mesh if known else None, gt=session_dir,
                                                   modalities=tuple(scene.effective_modalities))
    produced = any(k in summary["stages"] for k in ("generate", "reconstruct", "track"))
    if produced and _available("vtrack.viz.screenshot"):
        from vtrack.viz.screenshot import render_result

        has_result = any((out / d / "result.json").exists() for d in ("reconstruction", "tracking"))
        target = out if has_result else session_dir
        try:
            summary["stages"]["screenshot"] = {"path": str(render_result(target, out / "overview.png"))}
        except Exception as e:  # a rendering problem must not lose the results already written
            summary["stages"]["screenshot"] = {"error": f"{type(e).__name__}: {e}"}
    summary["seconds_total"] = time.perf_counter() - t0
    (out / "summary.json").write_text(json.dumps(summary, indent=2, default=str))
    return summary


def _session_complete(path: Path) -> bool:
    try:
        return bool(json.loads((path / "manifest.json").read_text()).get("complete"))
    except Exception:
        return False
