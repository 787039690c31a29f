"""Object meshes for the simulator: load, scale, recentre at the bounding-box centre.

YCB scans are not centred at their origin; the simulator's object frame is the mesh's
axis-aligned bounding-box centre (original axes kept), so poses ``T_world_object`` are meaningful
and a mesh written to a session (``assets/object.ply``) lies in that object frame.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vtrack.errors import InputError


class MeshNotWatertightWarning(UserWarning):
    """The object mesh has holes (repaired if possible); simulated sensing may miss its open parts."""


@dataclass
class ObjectMesh:
    """A triangle mesh in the object frame (m)."""

    vertices: np.ndarray  # (V, 3) float64
    faces: np.ndarray  # (F, 3) int32
    T_source_object: np.ndarray  # (4, 4) object frame in the source file's frame (scaled)
    source: Path | None = None

    @property
    def extents(self) -> np.ndarray:
        return self.vertices.max(0) - self.vertices.min(0)

    def write_ply(self, path: str | Path) -> Path:
        from vtrack.io.export import export_mesh

        return export_mesh(path, self.vertices, self.faces)


def load_object_mesh(path: str | Path, scale: float = 1.0) -> ObjectMesh:
    """Load a mesh (PLY/OBJ/STL, metres after ``scale``) and recentre it at its bounding-box centre.

    Warns:
        MeshNotWatertightWarning: the mesh has holes (filled when trimesh can; the message says which).

    Raises:
        InputError: missing/unreadable file, no triangles, non-finite vertices, or a size that is
            not plausible for an in-hand object (extent outside 5 mm .. 0.5 m).
    """
    import trimesh

    from vtrack.io.mesh import load_trimesh

    path = Path(path)
    m = load_trimesh(path, process=True, field="object.mesh")
    if len(m.faces) == 0:
        raise InputError("object mesh has no triangles", path=path, field="object.mesh")
    # Outward winding matters: the gel ray caster reads a back-face hit as "gel buried in the object".
    if m.is_watertight:
        if m.volume < 0:
            m.invert()
    else:
        # Holes are common in scans; try the cheap repairs first and say what was done, because a
        # leaky mesh gives rays that pass through the object (missing depth/contacts) in the simulator.
        trimesh.repair.fix_normals(m)
        trimesh.repair.fill_holes(m)
        if m.is_watertight:
            if m.volume < 0:
                m.invert()
            warnings.warn(
                f"{path}: object mesh was not watertight; holes were filled (repaired in memory)",
                MeshNotWatertightWarning,
                stacklevel=2,
            )
        else:
            n_open = int(len(trimesh.grouping.group_rows(m.edges_sorted, require_count=1)))
            warnings.warn(
                f"{path}: object mesh is not watertight ({n_open} open edges after hole filling); "
                "simulated depth and contacts may miss the object where it is open",
                MeshNotWatertightWarning,
                stacklevel=2,
            )
    v = np.asarray(m.vertices, dtype=np.float64) * float(scale)
    if not np.all(np.isfinite(v)):
        raise InputError("object mesh has non-finite vertices", path=path, field="object.mesh")
    centre = 0.5 * (v.min(0) + v.max(0))
    v = v - centre
    ext = float((v.max(0) - v.min(0)).max())
    if not 0.005 <= ext <= 0.5:
        raise InputError(
            "object size is implausible for an in-hand object (mesh must be in metres; use object.scale)",
            path=path,
            field="object.mesh",
            expected="extent 5 mm .. 0.5 m",
            got=f"{ext:.4g} m",
        )
    T = np.eye(4)
    T[:3, 3] = centre
    return ObjectMesh(v, np.asarray(m.faces, dtype=np.int32), T, path)
