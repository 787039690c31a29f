"""TSDF reconstruction with Open3D's tensor ``VoxelBlockGrid`` (CPU), in the OBJECT frame.

Never imports torch. Vision: each masked depth image is integrated with the extrinsic
``T_camera_object`` (so the object can move: the known object pose is folded into the extrinsic).
Touch as near-surface evidence: around each contact point the voxels of a narrow band get the
point-to-plane signed distance along the contact normal, written straight into the grid's voxel
blocks with weight ``touch_weight`` (a projective depth image would be ill-posed for a 1 cm patch),
so touch counts as high-confidence surface that vision cannot erase. Mesh by Open3D marching cubes.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from vtrack.fusion.cloud import TOUCH
from vtrack.geometry import se3


@dataclass
class TSDFConfig:
    """Options of :class:`TSDFReconstructor` and their defaults (the one place they are set).

    voxel_size: m (default 2 mm). block_resolution: voxels per block edge. block_count: initial hash-map
    capacity (grows as needed). trunc_voxels: vision truncation in voxels (``trunc_voxel_multiplier``).
    touch_trunc_voxels: truncation for touch splats (narrow: touch is exact). touch_weight: TSDF weight of
    one touch frame (one camera frame weighs 1 per voxel). depth_max: m, beyond which depth is ignored.
    max_patch_m: touch points farther than this from their frame's median point are outliers.
    weight_threshold: min weight for meshing.
    """

    voxel_size: float = 0.002
    block_resolution: int = 8
    block_count: int = 20000
    trunc_voxels: float = 4.0
    touch_trunc_voxels: float = 2.0
    touch_weight: float = 3.0
    depth_max: float = 3.0
    max_patch_m: float = 0.05
    weight_threshold: float = 1.0


class TSDFReconstructor:
    """Tensor TSDF (``o3d.t.geometry.VoxelBlockGrid``) fed with object-frame observations.

    Args:
        config: options (:class:`TSDFConfig`); ``opts`` override single fields of it by name
            (``TSDFReconstructor(voxel_size=0.004)``); an unknown name raises :class:`InputError`.
    """

    def __init__(self, config: TSDFConfig | None = None, **opts: Any) -> None:
        import open3d as o3d

        from vtrack.config import build_config

        self.config = c = build_config(TSDFConfig, opts, "TSDF", base=config)
        self.o3d = o3d
        self.voxel_size = float(c.voxel_size)
        self.trunc_voxels = float(c.trunc_voxels)
        self.touch_trunc_voxels = float(c.touch_trunc_voxels)
        self.touch_weight = float(c.touch_weight)
        self.block_resolution = int(c.block_resolution)
        self.max_patch_m = float(c.max_patch_m)
        self.depth_max = float(c.depth_max)
        self.weight_threshold = float(c.weight_threshold)
        self.device = o3d.core.Device("CPU:0")
        self.vbg = o3d.t.geometry.VoxelBlockGrid(
            attr_names=("tsdf", "weight"),
            attr_dtypes=(o3d.core.float32, o3d.core.float32),
            attr_channels=((1,), (1,)),
            voxel_size=self.voxel_size,
            block_resolution=int(c.block_resolution),
            block_count=int(c.block_count),
            device=self.device,
        )
        self.frames = {"vision": 0, "touch": 0, "skipped": 0}
        self.seconds = 0.0

    @classmethod
    def from_scene(cls, scene: Any = None, **opts: Any) -> TSDFReconstructor:
        """Registry entry point (``reconstruction.tsdf``)."""
        return cls(**opts)

    # -- integration -------------------------------------------------------------------------
    def integrate_depth(
        self, depth_m: np.ndarray, K: np.ndarray, T_camera_object: np.ndarray, trunc_voxels: float | None = None
    ) -> bool:
        """Integrate one float depth image (m, 0/NaN = invalid) seen from ``T_camera_object``.

        Returns False (and does nothing) for an image without valid depth or a non-finite pose.
        """
        o3d = self.o3d
        d = np.asarray(depth_m, np.float32)
        d = np.where(np.isfinite(d) & (d > 0) & (d < self.depth_max), d, 0.0).astype(np.float32)
        T = np.asarray(T_camera_object, np.float64)
        if not d.any() or not np.all(np.isfinite(T)) or not np.all(np.isfinite(K)):
            self.frames["skipped"] += 1
            return False
        t0 = time.perf_counter()
        depth = o3d.t.geometry.Image(o3d.core.Tensor(np.ascontiguousarray(d)))
        intr = o3d.core.Tensor(np.asarray(K, np.float64))
        extr = o3d.core.Tensor(T)
        tv = self.trunc_voxels if trunc_voxels is None else trunc_voxels
        try:
            coords = self.vbg.compute_unique_block_coordinates(depth, intr, extr, 1.0, self.depth_max, tv)
            self.vbg.integrate(coords, depth, intr, extr, 1.0, self.depth_max, tv)
        except RuntimeError:
            # Open3D aborts when no voxel block is touched (e.g. a few pixels far from any block).
            self.frames["skipped"] += 1
            return False
        self.seconds += time.perf_counter() - t0
        return True

    def integrate_points(
        self, points_obj: np.ndarray, normals_obj: np.ndarray | None = None, T_view_object: np.ndarray | None = None
    ) -> bool:
        """Touch: write near-surface TSDF evidence around object-frame contact points.

        Voxels within ``touch_trunc_voxels`` of a contact point (and within 1.5 voxels of it
        laterally, so the patch is not extrapolated) get the point-to-plane signed distance
        ``(x - p) . n`` (outward normal ``n``), blended with weight ``touch_weight``. Without normals,
        the direction from the sensor (``T_view_object``) is used: the sensor sits outside the object.
        """
        from scipy.spatial import cKDTree

        o3d = self.o3d
        P = np.asarray(points_obj, np.float64).reshape(-1, 3)
        N = None if normals_obj is None else np.asarray(normals_obj, np.float64).reshape(-1, 3)
        if N is None or len(N) != len(P) or not np.isfinite(N).all() or np.any(np.linalg.norm(N, axis=1) < 0.5):
            if T_view_object is None or not np.all(np.isfinite(T_view_object)):
                self.frames["skipped"] += 1
                return False
            # outward normal ~ towards the sensor origin
            org = se3.invert(np.asarray(T_view_object, np.float64))[:3, 3]
            N = org - P
        ok = np.isfinite(P).all(1) & np.isfinite(N).all(1)
        if ok.any():
            # One tactile frame is one fingertip patch: points far from its median are outliers.
            ok &= np.linalg.norm(P - np.median(P[ok], axis=0), axis=1) < self.max_patch_m
        P, N = P[ok], N[ok]
        N = N / np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-12)
        if len(P) == 0:
            self.frames["skipped"] += 1
            return False
        t0 = time.perf_counter()
        vs = self.voxel_size
        trunc = self.touch_trunc_voxels * vs
        bs = vs * self.block_resolution
        lo = np.floor((P.min(0) - trunc - vs) / bs).astype(np.int64)
        hi = np.floor((P.max(0) + trunc + vs) / bs).astype(np.int64)
        if np.prod((hi - lo + 1).astype(np.float64)) > 4096:  # not a contact patch: refuse
            self.frames["skipped"] += 1
            return False
        g = np.stack(np.meshgrid(*[np.arange(lo[i], hi[i] + 1) for i in range(3)], indexing="ij"), -1)
        coords = o3d.core.Tensor(g.reshape(-1, 3).astype(np.int32))
        hm = self.vbg.hashmap()
        buf, new = hm.activate(coords)
        buf_np, new_np = buf.numpy().astype(np.int64), new.numpy().astype(bool)
        tsdf = self.vbg.attribute("tsdf").numpy().reshape(-1)  # shares memory with the grid
        wgt = self.vbg.attribute("weight").numpy().reshape(-1)
        if new_np.any():
            _, nidx = self.vbg.voxel_coordinates_and_flattened_indices(o3d.core.Tensor(buf_np[new_np].astype(np.int32)))
            nidx = nidx.numpy().reshape(-1)
            tsdf[nidx] = 1.0
            wgt[nidx] = 0.0
        found, _ = hm.find(coords)
        xyz, idx = self.vbg.voxel_coordinates_and_flattened_indices(found)
        X, I = xyz.numpy().astype(np.float64), idx.numpy().reshape(-1)
        d, j = cKDTree(P).query(X, distance_upper_bound=trunc + 1e-9)
        near = np.isfinite(d)
        X, I, j = X[near], I[near], j[near]
        sd = np.einsum("ij,ij->i", X - P[j], N[j])
        lateral2 = np.maximum(np.sum((X - P[j]) ** 2, axis=1) - sd**2, 0.0)
        use = lateral2 <= (1.5 * vs) ** 2
        I, sd = I[use], sd[use]
        if len(I) == 0:
            self.frames["skipped"] += 1
            return False
        val = np.clip(sd / trunc, -1.0, 1.0).astype(np.float32)
        w0 = wgt[I]
        wt = float(self.touch_weight)
        tsdf[I] = (tsdf[I] * w0 + val * wt) / (w0 + wt)
        wgt[I] = w0 + wt
        self.seconds += time.perf_counter() - t0
        return True

    def integrate_observation(self, obs: Any) -> bool:
        """Add a :class:`vtrack.fusion.observations.Observation` (vision depth or touch points)."""
        if obs.modality == TOUCH:
            ok = self.integrate_points(obs.points, obs.normals, obs.T_view_object)
            self.frames["touch"] += int(ok)
            return ok
        if obs.depth_m is None or obs.K is None:
            self.frames["skipped"] += 1
            return False
        ok = self.integrate_depth(obs.depth_m, obs.K, obs.T_view_object)
        self.frames["vision"] += int(ok)
        return ok

    def fit(self, observations: list) -> dict[str, Any]:
        t0 = time.perf_counter()
        for o in observations:
            self.integrate_observation(o)
        return {"seconds": time.perf_counter() - t0, **self.frames}

    # -- output ------------------------------------------------------------------------------
    def extract_mesh(self) -> tuple[np.ndarray, np.ndarray]:
        """Marching-cubes mesh in the object frame: vertices (V, 3) m, faces (F, 3); empty if no data."""
        if self.vbg.hashmap().size() == 0:
            return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
        try:
            m = self.vbg.extract_triangle_mesh(weight_threshold=self.weight_threshold)
        except RuntimeError:
            return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
        V = m.vertex.positions.numpy().astype(np.float64) if "positions" in m.vertex else np.zeros((0, 3))
        F = m.triangle.indices.numpy().astype(np.int64) if "indices" in m.triangle else np.zeros((0, 3), np.int64)
        ok = np.isfinite(V).all(1)
        if not ok.all():
            keep_f = ok[F].all(1)
            F = F[keep_f]
        return V, F

    def extract_points(self) -> np.ndarray:
        """Surface points (N, 3) of the TSDF zero crossing, object frame."""
        if self.vbg.hashmap().size() == 0:
            return np.zeros((0, 3))
        pc = self.vbg.extract_point_cloud(weight_threshold=self.weight_threshold)
        return pc.point.positions.numpy().astype(np.float64) if "positions" in pc.point else np.zeros((0, 3))
