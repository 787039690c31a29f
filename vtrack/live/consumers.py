"""Live consumers: ``null`` (throughput check), ``track`` (tracking per camera frame through the frames
layer), ``reconstruct`` (TSDF integration per camera frame).

``track`` and ``reconstruct`` call the tracking / fusion engineers' per-frame APIs
(:meth:`vtrack.tracking.tracker.KnownShapeTracker.step`,
:meth:`vtrack.fusion.tsdf.TSDFReconstructor.integrate_depth`) on the newest data: joints and
tactile frames update state; each camera frame triggers one step.

Consumers are registry components (``live.<kind>``, :func:`make_consumer`); their options are typed
(:class:`LiveTrackConfig`, :class:`LiveReconstructConfig`) with the defaults set there.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError
from vtrack.live.pipeline import Consumer
from vtrack.live.sources import FrameEvent


@dataclass
class LiveTrackConfig:
    """Options of :class:`TrackConsumer`: depth_stride = keep every k-th depth pixel (rows and columns);
    the tracker's own options are :class:`vtrack.tracking.window.TrackerOptions` (passed through)."""

    depth_stride: int = 4


@dataclass
class LiveReconstructConfig:
    """Options of :class:`ReconstructConsumer`: the live TSDF is coarser than the offline one
    (:class:`vtrack.fusion.tsdf.TSDFConfig`, 2 mm) to keep up with the camera. voxel_size m; block_count =
    initial TSDF hash-map capacity; depth_stride = keep every k-th depth pixel for segmentation."""

    voxel_size: float = 0.004
    block_count: int = 4000
    depth_stride: int = 4


class NullConsumer(Consumer):
    """Touches every field of every frame (a checksum) so the replay + transport cost is measured."""

    name = "null"

    def __init__(self, session: str | Path | None = None) -> None:
        self.checksum = 0

    def process(self, event: FrameEvent) -> None:
        for v in event.data.values():
            self.checksum += int(np.asarray(v).ravel()[::997].sum())

    def finish(self) -> dict[str, Any]:
        return {"checksum": self.checksum}


class TrackConsumer(Consumer):
    """In-hand tracking on the live stream through the frames layer (no ground truth).

    Joint states and tactile images update the newest state; each camera frame is segmented (hand removed
    by forward kinematics), the newest tactile images go through the calibrated tactile pipeline, and the
    tracker takes one step. Known shape when ``mesh`` is given (initial pose ``init_pose``, else global
    registration on the first frame), else SLAM (object frame at the first frame's centroid).
    """

    name = "track"

    def __init__(
        self,
        session: str | Path,
        mesh: str | Path | None = None,
        init_pose: np.ndarray | None = None,
        *,
        config: LiveTrackConfig | None = None,
        depth_stride: int | None = None,
        **tracker_opts: Any,
    ) -> None:
        from vtrack.frames.session import SessionFrames
        from vtrack.tracking.run import TRACK_TOUCH_DOWNSAMPLE, TRACK_TOUCH_STRIDE

        self.config = config or LiveTrackConfig()
        if depth_stride is not None:
            self.config = LiveTrackConfig(depth_stride=depth_stride)
        depth_stride = self.config.depth_stride
        self.session = Path(session)
        try:
            self.sf = SessionFrames(
                self.session,
                modalities=("vision", "touch"),
                depth_stride=depth_stride,
                touch_stride=TRACK_TOUCH_STRIDE,
                touch_downsample=TRACK_TOUCH_DOWNSAMPLE,
            )
        except InputError:  # e.g. a sensor without calibration: vision only, said in the result
            self.sf = SessionFrames(self.session, modalities=("vision",), depth_stride=depth_stride)
        self.mesh = None if mesh is None else Path(mesh)
        self.init_pose = init_pose
        self.tracker_opts = tracker_opts
        self.tracker: Any = None
        self.cams = {f"camera/{c.name}": c for c in self.sf.cams}
        self.touch_streams = [f"tactile/{s}" for s in (self.sf.touch.sensors if self.sf.touch else [])]
        self.q: np.ndarray | None = None
        self.images: dict[str, Any] = {}
        self.poses: list[tuple[float, np.ndarray]] = []

    def streams(self) -> list[str]:
        s = list(self.cams) + self.touch_streams
        if self.sf.kin is not None:
            s.append("joints")
        return s

    def wants(self, stream: str) -> bool:
        return stream in self.cams or stream in self.touch_streams or (stream == "joints" and self.sf.kin is not None)

    def _start(self, frame: Any) -> None:
        from vtrack.tracking.run import build_tracker, centroid_frame, register_known_shape

        if self.mesh is not None:
            T0 = self.init_pose
            if T0 is None:
                try:
                    T0, _ = register_known_shape(self.mesh, [frame], bool(self.sf.scene.object.symmetric))
                except InputError:  # nothing to register on yet: try the next frame
                    return
            self.tracker = build_tracker("known_shape", self.mesh, T0, **self.tracker_opts)
        else:
            T0 = centroid_frame(frame)
            if T0 is not None:
                self.tracker = build_tracker("slam", None, T0, **self.tracker_opts)

    def process(self, ev: FrameEvent) -> None:
        if ev.stream == "joints":
            q = np.asarray(ev.data["q"], dtype=np.float64)[None]
            self.q = self.sf.kin.reorder(q, self.sf.reader["joints"].attrs.get("joint_names"))[0]
            return
        if ev.stream in self.touch_streams:
            self.images[ev.stream.split("/", 1)[1]] = ev.data["image"]
            return
        c = self.cams[ev.stream]
        k = self.sf.depth_stride
        raw = {
            "t": ev.t,
            "q": self.q,
            "cams": [(c, np.asarray(ev.data["depth"])[::k, ::k], None)],
            "touch": list(self.images.items()) if self.q is not None else [],
        }
        frame = self.sf.build(raw).tracking_frame()
        if self.tracker is None:
            self._start(frame)
            if self.tracker is None:
                return
        T = self.tracker.step(frame)
        self.poses.append((ev.t, np.asarray(T)))

    def finish(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "steps": len(self.poses),
            "modalities": list(self.sf.modalities),
            "mode": "known_shape" if self.mesh is not None else "slam",
        }
        if len(self.poses) > 1:
            from vtrack.eval.session_gt import SessionGroundTruth, score_trajectory

            gt = SessionGroundTruth.find(None, self.session)  # scoring only, after the run
            if gt is None:
                return out
            t = np.array([p[0] for p in self.poses])
            T = np.stack([p[1] for p in self.poses])
            m, _ = score_trajectory(gt, t, T, mesh=self.mesh)
            out["motion_err_mm"] = round(float(m["motion_err_mm"]), 3)
            out["motion_add_s_mm"] = round(float(m["motion_add_s_mm"]), 3)
            if "add_s_mm" in m:
                out["add_s_mm"] = round(float(m["add_s_mm"]), 3)
        return out


class ReconstructConsumer(Consumer):
    """TSDF reconstruction on the live stream: each camera frame's depth, segmented by the frames layer
    (no ground truth), is integrated in the object frame given by ``poses`` (a ``poses.csv`` of
    ``T_world_object``, e.g. from ``vtrack track``); without poses the object is taken as static in the
    world frame."""

    name = "reconstruct"

    def __init__(
        self,
        session: str | Path,
        poses: str | Path | None = None,
        *,
        config: LiveReconstructConfig | None = None,
        **opts: Any,
    ) -> None:
        from vtrack import registry
        from vtrack.config import build_config
        from vtrack.frames.session import SessionFrames

        self.config = c = build_config(LiveReconstructConfig, opts, "live reconstruction", base=config)
        self.sf = SessionFrames(session, modalities=("vision",), depth_stride=c.depth_stride)
        self.tsdf = registry.load("reconstruction.tsdf")(voxel_size=c.voxel_size, block_count=c.block_count)
        self.cams = {f"camera/{c.name}": c for c in self.sf.cams}
        if not self.cams:
            raise InputError("live reconstruction needs a camera stream", path=self.sf.path)
        self.poses = None
        if poses is not None:
            from vtrack.io.poses import read_poses_csv

            self.poses = read_poses_csv(poses)
        self.q: np.ndarray | None = None
        self.integrated = 0

    def streams(self) -> list[str]:
        return list(self.cams) + (["joints"] if self.sf.kin is not None else [])

    def wants(self, stream: str) -> bool:
        return stream in self.cams or (stream == "joints" and self.sf.kin is not None)

    def process(self, ev: FrameEvent) -> None:
        from vtrack.frames.session import upsample_mask
        from vtrack.geometry import se3

        if ev.stream == "joints":
            q = np.asarray(ev.data["q"], dtype=np.float64)[None]
            self.q = self.sf.kin.reorder(q, self.sf.reader["joints"].attrs.get("joint_names"))[0]
            return
        c = self.cams[ev.stream]
        k = self.sf.depth_stride
        depth = np.asarray(ev.data["depth"])
        fr = self.sf.build({"t": ev.t, "q": self.q, "cams": [(c, depth[::k, ::k], None)], "touch": []})
        mask = upsample_mask(fr.vision_mask[c.name], depth.shape)
        d = np.where(mask, depth.astype(np.float32) * c.depth_scale, 0.0).astype(np.float32)
        T_wo = np.eye(4) if self.poses is None else self.poses.at(np.array([ev.t]))[0]
        self.integrated += int(self.tsdf.integrate_depth(d, c.cam.K, se3.invert(c.T_wc) @ T_wo))

    def finish(self) -> dict[str, Any]:
        V, F = self.tsdf.extract_mesh()
        return {"integrated": self.integrated, "mesh_vertices": int(len(V)), "mesh_faces": int(len(F))}


def make_consumer(kind: str, session: str | Path, **opts: Any) -> Consumer:
    """The live consumer ``kind`` (``track`` | ``reconstruct`` | ``null``, registry key ``live.<kind>``) on
    ``session`` with its options (see the consumer's config)."""
    from vtrack import registry

    kinds = [k.split(".", 1)[1] for k in registry.COMPONENTS if k.startswith("live.")]
    if kind not in kinds:
        raise InputError("unknown live consumer", field="--consumer", expected="|".join(kinds), got=kind)
    return registry.load(f"live.{kind}")(session, **opts)


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
