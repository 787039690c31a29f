"""Live consumers: ``null`` (throughput check), ``track`` (known-shape tracking per camera frame),
``reconstruct`` (TSDF integration per camera frame).

``track`` and ``reconstruct`` call the tracking / fusion engineers' per-frame APIs
(:meth:`vtrack.tracking.tracker.KnownShapeTracker.step`,
:meth:`vtrack.fusion.tsdf.TSDFReconstructor.integrate_depth`) on the newest data: joints and
tactile frames update state; each camera frame triggers one step.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError
from vtrack.live.pipeline import Consumer
from vtrack.live.sources import FrameEvent


class NullConsumer(Consumer):
    """Touches every field of every frame (a checksum) so the replay + transport cost is measured."""

    name = "null"

    def __init__(self) -> None:
        self.checksum = 0

    def process(self, event: FrameEvent) -> None:
        for v in event.data.values():
            self.checksum += int(np.asarray(v).ravel()[:: 997].sum())

    def finish(self) -> dict[str, Any]:
        return {"checksum": self.checksum}


class TrackConsumer(Consumer):
    """Known-shape tracking on the live stream.

    Vision: each camera frame's depth (segmented with its mask when present) is unprojected into
    the world (the session's camera calibration). Touch: the newest ground-truth tactile height
    maps (``gt/tactile/*``, when the session has them) placed with the hand kinematics at the
    newest joint state. One ``tracker.step`` per camera frame.
    """

    name = "track"

    def __init__(self, session: str | Path, depth_stride: int = 4, **tracker_opts: Any) -> None:
        from vtrack.tracking.frontend import SessionFrames
        from vtrack.tracking.tracker import KnownShapeTracker

        self.session = Path(session)
        mods = ("vision", "touch")
        try:
            self.sf = SessionFrames(self.session, modalities=mods, depth_stride=depth_stride)
        except InputError:
            self.sf = SessionFrames(self.session, modalities=("vision",), depth_stride=depth_stride)
        reader = self.sf.reader
        mesh = self.session / "assets" / "object.ply"
        if not mesh.exists():
            raise InputError("live tracking needs the object mesh in the session", path=mesh)
        T0 = None
        if "gt/object_pose" in reader and reader["gt/object_pose"].n:
            T0 = reader["gt/object_pose"]["T_world_object"][0]
        self.tracker = KnownShapeTracker.from_scene(self.sf.scene, T_init=T0, mesh=mesh, **tracker_opts)
        self.cams = {f"camera/{c.name}" if not c.name.startswith("camera/") else c.name: c for c in self.sf.cams}
        self.kin = None
        if self.sf.scene.hand is not None and "joints" in reader and any(
                k.startswith("gt/tactile/") for k in reader.streams):
            from vtrack.kinematics.hand import HandKinematics

            self.kin = HandKinematics.from_scene(self.sf.scene)
            self.joint_names = reader["joints"].attrs.get("joint_names")
        self.q: np.ndarray | None = None
        self.touch: dict[str, tuple] = {}
        self.poses: list[tuple[float, np.ndarray]] = []

    def streams(self) -> list[str]:
        s = list(self.cams)
        if self.kin is not None:
            s += ["joints"] + [k for k in self.sf.reader.streams if k.startswith("gt/tactile/")]
        return s

    def wants(self, stream: str) -> bool:
        touch = stream == "joints" or stream.startswith("gt/tactile/")
        return stream in self.cams or (self.kin is not None and touch)

    def process(self, ev: FrameEvent) -> None:
        if ev.stream == "joints":
            q = np.asarray(ev.data["q"], dtype=np.float64)[None]
            self.q = self.kin.reorder(q, self.joint_names)[0]
            return
        if ev.stream.startswith("gt/tactile/"):
            s = self.sf.reader[ev.stream]
            self.touch[ev.stream.split("/", 2)[2]] = (ev.data["height_mm"], ev.data["contact"],
                                                       float(s.attrs.get("mm_per_px", 0.1)))
            return
        c = self.cams[ev.stream]
        raw: dict = {"cams": [(c, ev.data["depth"], ev.data.get("mask"))], "touch": []}
        if self.kin is not None and self.q is not None and np.all(np.isfinite(self.q)):
            poses = self.kin.sensor_poses(self.q[None])
            for s, (h, contact, mmpp) in self.touch.items():
                if s in poses:
                    raw["touch"].append((s, h, contact, mmpp, poses[s][0]))
        frame = self.sf.build(ev.t, raw)
        T = self.tracker.step(frame)
        self.poses.append((ev.t, np.asarray(T)))

    def finish(self) -> dict[str, Any]:
        out: dict[str, Any] = {"steps": len(self.poses)}
        r = self.sf.reader
        if self.poses and "gt/object_pose" in r and r["gt/object_pose"].n:
            t = np.array([p[0] for p in self.poses])
            T = np.stack([p[1] for p in self.poses])
            gt = r["gt/object_pose"].sample("T_world_object", t, mode="linear")
            err = np.linalg.norm(T[:, :3, 3] - gt[:, :3, 3], axis=1) * 1e3
            out["translation_error_mm_mean"] = round(float(err.mean()), 3)
            out["translation_error_mm_final"] = round(float(err[-1]), 3)
        return out


class ReconstructConsumer(Consumer):
    """TSDF reconstruction on the live stream: each camera frame's depth is integrated in the object
    frame, with the object pose from the session's ``gt/object_pose`` when it has one (replay), else
    the object is taken as static in the world frame."""

    name = "reconstruct"

    def __init__(self, session: str | Path, voxel_size: float = 0.004) -> None:
        from vtrack.fusion.tsdf import TSDFReconstructor
        from vtrack.io.session import open_session

        self.reader = open_session(session)
        self.tsdf = TSDFReconstructor(voxel_size=voxel_size, block_count=4000)
        self.cams = {}
        for k, s in self.reader.streams.items():
            if k.startswith("camera/") and s.n:
                a = s.attrs
                self.cams[k] = (np.asarray(a["K"], np.float64), np.asarray(a["T_world_camera"], np.float64),
                                float(a.get("depth_scale", 0.001)), "mask" in s.fields)
        if not self.cams:
            raise InputError("live reconstruction needs a camera stream", path=self.reader.path)
        self.gt = self.reader["gt/object_pose"] if "gt/object_pose" in self.reader else None
        self.integrated = 0

    def streams(self) -> list[str]:
        return list(self.cams)

    def wants(self, stream: str) -> bool:
        return stream in self.cams

    def process(self, ev: FrameEvent) -> None:
        K, T_wc, scale, has_mask = self.cams[ev.stream]
        d = ev.data["depth"].astype(np.float32) * scale
        if has_mask:
            d = np.where(ev.data["mask"] > 0, d, 0.0)
        from vtrack.geometry import se3

        T_wo = np.eye(4)
        if self.gt is not None and self.gt.n:
            T_wo = self.gt.sample("T_world_object", ev.t, mode="linear")[0]
        T_co = se3.invert(T_wc) @ T_wo
        self.integrated += int(self.tsdf.integrate_depth(d, K, T_co))

    def finish(self) -> dict[str, Any]:
        V, F = self.tsdf.extract_mesh()
        return {"integrated": self.integrated, "mesh_vertices": int(len(V)), "mesh_faces": int(len(F))}


def make_consumer(kind: str, session: str | Path, **opts: Any) -> Consumer:
    if kind == "null":
        return NullConsumer()
    if kind == "track":
        return TrackConsumer(session, **opts)
    if kind == "reconstruct":
        return ReconstructConsumer(session, **opts)
    raise InputError("unknown live consumer", field="--consumer", expected="track|reconstruct|null", got=kind)


def replay_streams(session: str | Path, consumers: list[Consumer]) -> list[str]:
    """Streams a replay must emit for these consumers: each consumer's ``streams()``, plus the
    default live streams (cameras, tactile images, joints) when a consumer takes everything."""
    from vtrack.io.session import open_session

    r = open_session(session)
    out: set[str] = set()
    for c in consumers:
        if hasattr(c, "streams"):
            out |= set(c.streams())
        else:
            out |= {k for k in r.streams if k.startswith(("camera/", "tactile/")) or k == "joints"}
    return sorted(k for k in out if k in r and r[k].n)
