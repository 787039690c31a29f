"""Unified visuo-tactile point cloud (3D-ViTac style), numpy only.

One structure holds every point of both modalities:

- ``xyz`` (N, 3) float64, metres, in ``frame`` (``"world"`` from the builders; ``"object"`` after
  :meth:`UnifiedCloud.transform_per_point`);
- ``normal`` (N, 3) unit outward surface normal (zero when unknown);
- ``modality`` (N,) int8: 0 = vision, 1 = touch (:data:`VISION`, :data:`TOUCH`);
- ``sensor_id`` (N,) int32: index of the camera / tactile sensor (see ``sensor_names``);
- ``t`` (N,) float64 timestamp, s;
- ``confidence`` (N,) float32 in [0, 1];
- ``tactile_value`` (N,) float32: gel penetration in mm for touch points (0 for vision).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vtrack.errors import InputError
from vtrack.geometry.camera import PinholeCamera

VISION = 0
TOUCH = 1
MODALITY_NAMES = {"vision": VISION, "touch": TOUCH}

_FIELDS = ("xyz", "normal", "modality", "sensor_id", "t", "confidence", "tactile_value")


@dataclass
class UnifiedCloud:
    """Vision + touch points with per-point metadata (see module docstring for units)."""

    xyz: np.ndarray
    normal: np.ndarray
    modality: np.ndarray
    sensor_id: np.ndarray
    t: np.ndarray
    confidence: np.ndarray
    tactile_value: np.ndarray
    frame: str = "world"
    sensor_names: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.xyz = np.asarray(self.xyz, np.float64).reshape(-1, 3)
        n = len(self.xyz)
        self.normal = np.asarray(self.normal, np.float64).reshape(n, 3)
        self.modality = np.asarray(self.modality, np.int8).reshape(n)
        self.sensor_id = np.asarray(self.sensor_id, np.int32).reshape(n)
        self.t = np.asarray(self.t, np.float64).reshape(n)
        self.confidence = np.asarray(self.confidence, np.float32).reshape(n)
        self.tactile_value = np.asarray(self.tactile_value, np.float32).reshape(n)

    # -- construction ------------------------------------------------------------------------
    @classmethod
    def empty(cls, frame: str = "world") -> UnifiedCloud:
        return cls(np.zeros((0, 3)), np.zeros((0, 3)), [], [], [], [], [], frame=frame)

    @classmethod
    def concat(cls, clouds: list[UnifiedCloud]) -> UnifiedCloud:
        """Stack clouds (all in the same frame)."""
        clouds = [c for c in clouds if c is not None]
        if not clouds:
            return cls.empty()
        frames = {c.frame for c in clouds}
        if len(frames) > 1:
            raise InputError(
                "cannot concatenate clouds in different frames", field="frame", expected="one frame", got=sorted(frames)
            )
        names = max((c.sensor_names for c in clouds), key=len)
        return cls(
            *(np.concatenate([getattr(c, f) for c in clouds]) for f in _FIELDS),
            frame=clouds[0].frame,
            sensor_names=list(names),
        )

    def __len__(self) -> int:
        return len(self.xyz)

    def select(self, mask: np.ndarray) -> UnifiedCloud:
        """Subset by boolean mask or index array."""
        return UnifiedCloud(
            *(getattr(self, f)[mask] for f in _FIELDS), frame=self.frame, sensor_names=list(self.sensor_names)
        )

    def of_modality(self, modality: int | str) -> UnifiedCloud:
        m = MODALITY_NAMES[modality] if isinstance(modality, str) else int(modality)
        return self.select(self.modality == m)

    def counts(self) -> dict[str, int]:
        return {name: int(np.sum(self.modality == m)) for name, m in MODALITY_NAMES.items()}

    # -- frames ------------------------------------------------------------------------------
    def transform(self, T: np.ndarray, frame: str | None = None) -> UnifiedCloud:
        """Apply one 4x4 transform to points and normals."""
        T = np.asarray(T, np.float64)
        out = self.select(slice(None))
        out.xyz = self.xyz @ T[:3, :3].T + T[:3, 3]
        out.normal = self.normal @ T[:3, :3].T
        out.frame = frame or self.frame
        return out

    def transform_per_point(self, T: np.ndarray, frame: str) -> UnifiedCloud:
        """Apply a (N, 4, 4) transform per point (e.g. ``T_object_world`` at each point's time)."""
        T = np.asarray(T, np.float64).reshape(len(self), 4, 4)
        out = self.select(slice(None))
        out.xyz = np.einsum("nij,nj->ni", T[:, :3, :3], self.xyz) + T[:, :3, 3]
        out.normal = np.einsum("nij,nj->ni", T[:, :3, :3], self.normal)
        out.frame = frame
        return out

    # -- downsampling ------------------------------------------------------------------------
    def voxel_downsample(self, voxel_size: float, touch_voxel_size: float | None = None) -> UnifiedCloud:
        """Average points per voxel, never merging across modality (or sensor).

        Touch is usually much denser (0.1 mm pixels) but far smaller in extent than vision; a
        separate ``touch_voxel_size`` (default ``voxel_size / 2``) keeps its detail so that touch is
        not drowned after downsampling. Normals are re-normalised; ids take the first point's value.
        """
        from vtrack.geometry.pointcloud import voxel_downsample

        tv = voxel_size / 2.0 if touch_voxel_size is None else touch_voxel_size
        parts = []
        for m, vs in ((VISION, voxel_size), (TOUCH, tv)):
            sub = self.select(self.modality == m)
            if len(sub) == 0:
                continue
            group = sub.sensor_id.astype(np.int64)
            xyz, nrm, mod, sid, t, conf, tv_ = voxel_downsample(
                sub.xyz,
                vs,
                sub.normal,
                sub.modality,
                sub.sensor_id,
                sub.t,
                sub.confidence,
                sub.tactile_value,
                group=group,
            )
            ln = np.linalg.norm(nrm, axis=1, keepdims=True)
            nrm = np.where(ln > 1e-9, nrm / np.maximum(ln, 1e-12), 0.0)
            parts.append(
                UnifiedCloud(xyz, nrm, mod, sid, t, conf, tv_, frame=self.frame, sensor_names=list(self.sensor_names))
            )
        return UnifiedCloud.concat(parts) if parts else UnifiedCloud.empty(self.frame)

    def balance_weights(self) -> np.ndarray:
        """(N,) per-point weights giving each present modality the same total weight (mean 1)."""
        w = np.zeros(len(self), np.float64)
        present = [m for m in (VISION, TOUCH) if np.any(self.modality == m)]
        for m in present:
            sel = self.modality == m
            w[sel] = len(self) / (len(present) * sel.sum())
        return w

    # -- export ------------------------------------------------------------------------------
    def to_ply(self, path: str | Path) -> Path:
        """Binary PLY with normals and scalar fields modality, sensor_id, t, confidence, tactile_value."""
        from vtrack.io.export import write_ply_points

        colors = np.where(self.modality[:, None] == TOUCH, [[230, 60, 40]], [[60, 120, 220]]).astype(np.uint8)
        return write_ply_points(
            path,
            self.xyz,
            normals=self.normal,
            colors=colors,
            scalars={
                "modality": self.modality.astype(np.int32),
                "sensor_id": self.sensor_id.astype(np.int32),
                "t": self.t.astype(np.float64),
                "confidence": self.confidence.astype(np.float32),
                "tactile_value": self.tactile_value.astype(np.float32),
            },
        )


# -- builders -----------------------------------------------------------------------------------
def depth_normals(points_img: np.ndarray, valid: np.ndarray, max_jump: float = 0.01) -> np.ndarray:
    """Normals (H, W, 3) of an organised point image (camera frame) by central differences.

    Pixels whose neighbours are invalid or across a depth jump larger than ``max_jump`` metres get
    a zero normal. Normals face the camera (negative z component in the camera frame).
    """
    P = points_img
    H, W = valid.shape
    n = np.zeros((H, W, 3))
    if H < 3 or W < 3:
        return n
    dx = P[1:-1, 2:] - P[1:-1, :-2]
    dy = P[2:, 1:-1] - P[:-2, 1:-1]
    ok = valid[1:-1, 2:] & valid[1:-1, :-2] & valid[2:, 1:-1] & valid[:-2, 1:-1] & valid[1:-1, 1:-1]
    ok &= (np.abs(dx[..., 2]) < max_jump) & (np.abs(dy[..., 2]) < max_jump)
    c = np.cross(dx, dy)
    ln = np.linalg.norm(c, axis=-1, keepdims=True)
    ok &= ln[..., 0] > 1e-12
    c = np.where(ok[..., None], c / np.maximum(ln, 1e-12), 0.0)
    # Orient towards the camera: normal . (0 - p) > 0.
    flip = np.einsum("hwi,hwi->hw", c, P[1:-1, 1:-1]) > 0
    c[flip] *= -1.0
    n[1:-1, 1:-1] = c
    return n


def from_rgbd(
    depth: np.ndarray,
    camera: PinholeCamera,
    T_world_camera: np.ndarray,
    *,
    mask: np.ndarray | None = None,
    t: float = 0.0,
    sensor_id: int = 0,
    depth_scale: float = 0.001,
    stride: int = 1,
    min_depth: float = 0.05,
    max_depth: float = 3.0,
    sensor_names: list[str] | None = None,
) -> UnifiedCloud:
    """Masked unprojection of one RGB-D frame to a world-frame cloud.

    Args:
        depth: (H, W) uint16 (``depth_scale`` m per unit) or float metres; 0/NaN/Inf are invalid.
        camera: intrinsics; ``T_world_camera``: 4x4 extrinsics (OpenCV camera frame).
        mask: optional (H, W) object segmentation (non-zero = object).
        stride: keep every ``stride``-th pixel in both directions (normals use full resolution).

    Confidence is ``|cos|`` of the angle between the viewing ray and the normal (grazing
    measurements are the noisiest); points without a normal get confidence 0.25.
    """
    z, valid = camera.valid_depth(depth, mask, depth_scale, min_depth, max_depth)
    if not valid.any():
        out = UnifiedCloud.empty()
        out.sensor_names = list(sensor_names or [])
        return out
    # Work on the bounding box of valid pixels (+1 px for the normals' central differences): the
    # object usually covers a small part of the image.
    rr, cc = np.nonzero(valid.any(1))[0], np.nonzero(valid.any(0))[0]
    r0, r1 = max(rr[0] - 1, 0), min(rr[-1] + 2, valid.shape[0])
    c0, c1 = max(cc[0] - 1, 0), min(cc[-1] + 2, valid.shape[1])
    vz = valid[r0:r1, c0:c1]
    zz = np.where(vz, z[r0:r1, c0:c1], 0.0)
    u, v = np.meshgrid(np.arange(c0, c1, dtype=np.float64), np.arange(r0, r1, dtype=np.float64))
    rays = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones_like(u)], axis=-1)
    P = rays * zz[..., None]
    N = depth_normals(P, vz)
    keep = vz.copy()
    if stride > 1:
        sub = np.zeros_like(keep)
        sub[(-r0) % stride :: stride, (-c0) % stride :: stride] = True  # same pixel lattice as the full image
        keep &= sub
    rows, cols = np.nonzero(keep)
    pts, nrm = P[rows, cols], N[rows, cols]
    ray = rays[rows, cols]
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    cosang = np.abs(np.einsum("ij,ij->i", ray, nrm))
    conf = np.where(np.linalg.norm(nrm, axis=1) > 0, cosang, 0.25)
    n = len(pts)
    cloud = UnifiedCloud(
        pts,
        nrm,
        np.full(n, VISION),
        np.full(n, sensor_id),
        np.full(n, t),
        conf,
        np.zeros(n),
        frame="camera",
        sensor_names=list(sensor_names or []),
    )
    return cloud.transform(T_world_camera, frame="world")


def from_contact_points(
    points_sensor: np.ndarray,
    normals_sensor: np.ndarray,
    T_world_sensor: np.ndarray,
    *,
    t: float = 0.0,
    sensor_id: int = 0,
    confidence: np.ndarray | float = 1.0,
    tactile_value: np.ndarray | float = 0.0,
    sensor_names: list[str] | None = None,
) -> UnifiedCloud:
    """Touch points given in a tactile sensor frame (e.g. from the tactile pipeline) -> world cloud.

    Normals in the sensor frame point out of the gel, i.e. *into* the touched object; the cloud stores
    outward object normals, so they are negated here.
    """
    P = np.asarray(points_sensor, np.float64).reshape(-1, 3)
    Nn = -np.asarray(normals_sensor, np.float64).reshape(-1, 3)
    ok = np.isfinite(P).all(1) & np.isfinite(Nn).all(1)
    P, Nn = P[ok], Nn[ok]
    n = len(P)
    conf = (
        np.broadcast_to(np.asarray(confidence, np.float32), ok.shape)[ok]
        if np.ndim(confidence)
        else np.full(n, confidence)
    )
    tv = (
        np.broadcast_to(np.asarray(tactile_value, np.float32), ok.shape)[ok]
        if np.ndim(tactile_value)
        else np.full(n, tactile_value)
    )
    cloud = UnifiedCloud(
        P,
        Nn,
        np.full(n, TOUCH),
        np.full(n, sensor_id),
        np.full(n, t),
        conf,
        tv,
        frame="sensor",
        sensor_names=list(sensor_names or []),
    )
    return cloud.transform(T_world_sensor, frame="world")


def from_tactile(
    height_mm: np.ndarray,
    contact: np.ndarray | None,
    mm_per_px: float,
    T_world_sensor: np.ndarray,
    *,
    t: float = 0.0,
    sensor_id: int = 0,
    stride: int = 2,
    contact_threshold_mm: float = 0.05,
    contact_probability: np.ndarray | None = None,
    sensor_names: list[str] | None = None,
) -> UnifiedCloud:
    """Contact points of one tactile height map (mm, into the gel) -> world-frame touch cloud.

    Contact pixels are ``contact`` (if given) and height above ``contact_threshold_mm``. The
    tactile value is the penetration (mm); confidence is the contact probability (1 if not given).
    """
    from vtrack.geometry.tactile_frame import height_to_points

    h = np.asarray(height_mm, np.float64)
    if h.ndim != 2:
        raise InputError("height map must be 2-D", field="height_mm", expected="(H, W)", got=h.shape)
    with np.errstate(invalid="ignore"):
        m = np.isfinite(h) & (h > contact_threshold_mm)
    if contact is not None:
        m &= np.asarray(contact).astype(bool)
    if stride > 1:
        sub = np.zeros_like(m)
        sub[::stride, ::stride] = True
        m &= sub
    if not m.any():
        out = UnifiedCloud.empty()
        out.sensor_names = list(sensor_names or [])
        return out
    pts, nrm = height_to_points(h, mm_per_px, mask=m)
    rows, cols = np.nonzero(m)
    conf = 1.0 if contact_probability is None else np.asarray(contact_probability, np.float32)[rows, cols]
    return from_contact_points(
        pts,
        nrm,
        T_world_sensor,
        t=t,
        sensor_id=sensor_id,
        confidence=conf,
        tactile_value=h[rows, cols].astype(np.float32),
        sensor_names=sensor_names,
    )
