"""Mesh files: the one reader of triangle meshes (PLY / OBJ / STL / OFF / GLB via trimesh); the writer is
:func:`vtrack.io.export.export_mesh`.

Everything that reads a mesh (evaluation ground truth, the viewer, the trackers' SDF grids, the simulator's
objects, synthetic observations) goes through :func:`load_mesh` / :func:`load_trimesh`, so a missing,
corrupt, empty or non-finite file gets the same one-line error everywhere. Units are whatever the file
holds (vtrack's files are metres); ``scale`` converts.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError


def load_trimesh(path: str | Path, *, process: bool = False, field: str | None = None) -> Any:
    """The file as one ``trimesh.Trimesh`` (scenes are concatenated).

    ``process=False`` keeps the file's vertices and order (needed when indices matter); ``process=True`` merges
    duplicate vertices (what watertightness checks need). Raises InputError (naming ``path`` and ``field``)
    for a missing or unreadable file or one that holds no triangle mesh; an empty mesh is returned as is.
    """
    import trimesh

    path = Path(path)
    if not path.is_file():
        raise InputError("mesh file does not exist", path=path, field=field)
    try:
        m = trimesh.load(str(path), force="mesh", process=process)
    except Exception as e:  # noqa: BLE001 - trimesh raises many types for corrupt files
        raise InputError(f"cannot read mesh ({type(e).__name__}: {e})", path=path, field=field) from None
    if not isinstance(m, trimesh.Trimesh):
        raise InputError("not a triangle mesh", path=path, field=field, got=type(m).__name__)
    return m


def load_mesh(
    path: str | Path, scale: float = 1.0, *, allow_empty: bool = False, field: str | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) float64 (file units x ``scale``) and faces (F, 3) int64 of a mesh file, as stored.

    Raises InputError for what :func:`load_trimesh` refuses, for non-finite vertices, for face indices out of
    range and (unless ``allow_empty``: then (0, 3) arrays) for a mesh without triangles.
    """
    m = load_trimesh(path, field=field)
    V = np.asarray(m.vertices, np.float64).reshape(-1, 3) * float(scale)
    F = np.asarray(m.faces, np.int64).reshape(-1, 3)
    if len(V) == 0 or len(F) == 0:
        if allow_empty:
            return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
        raise InputError("mesh has no triangles", path=path, field=field)
    if not np.isfinite(V).all():
        raise InputError("mesh has non-finite vertices", path=path, field=field)
    if F.min() < 0 or F.max() >= len(V):
        raise InputError("mesh face indices out of range", path=path, field=field)
    return V, F
