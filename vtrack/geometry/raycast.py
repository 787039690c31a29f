"""Thin wrapper over Open3D's ``RaycastingScene`` (imported lazily): the simulator's renderer and the
segmenter's exact hand silhouette."""

from __future__ import annotations

import numpy as np


class Raycaster:
    """Static triangle meshes (each gets a geometry id in insertion order) for batched ray casts."""

    def __init__(self, meshes: list[tuple[np.ndarray, np.ndarray]]) -> None:
        import open3d as o3d

        self._o3d = o3d
        self.scene = o3d.t.geometry.RaycastingScene()
        self.ids = []
        for v, f in meshes:
            mesh = o3d.t.geometry.TriangleMesh()
            mesh.vertex.positions = o3d.core.Tensor(np.ascontiguousarray(v, dtype=np.float32))
            mesh.triangle.indices = o3d.core.Tensor(np.ascontiguousarray(f, dtype=np.int32))
            self.ids.append(int(self.scene.add_triangles(mesh)))

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> dict[str, np.ndarray]:
        """Cast rays (..., 3) origins and directions (not necessarily unit; ``t`` is in their units).

        Returns ``t`` (inf = miss), ``geometry`` id (-1 = miss) and unit ``normal`` of the hit
        triangle (world of the meshes, orientation from the winding).
        """
        shape = origins.shape[:-1]
        rays = np.empty((int(np.prod(shape)), 6), dtype=np.float32)
        rays[:, :3] = origins.reshape(-1, 3)
        rays[:, 3:] = np.broadcast_to(directions, origins.shape).reshape(-1, 3)
        ans = self.scene.cast_rays(self._o3d.core.Tensor(rays))
        t = ans["t_hit"].numpy().astype(np.float64).reshape(shape)
        gid = ans["geometry_ids"].numpy().astype(np.int64)
        gid = np.where(gid == self._o3d.t.geometry.RaycastingScene.INVALID_ID, -1, gid).reshape(shape)
        n = ans["primitive_normals"].numpy().astype(np.float64).reshape(shape + (3,))
        return {"t": t, "geometry": gid, "normal": n}

    def hit_distance(self, origin: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """(N,) ray parameter of the first hit (inf = miss) of rays from one ``origin`` (3,) along
        ``directions`` (N, 3): the per-frame fast path (no normals, ids or reshapes)."""
        rays = np.empty((len(directions), 6), dtype=np.float32)
        rays[:, :3] = origin
        rays[:, 3:] = directions
        # from_numpy shares ``rays`` (alive until the call returns) instead of copying it: ~10 us of the ~50 us
        # a small cast costs (the segmenter casts once per hand link per frame)
        return self.scene.cast_rays(self._o3d.core.Tensor.from_numpy(rays))["t_hit"].numpy().astype(np.float64)

    def closest(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Closest surface points (..., 3) and the unit normals of their triangles (winding-oriented)."""
        shape = points.shape
        q = self._o3d.core.Tensor(np.ascontiguousarray(points.reshape(-1, 3), dtype=np.float32))
        ans = self.scene.compute_closest_points(q)
        p = ans["points"].numpy().astype(np.float64).reshape(shape)
        n = ans["primitive_normals"].numpy().astype(np.float64).reshape(shape)
        return p, n
