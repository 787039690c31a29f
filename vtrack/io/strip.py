"""``strip_gt``: copy a session without any ground truth, as a user's real recording would be.

What a real recording has: RGB, depth, tactile images, joint states, calibration files and the scene
(hand, sensors, cameras). What it does not have, and what this removes:

- every ``gt/*`` stream (object poses, tactile height maps and contact masks, camera masks, visibility)
  and the ``SESSION/gt/`` folder (the object mesh);
- legacy ground truth outside ``gt/`` (sessions written before format 2): the ``mask`` field of camera
  streams and ``assets`` whose role is ``object_mesh``;
- the embedded scene's object mesh and pose (``object.mesh``, ``object.T_world_object`` -> unknown;
  ``pipeline.tracking: known_shape`` -> ``slam`` since the shape is no longer given);
- the simulator's creation info (seed, trajectory, contact phases, mesh source).

The pipeline never reads any of it (tests check that estimates on a session and on its stripped copy are
identical), so stripping is how a result is shown to be obtained blind.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

from vtrack.errors import InputError
from vtrack.io.jsonio import write_json

#: Creation-info keys that describe the recording itself (kept); everything else is dropped.
_KEEP_CREATED = ("time_unix", "host", "vtrack_version", "platform", "python")
#: Per-stream fields that are ground truth even outside ``gt/`` (legacy layout).
_LEGACY_GT_FIELDS = {"rgbd": ("mask",)}


def is_gt_stream(name: str) -> bool:
    """True for ground-truth streams (``gt/...``)."""
    return name == "gt" or name.startswith("gt/")


def strip_gt(src: str | Path, dst: str | Path, *, overwrite: bool = False) -> dict[str, Any]:
    """Write a copy of session ``src`` at ``dst`` with all ground truth removed.

    Args:
        src: session folder (``vtrack.io.session`` format).
        dst: new folder; must not exist unless ``overwrite`` and it is a vtrack session.
        overwrite: replace an existing session folder at ``dst`` (never any other folder).

    Returns:
        a report: ``removed_streams``, ``removed_fields``, ``removed_files``, ``scene_changes``.

    Raises:
        InputError: ``src`` is not a session, ``dst`` exists (and is not a replaceable session) or is
            inside ``src``.
    """
    from vtrack.io.session import DATA, MANIFEST, check_replaceable, open_session

    reader = open_session(src)  # validates the source
    src = Path(reader.path).resolve()
    dst = Path(dst).resolve()
    if dst == src or src in dst.parents:
        raise InputError(
            "the stripped copy cannot be written inside the source session",
            path=dst,
            field="--out",
            expected="a folder outside the session",
        )
    if dst.exists() or dst.is_symlink():
        if not overwrite:
            raise InputError("output folder exists (pass --force to replace a session folder)", path=dst)
        check_replaceable(dst)  # the same rule as SessionWriter: never delete a user's files
        shutil.rmtree(dst)
    manifest = json.loads((src / MANIFEST).read_text())
    streams: dict[str, Any] = manifest.get("streams", {})
    removed_streams = sorted(k for k in streams if is_gt_stream(k))
    removed_fields: list[str] = []
    removed_files: list[str] = []

    def ignore(folder: str, names: list[str]) -> set[str]:
        rel = Path(folder).resolve().relative_to(src)
        drop = set()
        if rel == Path("."):
            drop |= {n for n in names if n == "gt"}
        if rel == Path(DATA):
            drop |= {n for n in names if n == "gt"}
        # legacy GT fields stored inside sensor streams, e.g. data.zarr/camera/cam0/mask
        if len(rel.parts) >= 2 and rel.parts[0] == DATA:
            stream = "/".join(rel.parts[1:])
            meta = streams.get(stream)
            if meta is not None:
                for f in _LEGACY_GT_FIELDS.get(meta.get("kind", ""), ()):
                    if f in names:
                        drop.add(f)
        return drop

    shutil.copytree(src, dst, ignore=ignore)
    for k in removed_streams:
        streams.pop(k)
        manifest.get("counts", {}).pop(k, None)
    for k, meta in streams.items():
        for f in _LEGACY_GT_FIELDS.get(meta.get("kind", ""), ()):
            if f in meta.get("fields", {}):
                meta["fields"].pop(f)
                removed_fields.append(f"{k}/{f}")
    for name, a in list(manifest.get("assets", {}).items()):
        if a.get("role") == "object_mesh":
            (dst / "assets" / name).unlink(missing_ok=True)
            manifest["assets"].pop(name)
            removed_files.append(f"assets/{name}")
    removed_files += [str(Path(n)) for n in manifest.pop("gt_files", {})]
    scene_changes: list[str] = []
    scene = manifest.get("scene")
    if isinstance(scene, dict):
        obj = scene.setdefault("object", {})
        for key in ("mesh", "T_world_object"):
            if obj.get(key) is not None:
                obj[key] = None
                scene_changes.append(f"object.{key} -> unknown")
        pipe = scene.get("pipeline") or {}
        if pipe.get("tracking") == "known_shape":
            pipe["tracking"] = "slam"
            scene_changes.append("pipeline.tracking known_shape -> slam")
    created = manifest.get("created", {})
    manifest["created"] = {k: v for k, v in created.items() if k in _KEEP_CREATED}
    manifest["created"]["stripped_from"] = str(src)
    report = {
        "removed_streams": removed_streams,
        "removed_fields": removed_fields,
        "removed_files": removed_files,
        "scene_changes": scene_changes,
    }
    manifest["stripped"] = report
    write_json(dst / MANIFEST, manifest, indent=1, fsync=True)
    open_session(dst)  # the copy must be a valid session
    return report
