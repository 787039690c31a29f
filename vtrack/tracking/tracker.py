"""Known-shape tracking: the window tracker against a precomputed SDF grid of the object mesh.

``KnownShapeTracker.from_scene(scene)`` reads ``scene.object.mesh`` (object frame, scaled by
``scene.object.scale``) and starts from ``scene.object.T_world_object`` unless ``T_init`` is
given (session runs pass the first ground-truth pose, see :mod:`vtrack.tracking.run`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError
from vtrack.tracking.sdf_grid import SDFGrid
from vtrack.tracking.window import TrackerOptions, WindowTracker


class KnownShapeTracker(WindowTracker):
    """Per-frame ``step(frame) -> T_world_object`` with the object's SDF known from its mesh.

    Args:
        mesh: mesh file (object frame) or a ready :class:`SDFGrid`.
        T_init: initial ``T_world_object``.
        voxel: SDF grid spacing, m.
        scale: mesh units -> m.
        **opts: :class:`~vtrack.tracking.window.TrackerOptions` overrides.
    """

    mode = "known_shape"

    def __init__(
        self, mesh: str | Path | SDFGrid, T_init: np.ndarray, voxel: float = 0.002, scale: float = 1.0, **opts: Any
    ) -> None:
        grid = mesh if isinstance(mesh, SDFGrid) else SDFGrid.from_mesh(mesh, voxel=voxel, scale=scale)
        if "object_radius" not in opts:
            lo, hi = grid.bounds
            # grid bounds include padding; half the diagonal of the unpadded box is close enough
            opts["object_radius"] = max(0.01, 0.5 * float(np.linalg.norm(hi - lo)) * 0.6)
        super().__init__(grid, T_init, TrackerOptions.from_dict(opts))
        self.grid = grid

    @classmethod
    def from_scene(
        cls, scene: Any, T_init: np.ndarray | None = None, mesh: str | Path | None = None, **opts: Any
    ) -> KnownShapeTracker:
        """Build from a scene with ``object.mesh`` (or an explicit ``mesh`` path, e.g. a session asset)."""
        path = mesh if mesh is not None else scene.object.mesh
        if path is None:
            raise InputError(
                "known-shape tracking needs the object mesh",
                path=getattr(scene, "source", None),
                field="object.mesh",
                expected="a mesh file",
            )
        if T_init is None and scene.object.T_world_object is None:
            raise InputError(
                "known-shape tracking needs an initial pose (the scene gives none)",
                path=getattr(scene, "source", None),
                field="object.T_world_object",
                expected="a pose prior, or use vtrack.tracking.run (global registration)",
            )
        T0 = scene.object.T_world_object.as_matrix() if T_init is None else T_init
        return cls(path, T0, scale=float(scene.object.scale) if mesh is None else 1.0, **opts)
