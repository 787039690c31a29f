"""Frames of a session -> time-ordered observations in the OBJECT frame, given object poses.

Built on the frames layer (:mod:`vtrack.frames`): each camera frame's segmentation (no ground truth) and
each tactile sensor's contacts from its images through the calibrated tactile pipeline, at the frames'
time base. The object poses come from the caller (:class:`~vtrack.io.poses.PoseTrack`: the tracker's
estimate, a ``poses.csv``, or - as a labelled oracle - the ground truth):

- vision: depth unprojected under the frame's object mask (full-resolution normals and confidences from
  :func:`~vtrack.fusion.cloud.from_rgbd`), camera extrinsics ``T_world_camera``, then ``T_object_world``;
  the masked depth image itself is kept for TSDF integration;
- touch: the contact points of each sensor (sensor frame), placed in the world by forward kinematics
  (``T_world_sensor`` at the frame time), then ``T_object_world``; the tactile value is the penetration (mm).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError
from vtrack.fusion.cloud import TOUCH, VISION, UnifiedCloud, from_contact_points, from_rgbd
from vtrack.geometry import se3


@dataclass
class Observation:
    """One frame of surface evidence in the object frame (metres).

    Attributes:
        t: timestamp, s. modality: 0 vision / 1 touch. sensor_id / sensor: camera or tactile sensor.
        points, normals: (N, 3) object-frame surface points and outward unit normals (0 = unknown).
        confidence: (N,) in [0, 1]. tactile_value: (N,) penetration mm (touch) or 0.
        T_view_object: 4x4 camera (or tactile sensor) frame from the object frame.
        depth_m, K: vision only, masked float32 depth (m, 0 = invalid) and 3x3 intrinsics (TSDF input).
        free_depth: vision only, free-space evidence of every pixel (float32 (H / s, W / s), camera z, m): the ray
            is empty up to that depth (measured depth of any surface, object or not; ``inf`` where the sensor got
            no return and the pixel is clear of the object mask; 0 = unknown), min-pooled over ``s x s``
            blocks (``free_stride``) so the subsampled image never claims more than the full one.
    """

    t: float
    modality: int
    sensor_id: int
    sensor: str
    points: np.ndarray
    normals: np.ndarray
    confidence: np.ndarray
    tactile_value: np.ndarray
    T_view_object: np.ndarray
    depth_m: np.ndarray | None = None
    K: np.ndarray | None = None
    free_depth: np.ndarray | None = None
    free_stride: int = 1

    @property
    def origin(self) -> np.ndarray:
        """Viewpoint (camera centre / sensor origin) in the object frame, m."""
        return se3.invert(self.T_view_object)[:3, 3]

    def __len__(self) -> int:
        return len(self.points)


@dataclass
class SessionObservations:
    """All observations of a session plus what was used to build them."""

    observations: list[Observation]
    sensor_names: list[str]
    info: dict[str, Any] = field(default_factory=dict)

    def cloud(self) -> UnifiedCloud:
        """Object-frame unified cloud of every observation."""
        parts = []
        for o in self.observations:
            n = len(o)
            parts.append(
                UnifiedCloud(
                    o.points,
                    o.normals,
                    np.full(n, o.modality),
                    np.full(n, o.sensor_id),
                    np.full(n, o.t),
                    o.confidence,
                    o.tactile_value,
                    frame="object",
                    sensor_names=self.sensor_names,
                )
            )
        if not parts:
            c = UnifiedCloud.empty("object")
            c.sensor_names = list(self.sensor_names)
            return c
        return UnifiedCloud.concat(parts)


def _cloud_to_object(c: UnifiedCloud, T_world_object: np.ndarray) -> UnifiedCloud:
    return c.transform(se3.invert(T_world_object), frame="object")


def free_depth_image(
    z: np.ndarray, mask: np.ndarray, stride: int = 2, mask_margin_px: int = 3, no_return_free: bool = True
) -> np.ndarray:
    """Free-space depth per pixel (see :attr:`Observation.free_depth`) from a depth image and its object mask.

    Args:
        z: (H, W) depth, m (0 / non-finite = no return). mask: (H, W) bool object mask.
        stride: output block size (min-pooled). mask_margin_px: no-return pixels this close to the mask stay
            unknown (a dropout on the object, or a mask that is a few pixels short, must not carve it).
        no_return_free: a no-return pixel away from the mask is free along the whole ray (a sensor that
            returns nothing beyond its range; set False for sensors with dropouts on dark surfaces).
    """
    import cv2

    z = np.asarray(z, np.float32)
    ok = np.isfinite(z) & (z > 0)
    out = np.where(ok, z, 0.0).astype(np.float32)
    if no_return_free:
        k = 2 * int(mask_margin_px) + 1
        near = cv2.dilate(np.asarray(mask, np.uint8), np.ones((k, k), np.uint8)) > 0 if mask_margin_px > 0 else mask
        out[~ok & ~near] = np.inf
    s = max(1, int(stride))
    if s > 1:
        H, W = out.shape
        h, w = H // s, W // s
        out = out[: h * s, : w * s].reshape(h, s, w, s).min(axis=(1, 3))
    return out


def observations_from_frames(
    frames: Any,
    built: list[tuple[int, Any]],
    poses: Any,
    *,
    vision_stride: int = 4,
    max_vision_points: int = 4000,
    keep_depth: bool = True,
    free_stride: int = 2,
) -> SessionObservations:
    """Object-frame observations of already built frames.

    Args:
        frames: the :class:`~vtrack.frames.session.SessionFrames` the frames come from.
        built: ``(index, Frame)`` pairs (e.g. kept while tracking, so nothing is computed twice).
        poses: :class:`~vtrack.io.poses.PoseTrack` of ``T_world_object``.
        vision_stride: pixel stride of the vision points (normals use full resolution).
        max_vision_points: random cap on points per camera frame (seeded).
        keep_depth: keep masked full-resolution depth images (TSDF input).
        free_stride: block size of the free-space images (:func:`free_depth_image`; 0 = none kept).
    """
    from vtrack.frames.session import upsample_mask

    rng = np.random.default_rng(0)
    cam_names = [c.name for c in frames.cams] if "vision" in frames.modalities else []
    touch_names = list(frames.touch.sensors) if frames.touch is not None else []
    names = cam_names + touch_names
    obs: list[Observation] = []
    counts: dict[str, int] = {}
    times = np.array([frames.times[i] for i, _ in built])
    T_wo_all = poses.at(times) if len(times) else np.zeros((0, 4, 4))
    for k, (i, fr) in enumerate(built):
        t = float(frames.times[i])
        T_wo = T_wo_all[k]
        for sid, c in enumerate(frames.cams if cam_names else []):
            mask = fr.vision_mask.get(c.name)
            if mask is None:
                continue
            j = int(c.stream.index_at(t)[0])
            depth = np.asarray(c.stream["depth"][j])
            full = upsample_mask(mask, depth.shape)
            cl = from_rgbd(
                depth, c.cam, c.T_wc, mask=full, t=t, sensor_id=sid, depth_scale=c.depth_scale, stride=vision_stride
            )
            if len(cl) > max_vision_points:
                cl = cl.select(np.sort(rng.choice(len(cl), max_vision_points, replace=False)))
            dm = fd = None
            if keep_depth or free_stride:
                z = c.cam.depth_to_meters(depth, c.depth_scale).astype(np.float32)
                if keep_depth:
                    dm = np.where(np.isfinite(z) & (z > 0.05) & full, z, 0.0).astype(np.float32)
                if free_stride:
                    fd = free_depth_image(z, full, int(free_stride))
            if len(cl) == 0 and (dm is None or not dm.any()):
                continue
            co = _cloud_to_object(cl, T_wo)
            obs.append(
                Observation(
                    t,
                    VISION,
                    sid,
                    c.name,
                    co.xyz,
                    co.normal,
                    co.confidence,
                    co.tactile_value,
                    se3.invert(c.T_wc) @ T_wo,
                    dm,
                    c.cam.K,
                    fd,
                    max(1, int(free_stride)),
                )
            )
            counts[f"camera/{c.name}"] = counts.get(f"camera/{c.name}", 0) + 1
        for s, con in fr.contacts.items():
            if not con.in_contact:
                continue
            T_ws = fr.sensor_poses[s]
            sid = len(cam_names) + touch_names.index(s)
            cl = from_contact_points(
                con.points, con.normals, T_ws, t=t, sensor_id=sid, tactile_value=con.penetration_mm.astype(np.float32)
            )
            if len(cl) == 0:
                continue
            co = _cloud_to_object(cl, T_wo)
            obs.append(
                Observation(
                    t, TOUCH, sid, s, co.xyz, co.normal, co.confidence, co.tactile_value, se3.invert(T_ws) @ T_wo
                )
            )
            counts[f"tactile/{s}"] = counts.get(f"tactile/{s}", 0) + 1
    obs.sort(key=lambda o: (o.t, o.modality, o.sensor_id))
    info = {
        "session": str(frames.path),
        "modalities": list(frames.modalities),
        "frames": counts,
        "tactile_source": frames.tactile_source if frames.touch is not None else "none",
        "segmentation": frames.segmentation if cam_names else "none",
        "cameras": cam_names,
        "tactile_sensors": touch_names,
    }
    return SessionObservations(obs, names, info)


def load_observations(
    session: str | Path | Any,
    modalities: tuple[str, ...] | list[str] = ("vision", "touch"),
    *,
    poses: Any,
    tactile_source: str = "pipeline",
    segmentation: str = "pipeline",
    vision_stride: int = 4,
    frame_step: int = 2,
    touch_stride: int = 3,
    max_vision_points: int = 4000,
    keep_depth: bool = True,
    scene: Any = None,
    depth_stride: int = 4,
) -> SessionObservations:
    """Read a session through the frames layer and return its observations in the object frame.

    Args:
        session: session directory or an open :class:`~vtrack.io.session.SessionReader`.
        modalities: subset of ``("vision", "touch")``.
        poses: :class:`~vtrack.io.poses.PoseTrack` (``T_world_object`` over time).
        tactile_source / segmentation: ``pipeline`` (default) or ``gt`` (oracle ablations).
        vision_stride: pixel stride for unprojected points (TSDF depth stays full resolution).
        frame_step: use every k-th frame of the time base (first camera, 30 Hz by default).
        touch_stride: point stride of the tactile pipeline.
        max_vision_points: random cap on points per camera frame (seeded).
        keep_depth: keep masked depth images (needed by TSDF only; memory otherwise).
        depth_stride: stride at which the depth is segmented (the mask is upsampled for TSDF).
    """
    from vtrack.frames.session import SessionFrames

    mods = tuple(m.strip() for m in modalities)
    if not mods or set(mods) - {"vision", "touch"}:
        raise InputError("unknown modality", field="modalities", expected="vision and/or touch", got=list(mods))
    frames = SessionFrames(
        session,
        mods,
        tactile_source=tactile_source,
        segmentation=segmentation,
        depth_stride=depth_stride,
        touch_stride=touch_stride,
        scene=scene,
    )
    built = [(i, frames.frame(i)[0]) for i in range(0, len(frames), max(1, int(frame_step)))]
    return observations_from_frames(
        frames, built, poses, vision_stride=vision_stride, max_vision_points=max_vision_points, keep_depth=keep_depth
    )
