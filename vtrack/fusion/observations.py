"""Session -> time-ordered observations in the OBJECT frame (mapping with known object poses).

Each :class:`Observation` is one camera frame or one tactile frame with contact, expressed in the
object frame using ``gt/object_pose`` (``T_world_object`` interpolated at the frame's time):

- vision: masked depth unprojected with the camera extrinsics (``T_world_camera``), then
  ``T_object_world``; the depth image itself is kept for TSDF integration.
- touch: contact pixels of the tactile height map lifted with :func:`vtrack.geometry.tactile_frame.
  height_to_points`, placed in the world by the hand's forward kinematics
  (:class:`vtrack.kinematics.hand.HandKinematics`, joints interpolated at the tactile timestamps),
  then ``T_object_world``.

Tactile height source (``tactile_source``): ``"gt"`` = ``gt/tactile/<sensor>/height_mm`` (synthetic
sessions), ``"pipeline"`` = tactile images through ``vtrack.tactile.pipeline.TactilePipeline``,
``"auto"`` = GT when the session has it, else the pipeline. The source used is reported.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError
from vtrack.fusion.cloud import TOUCH, VISION, UnifiedCloud, from_rgbd, from_tactile
from vtrack.geometry import se3
from vtrack.geometry.camera import PinholeCamera


@dataclass
class Observation:
    """One frame of surface evidence in the object frame (metres).

    Attributes:
        t: timestamp, s. modality: 0 vision / 1 touch. sensor_id / sensor: camera or tactile sensor.
        points, normals: (N, 3) object-frame surface points and outward unit normals (0 = unknown).
        confidence: (N,) in [0, 1]. tactile_value: (N,) penetration mm (touch) or 0.
        T_view_object: 4x4 camera (or tactile sensor) frame from the object frame.
        depth_m, K: vision only, masked float32 depth (m, 0 = invalid) and 3x3 intrinsics (TSDF input).
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
            parts.append(UnifiedCloud(o.points, o.normals, np.full(n, o.modality), np.full(n, o.sensor_id),
                                      np.full(n, o.t), o.confidence, o.tactile_value, frame="object",
                                      sensor_names=self.sensor_names))
        if not parts:
            c = UnifiedCloud.empty("object")
            c.sensor_names = list(self.sensor_names)
            return c
        return UnifiedCloud.concat(parts)


def _object_poses(reader, times: np.ndarray) -> np.ndarray:
    if "gt/object_pose" not in reader:
        raise InputError("mapping needs known object poses but the session has no gt/object_pose stream",
                         path=reader.path, field="gt/object_pose")
    s = reader["gt/object_pose"]
    if s.n == 0:
        raise InputError("gt/object_pose has no frames", path=reader.path, field="gt/object_pose")
    T = s.sample("T_world_object", times, mode="linear")
    if not np.all(np.isfinite(T)):
        raise InputError("object poses contain NaN/Inf", path=reader.path, field="gt/object_pose")
    return T


def _blocks(stream, fields: list[str], idx: np.ndarray, block: int = 24):
    """Yield (j, i, {field: frame}) reading ``block`` frames per call (far fewer store round trips)."""
    for a in range(0, len(idx), block):
        ids = idx[a:a + block]
        data = {f: stream[f][ids] for f in fields}
        for k, i in enumerate(ids):
            yield a + k, int(i), {f: v[k] for f, v in data.items()}


def _cloud_to_object(c: UnifiedCloud, T_world_object: np.ndarray) -> UnifiedCloud:
    return c.transform(se3.invert(T_world_object), frame="object")


def load_observations(session: str | Path | Any, modalities: tuple[str, ...] | list[str] = ("vision", "touch"), *,
                      tactile_source: str = "auto", vision_stride: int = 4, vision_frame_step: int = 1,
                      touch_stride: int = 6, touch_frame_step: int = 1, max_vision_points: int = 4000,
                      keep_depth: bool = True, scene: Any = None) -> SessionObservations:
    """Read a session and return its observations in the object frame, sorted by time.

    Args:
        session: session directory or an open :class:`~vtrack.io.session.SessionReader`.
        modalities: subset of ``("vision", "touch")``.
        tactile_source: ``"gt"``, ``"pipeline"`` or ``"auto"`` (see module docstring).
        vision_stride: pixel stride for unprojected points (depth for TSDF stays full resolution).
        vision_frame_step / touch_frame_step: use every k-th camera / tactile frame.
        touch_stride: pixel stride on the tactile height map (DIGIT 0.09 mm px -> 0.54 mm at 6).
        max_vision_points: random cap on points per camera frame (seeded).
        keep_depth: keep masked depth images (needed by TSDF only; memory otherwise).
        scene: override the session's embedded scene (for the hand / tactile specs).
    """
    from vtrack.io.session import SessionReader, open_session

    reader = session if isinstance(session, SessionReader) else open_session(session)
    mods = [m.strip() for m in modalities]
    bad = set(mods) - {"vision", "touch"}
    if bad or not mods:
        raise InputError("unknown modality", field="modalities", expected="vision and/or touch", got=mods)
    rng = np.random.default_rng(0)
    obs: list[Observation] = []
    names: list[str] = []
    info: dict[str, Any] = {"session": str(reader.path), "modalities": mods, "frames": {}}

    if "vision" in mods:
        cams = {k: s for k, s in reader.streams.items() if k.startswith("camera/")}
        info["cameras"] = sorted(cams)
        for name, s in sorted(cams.items()):
            if s.n == 0:
                continue
            sid = len(names)
            names.append(name.split("/", 1)[1])
            a = s.attrs
            try:
                K = np.asarray(a["K"], np.float64)
                T_wc = np.asarray(a["T_world_camera"], np.float64)
                cam = PinholeCamera(int(a["width"]), int(a["height"]), K[0, 0], K[1, 1], K[0, 2], K[1, 2])
            except (KeyError, TypeError, ValueError, IndexError) as e:
                raise InputError(f"camera stream attrs incomplete ({e})", path=reader.path,
                                 field=f"{name}.attrs", expected="K, width, height, T_world_camera") from None
            scale = float(a.get("depth_scale", 0.001))
            idx = np.arange(0, s.n, max(1, vision_frame_step))
            T_wo = _object_poses(reader, s.t[idx])
            has_mask = "mask" in s.fields
            used = 0
            for j, i, fr in _blocks(s, ["depth", "mask"] if has_mask else ["depth"], idx):
                depth = fr["depth"]
                mask = fr["mask"] if has_mask else None
                c = from_rgbd(depth, cam, T_wc, mask=mask, t=float(s.t[i]), sensor_id=sid, depth_scale=scale,
                              stride=vision_stride)
                if len(c) > max_vision_points:
                    c = c.select(np.sort(rng.choice(len(c), max_vision_points, replace=False)))
                T_vo = se3.invert(T_wc) @ T_wo[j]
                dm = None
                if keep_depth:
                    z = cam.depth_to_meters(depth, scale).astype(np.float32)
                    ok = np.isfinite(z) & (z > 0.05)
                    if mask is not None:
                        ok &= mask.astype(bool)
                    dm = np.where(ok, z, 0.0).astype(np.float32)
                if len(c) == 0 and dm is None:
                    continue
                co = _cloud_to_object(c, T_wo[j])
                obs.append(Observation(float(s.t[i]), VISION, sid, names[sid], co.xyz, co.normal, co.confidence,
                                       co.tactile_value, T_vo, dm, cam.K))
                used += 1
            info["frames"][name] = used

    if "touch" in mods:
        obs += _touch_observations(reader, names, info, tactile_source, touch_stride, touch_frame_step, scene)

    obs.sort(key=lambda o: (o.t, o.modality, o.sensor_id))
    return SessionObservations(obs, names, info)


def _touch_observations(reader, names: list[str], info: dict, tactile_source: str, stride: int,
                        frame_step: int, scene: Any) -> list[Observation]:
    sensors = sorted({k.split("/", 1)[1] for k in reader.streams if k.startswith("tactile/")}
                     | {k.split("/", 2)[2] for k in reader.streams if k.startswith("gt/tactile/")})
    info["tactile_sensors"] = sensors
    if not sensors:
        info["tactile_source"] = "none"
        return []
    if tactile_source not in ("auto", "gt", "pipeline"):
        raise InputError("unknown tactile source", field="tactile_source", expected="auto|gt|pipeline",
                         got=tactile_source)
    has_gt = all(f"gt/tactile/{s}" in reader for s in sensors)
    src = ("gt" if has_gt else "pipeline") if tactile_source == "auto" else tactile_source
    if src == "gt" and not has_gt:
        raise InputError("tactile_source 'gt' needs gt/tactile/<sensor> streams", path=reader.path,
                         field="gt/tactile", expected=str(sensors))
    info["tactile_source"] = src
    scene = scene or reader.scene()
    if "joints" not in reader:
        raise InputError("touch needs the hand's joint states (no 'joints' stream)", path=reader.path,
                         field="joints")
    from vtrack.kinematics.hand import HandKinematics

    hand = HandKinematics.from_scene(scene)
    pipeline = None
    if src == "pipeline":
        from vtrack.tactile.pipeline import TactilePipeline

        pipeline = TactilePipeline.from_scene(scene)
    out: list[Observation] = []
    for sname in sensors:
        stream = reader[f"gt/tactile/{sname}"] if src == "gt" else reader[f"tactile/{sname}"]
        if stream.n == 0:
            continue
        spec = next((t for t in scene.tactile if t.name == sname), None)
        mm_per_px = float(stream.attrs.get("mm_per_px", spec.mm_per_px if spec else 0.0) or 0.0)
        if mm_per_px <= 0:
            raise InputError("unknown tactile pixel pitch", path=reader.path, field=f"{stream.name}.mm_per_px")
        thr = spec.contact_threshold_mm if spec else 0.05
        sid = len(names)
        names.append(sname)
        idx = np.arange(0, stream.n, max(1, frame_step))
        times = stream.t[idx]
        T_ws = hand.sensor_poses_at(reader["joints"], times)[sname]
        T_wo = _object_poses(reader, times)
        n_used = 0
        fields = ["height_mm", "contact"] if src == "gt" else ["image"]
        for j, _i, fr in _blocks(stream, fields, idx):
            if src == "gt":
                h, contact, prob = fr["height_mm"], fr["contact"], None
            else:
                h, contact, prob = _pipeline_height(pipeline, sname, fr["image"])
            c = from_tactile(h, contact, mm_per_px, T_ws[j], t=float(times[j]), sensor_id=sid, stride=stride,
                             contact_threshold_mm=thr, contact_probability=prob)
            if len(c) == 0:
                continue
            co = _cloud_to_object(c, T_wo[j])
            T_vo = se3.invert(T_ws[j]) @ T_wo[j]
            out.append(Observation(float(times[j]), TOUCH, sid, sname, co.xyz, co.normal, co.confidence,
                                   co.tactile_value, T_vo))
            n_used += 1
        info["frames"][f"tactile/{sname}"] = n_used
    return out


def _pipeline_height(pipeline: Any, sensor: str, image: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Height map (mm), contact mask and optional contact probability from the tactile pipeline.

    Uses ``TactilePipeline.process(sensor, image)`` (a ``TactileFrame`` with ``height_mm`` and
    ``contact``); frames whose ``quality`` is not "ok" count as no contact. Arrays and dicts with the
    same keys are accepted too, so fusion does not hinge on the exact return type.
    """
    fn = getattr(pipeline, "process", None) or pipeline
    try:
        r = fn(sensor, image)
    except TypeError:
        r = fn(image)
    if isinstance(r, np.ndarray):
        return np.asarray(r, np.float64), None, None
    get = r.get if isinstance(r, dict) else (lambda k, d=None: getattr(r, k, d))
    h = np.asarray(get("height_mm"), np.float64)
    if get("quality", "ok") != "ok":
        return np.zeros_like(h), np.zeros(h.shape, bool), None
    c = get("contact", None)
    p = get("contact_prob", None)
    return h, None if c is None else np.asarray(c, bool), None if p is None else np.asarray(p, np.float32)
