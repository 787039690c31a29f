"""Time-aligned, world-frame observations of a recorded session: the one front end of fusion, tracking
and live.

A :class:`SessionFrames` turns a session (RGB-D, tactile images, joint states, calibrations; no ground
truth needed) into :class:`Frame` objects at the time base (the first camera's timestamps; without a
camera, the first tactile stream's):

- **vision**: each camera's nearest depth frame, subsampled by ``depth_stride`` (a strided image is a
  camera with scaled intrinsics), segmented WITHOUT ground truth by
  :class:`~vtrack.frames.segmentation.HandAwareSegmenter` (the URDF hand posed by forward kinematics is
  rendered into the camera and removed, workspace crop around the fingertips, support planes, the
  cluster nearest the tactile contacts), unprojected and moved to the world with ``T_world_camera``;
- **touch**: each sensor's nearest tactile image through its calibrated tactile pipeline
  (:class:`~vtrack.frames.touch.TouchSource`), contact points placed in the world by forward kinematics
  (``T_world_sensor`` from the joint states interpolated at the frame time); object normals are minus the
  gel normals; sensors that see no contact give gel-surface ``free_points`` (non-penetration); in frames where
  vision sees (almost) nothing, sensors IN contact add the gel-surface points farther than
  ``contact_free_margin_m`` from their contact patch (the object is not there either: with shallow contacts
  read one-sided, they are what holds the object between the fingers);
- **joints** ``q`` and the sensor poses.

Oracle ablations (labelled, never defaults): ``tactile_source="gt"`` (simulated height maps) and
``segmentation="gt"`` (the renderer's masks), both read through :mod:`vtrack.eval.oracle`; blind runs never
open a ground-truth stream.

Robustness: NaN joints drop touch and hand removal for that frame only; a frame without object pixels
or without contact is returned with empty arrays, never an exception.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError
from vtrack.frames.touch import Contact, TouchSource, gel_free_points
from vtrack.geometry import se3
from vtrack.geometry.camera import PinholeCamera
from vtrack.tracking.frame import TrackingFrame

SEGMENTATIONS = ("pipeline", "gt", "none", "gt_colour", "gt_points")
#: oracle ablations that split the mask's two uses: ``gt_colour`` follows the colour feature tracks on the renderer's
#: mask and takes the depth points from the pipeline's; ``gt_points`` the reverse
SPLIT_ORACLES = ("gt_colour", "gt_points")
#: segmentations that read the renderer's masks: a run using one is an oracle ablation, never blind
ORACLE_SEGMENTATIONS = ("gt", *SPLIT_ORACLES)
#: a colour track's full-resolution depth must agree with the depth-stride sample this well (m)
_COLOUR_DEPTH_AGREE_M = 0.005


@dataclass
class CameraView:
    """One camera of a session: stream, intrinsics, extrinsics ``T_world_camera`` and its segmenter."""

    name: str
    stream: Any
    cam: PinholeCamera
    T_wc: np.ndarray
    depth_scale: float
    segmenter: Any = None
    gt_mask: Any = None  # oracle ablation only
    tracks: Any = None  #: :class:`~vtrack.tracking.colour.FeatureTracks` when the colour term is on
    _strided: dict = field(default_factory=dict)

    def strided(self, k: int, shape: tuple[int, int]) -> PinholeCamera:
        """The camera of the image subsampled as ``image[::k, ::k]`` (pixel (r, c) -> (k r, k c))."""
        if k not in self._strided:
            c = self.cam
            self._strided[k] = PinholeCamera(shape[1], shape[0], c.fx / k, c.fy / k, c.cx / k, c.cy / k)
        return self._strided[k]


@dataclass
class Frame:
    """World-frame observations at one time ``t`` (s); metres.

    Attributes:
        vision_points: (N, 3) segmented object points from depth.
        vision_mask: per camera, the (h, w) object mask at the depth stride (for TSDF / the viewer).
        touch_points / touch_normals / touch_penetration_mm / touch_sensor: contacts on the object, the
            object's outward normals there, gel indentation (mm) and the sensor index of each point.
        free_points: points on gels of sensors without contact, and (frames without vision) on the gels of
            sensors in contact away from their patch (the object is not there).
        sensor_poses: ``T_world_sensor`` per sensor (NaN when the joints are unknown).
        q: joint positions (rad, the hand's joint order) or None.
        contacts: per sensor, the contact in the SENSOR frame (see :class:`~vtrack.frames.touch.Contact`).
    """

    t: float
    vision_points: np.ndarray
    touch_points: np.ndarray
    touch_normals: np.ndarray
    touch_penetration_mm: np.ndarray
    touch_sensor: np.ndarray
    free_points: np.ndarray
    sensor_poses: dict[str, np.ndarray]
    q: np.ndarray | None = None
    vision_mask: dict[str, np.ndarray] = field(default_factory=dict)
    contacts: dict[str, Contact] = field(default_factory=dict)
    info: dict = field(default_factory=dict)
    #: colour feature tracks (``colour=True`` only): track ids (N,), their world points (N, 3) in this frame and the
    #: world centres of the cameras that saw them (N, 3)
    colour_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    colour_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    colour_origins: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    def tracking_frame(self) -> TrackingFrame:
        """The tracker's input (:class:`~vtrack.tracking.frame.TrackingFrame`)."""
        return TrackingFrame(
            t=self.t,
            vision_points=self.vision_points if len(self.vision_points) else None,
            touch_points=self.touch_points if len(self.touch_points) else None,
            touch_normals=self.touch_normals if len(self.touch_normals) else None,
            free_points=self.free_points if len(self.free_points) else None,
            info=dict(
                self.info,
                colour_ids=self.colour_ids,
                colour_points=self.colour_points,
                colour_origins=self.colour_origins,
            )
            if len(self.colour_ids)
            else dict(self.info),
        )


def upsample_mask(mask: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """A frame's object mask (at the depth stride) at the full image size ``shape`` (nearest neighbour)."""
    import cv2

    if mask.shape == tuple(shape):
        return mask
    (H, W), (h, w) = shape, mask.shape
    if h and w and H % h == 0 and W % w == 0:
        # a whole stride (the usual case): nearest neighbour is a repeat, done on the mask's bounding box only
        ky, kx = H // h, W // w
        mask = mask if mask.dtype == bool else mask.astype(np.uint8) > 0  # the values the resize path sees
        out = np.zeros((H, W), bool)
        rows = np.flatnonzero(mask.any(1))
        if len(rows):
            cols = np.flatnonzero(mask.any(0))
            r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
            out[r0 * ky : r1 * ky, c0 * kx : c1 * kx] = mask[r0:r1, c0:c1].repeat(ky, 0).repeat(kx, 1)
        return out
    return cv2.resize(mask.astype(np.uint8), (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST) > 0


def _cat(parts: list[np.ndarray], width: int = 3) -> np.ndarray:
    return np.concatenate(parts) if parts else np.zeros((0, width) if width else 0)


class SessionFrames:
    """Frames of a session (see module docstring); ``len()``, ``frame(i)``, iteration.

    Args:
        session: session directory or an open :class:`~vtrack.io.session.SessionReader`.
        modalities: subset of ("vision", "touch").
        tactile_source: ``pipeline`` (default) or ``gt`` (oracle ablation).
        segmentation: ``pipeline`` (default), ``gt`` (oracle ablation), ``none`` (all valid depth), or the split
            oracle ablations ``gt_colour`` (colour tracks on the renderer's mask, depth points from the pipeline's)
            and ``gt_points`` (the reverse).
        depth_stride: pixel stride of the depth images.
        touch_stride: point stride of the tactile pipeline (working pixels).
        touch_downsample: working-resolution factor of the tactile pipeline (``auto``: from the image size).
        contact_free_margin_m / contact_free_max_vision: in frames with fewer than ``contact_free_max_vision``
            segmented vision points (0: never), the gel points of in-contact sensors farther than the margin (m)
            from their contact patch are free points too. Only then: next to a flat face the detected patch is
            smaller than the true contact (shading sees slopes), so with vision these points pushed the boxes
            (mustard 1.2 -> 4.5 mm, 5 s session); without vision they are the only thing holding the object
            (baseball at medium occlusion, 4 frames with vision in 150: 18.9 -> 6.5 mm).
        max_frames: keep only the first frames (0 = all).
        scene: override the session's embedded scene.
        colour: also read each camera's RGB and follow KLT feature tracks on the segmented object pixels
            (:mod:`vtrack.tracking.colour`; the tracker's colour term, option ``sigma_colour``); cameras without
            an ``rgb`` field give none. Off by default: the default path reads no RGB.
        colour_opts: :class:`~vtrack.tracking.colour.ColourOptions` overrides.
        segmentation_opts: :class:`~vtrack.frames.segmentation.SegmentationOptions` overrides of the pipeline's
            segmenter (e.g. ``{"colour_grow_px": 1}``, the heavy-occlusion colour mask); unknown names are an
            :class:`~vtrack.errors.InputError`.
    """

    def __init__(
        self,
        session: str | Path | Any,
        modalities: tuple[str, ...] | list[str] = ("vision", "touch"),
        *,
        tactile_source: str = "pipeline",
        segmentation: str = "pipeline",
        depth_stride: int = 4,
        touch_stride: int = 3,
        max_frames: int = 0,
        scene: Any = None,
        touch_downsample: int | str = "auto",
        contact_free_margin_m: float = 0.002,
        contact_free_max_vision: int = 30,
        colour: bool = False,
        colour_opts: dict | None = None,
        segmentation_opts: dict | None = None,
    ) -> None:
        from vtrack.io.session import SessionReader, open_session

        self.modalities = tuple(m.strip() for m in modalities)
        bad = set(self.modalities) - {"vision", "touch"}
        if bad or not self.modalities:
            raise InputError(
                "unknown modality", field="modalities", expected="vision and/or touch", got=list(self.modalities)
            )
        if segmentation not in SEGMENTATIONS:
            raise InputError(
                "unknown segmentation", field="segmentation", expected=" | ".join(SEGMENTATIONS), got=segmentation
            )
        self.reader = r = session if isinstance(session, SessionReader) else open_session(session)
        self.path = Path(r.path)
        if scene is None and r.scene_dict is None:
            from vtrack.scene.schema import Scene

            scene = Scene(name=self.path.name)  # a bare recording: cameras only, no hand, no tactile specs
        self.scene = scene or r.scene(check_files=False)
        self.tactile_source = tactile_source
        self.segmentation = segmentation
        self._seg_opts: Any = None
        if segmentation_opts:
            from vtrack.config import build_config
            from vtrack.frames.segmentation import SegmentationOptions

            self._seg_opts = build_config(SegmentationOptions, segmentation_opts, "segmentation")
        self.depth_stride = max(1, int(depth_stride))
        self.contact_free_margin_m = float(contact_free_margin_m)
        self.contact_free_max_vision = int(contact_free_max_vision)
        self._gel_grid: dict[tuple[str, int, int], np.ndarray] = {}
        if not (np.isfinite(self.contact_free_margin_m) and self.contact_free_margin_m >= 0):
            raise InputError(
                "contact_free_margin_m must be >= 0 (m)", field="contact_free_margin_m", got=contact_free_margin_m
            )
        self.kin = None
        if self.scene.hand is not None and "joints" in r and r["joints"].n:
            from vtrack.kinematics.hand import HandKinematics

            self.kin = HandKinematics.from_scene(self.scene)
        self.touch: TouchSource | None = None
        if "touch" in self.modalities:
            self.touch = TouchSource(
                r, self.scene, tactile_source, point_stride=touch_stride, downsample=touch_downsample
            )
            if self.touch.sensors and self.kin is None:
                raise InputError(
                    "touch needs the hand (scene.hand) and its joint states (a 'joints' stream)",
                    path=self.path,
                    field="joints",
                )
        self.cams: list[CameraView] = []
        for name, s in sorted(r.streams.items()):
            if not name.startswith("camera/") or s.n == 0:
                continue
            a = s.attrs
            try:
                K = np.asarray(a["K"], dtype=np.float64)
                cam = PinholeCamera(int(a["width"]), int(a["height"]), K[0, 0], K[1, 1], K[0, 2], K[1, 2])
                T_wc = np.asarray(a["T_world_camera"], dtype=np.float64)
            except (KeyError, TypeError, ValueError, IndexError) as e:
                raise InputError(
                    f"camera stream attrs incomplete ({e})",
                    path=self.path,
                    field=f"{name}.attrs",
                    expected="K, width, height, T_world_camera",
                ) from None
            self.cams.append(CameraView(name.split("/", 1)[1], s, cam, T_wc, float(a.get("depth_scale", 0.001))))
        if "vision" in self.modalities:
            self._setup_segmentation()
        self.colour = bool(colour) and "vision" in self.modalities
        if self.colour:
            from vtrack.tracking.colour import ColourOptions, FeatureTracks

            co = ColourOptions.from_dict(colour_opts)
            for c in self.cams:
                # a depth-only camera gives no colour tracks (the tracker's colour term then has nothing to use)
                if "rgb" in getattr(c.stream, "fields", ("rgb",)):
                    c.tracks = FeatureTracks(co)
        if self.cams:
            t = self.cams[0].stream.t
        elif self.touch is not None and self.touch.sensors:
            t = self.touch.times(self.touch.sensors[0])
        else:
            raise InputError(
                "session has no camera or tactile stream to build frames from",
                path=self.path,
                expected="camera/<name> or tactile/<name> streams with frames",
            )
        if max_frames:
            t = t[: int(max_frames)]
        if len(t) == 0:
            raise InputError("no frames", path=self.path)
        self.times = np.asarray(t, dtype=np.float64)
        self.q = self._joints_at(self.times)
        self.sensor_poses = self._sensor_poses(self.q)
        q0 = None
        if self.q is not None:
            ok = np.flatnonzero(np.isfinite(self.q).all(1))
            q0 = self.q[ok[0]] if len(ok) else None
        for c in self.cams:
            if c.segmenter is not None:
                c.segmenter.prepare(q0)  # one-time set-up here, not in the first frame's time

    # ------------------------------------------------------------------ set-up
    def _setup_segmentation(self) -> None:
        for c in self.cams:
            if self.segmentation in ORACLE_SEGMENTATIONS:  # oracle ablation: the renderer's exact mask
                from vtrack.eval.oracle import gt_mask_stream

                c.gt_mask = gt_mask_stream(self.reader, c.name)
            if self.segmentation in ("pipeline", *SPLIT_ORACLES):
                from vtrack import registry

                k = self.depth_stride
                h, w = -(-c.cam.height // k), -(-c.cam.width // k)
                c.segmenter = registry.load("segmentation")(self.kin, c.strided(k, (h, w)), c.T_wc, self._seg_opts)

    def _joints_at(self, times: np.ndarray) -> np.ndarray | None:
        if self.kin is None:
            return None
        js = self.reader["joints"]
        q = js.sample("q", times, mode="linear")
        return self.kin.reorder(q, js.attrs.get("joint_names"))

    def _sensor_poses(self, q: np.ndarray | None) -> dict[str, np.ndarray]:
        """``T_world_sensor`` (N, 4, 4) per mounted sensor at the frame times; NaN where joints are NaN."""
        if self.kin is None or q is None:
            return {}
        ok = np.isfinite(q).all(1)
        out = {s: np.full((len(q), 4, 4), np.nan) for s in self.kin.sensor_names}
        if ok.any():
            for s, P in self.kin.sensor_poses(q[ok]).items():
                out[s][ok] = P
        return out

    def reset(self) -> None:
        """Forget per-camera segmentation state (e.g. before re-running from the first frame)."""
        for c in self.cams:
            if c.segmenter is not None:
                c.segmenter.reset()
            if c.tracks is not None:
                c.tracks.reset()

    def __len__(self) -> int:
        return len(self.times)

    # ------------------------------------------------------------------ per frame
    def read(self, i: int, touch: bool = True) -> dict:
        """Decoded arrays of frame ``i`` (disk IO + decompression; not part of the per-frame compute).
        ``touch=False``: without the tactile images (``raw["touch"]`` empty; a caller that has the frame's contacts
        from elsewhere, :meth:`read_touch` + :meth:`touch_contacts` in another process, puts them there)."""
        t = float(self.times[i])
        raw: dict = {"i": i, "cams": [], "touch": []}
        if "vision" in self.modalities:
            k = self.depth_stride
            for c in self.cams:
                j = int(c.stream.index_at(t)[0])
                d_full = np.asarray(c.stream["depth"][j])
                d = d_full[::k, ::k]
                m = None
                if c.gt_mask is not None:
                    from vtrack.eval.oracle import read_gt_mask

                    m = read_gt_mask(c.gt_mask, j)[::k, ::k]
                raw["cams"].append((c, d, m))
                if c.tracks is not None:  # the colour term: RGB, and depth at full resolution for its tracks
                    raw.setdefault("rgb", {})[c.name] = np.asarray(c.stream["rgb"][j])
                    raw.setdefault("depth_full", {})[c.name] = d_full
        if touch:
            raw["touch"] = self.read_touch(i)
        return raw

    def read_touch(self, i: int) -> list[tuple[str, Any]]:
        """``(sensor, decoded input)`` of frame ``i`` for each tactile sensor (the newest tactile frame at the frame's
        time; sensors the hand does not mount are left out); empty without touch."""
        out: list[tuple[str, Any]] = []
        if self.touch is None:
            return out
        t = float(self.times[i])
        for s in self.touch.sensors:
            if self.sensor_poses and s not in self.sensor_poses:
                continue
            j = int(self.touch.streams[s].index_at(t)[0])
            out.append((s, self.touch.read(s, j)))
        return out

    def frame_sensor_poses(self, i: int) -> dict[str, np.ndarray]:
        """``T_world_sensor`` (4x4, m) of each mounted sensor at frame ``i`` (NaN where the joints are unknown)."""
        return {s: P[i] for s, P in self.sensor_poses.items()}

    def touch_contacts(
        self, raw_touch: list[tuple[str, Any]], poses: dict[str, np.ndarray]
    ) -> list[tuple[str, Contact]]:
        """The contacts of one time step: ``(sensor, Contact)`` for each entry of ``raw_touch`` (what
        :meth:`read_touch` gave, or contacts already computed, kept as they are) whose sensor has a finite pose in
        ``poses``, in ``raw_touch``'s order. The images go through their pipelines together
        (:meth:`~vtrack.frames.touch.TouchSource.contacts`: the same contacts as one by one, less CPU). The pipelines
        keep state from frame to frame (a background taken from a frame), so one caller feeds them every frame in
        order: :meth:`build`, or the process that computes the contacts for it (:mod:`vtrack.frames.prefetch`)."""
        keep = [(s, d) for s, d in raw_touch if s in poses and np.all(np.isfinite(poses[s]))]
        todo = [(s, d) for s, d in keep if not isinstance(d, Contact)]
        assert self.touch is not None or not todo
        batched = dict(zip([s for s, _ in todo], self.touch.contacts(todo), strict=True)) if todo else {}  # type: ignore[union-attr]
        return [(s, d if isinstance(d, Contact) else batched[s]) for s, d in keep]

    def build(self, raw: dict) -> Frame:
        """World-frame observations from decoded arrays (the per-frame work a live pipeline does)."""
        if "q" in raw:  # live: the newest joint state rather than the session's interpolated one
            t = float(raw["t"])
            q = None if raw["q"] is None else np.asarray(raw["q"], np.float64)
            poses = {s: P[0] for s, P in self._sensor_poses(None if q is None else q[None]).items()}
        else:
            i = int(raw["i"])
            t = float(self.times[i])
            q = None if self.q is None else self.q[i]
            poses = self.frame_sensor_poses(i)
        info: dict = {}
        cids: list = []
        cpts: list[np.ndarray] = []
        corg: list[np.ndarray] = []
        tp, tn, pen, sid, free = [], [], [], [], []
        in_contact: list[tuple[str, np.ndarray, Contact]] = []  # for the gel points beside the patches (see below)
        contacts: dict[str, Contact] = {}
        # a Contact already computed is kept (the live pipeline runs the tactile pipeline as the images arrive; the
        # offline prefetch in a process of its own); sensors without a finite pose are left out
        for s, c in self.touch_contacts(raw["touch"], poses):
            T_ws = poses[s]
            contacts[s] = c
            if c.in_contact:
                tp.append(se3.transform_points(T_ws, c.points))
                tn.append(-se3.rotate_vectors(T_ws, c.normals))
                pen.append(c.penetration_mm)
                sid.append(np.full(len(c.points), self.touch.sensors.index(s)))  # type: ignore[union-attr]
                in_contact.append((s, T_ws, c))
            elif c.valid:
                free.append(se3.transform_points(T_ws, self._gel(s)))
        touch_points = _cat(tp)
        vis, masks = [], {}
        for c, d, m in raw["cams"]:
            info.setdefault("camera_origin", c.T_wc[:3, 3].copy())
            cam = c.strided(self.depth_stride, d.shape)
            z = cam.depth_to_meters(d, c.depth_scale).astype(np.float32)
            z = np.where(np.isfinite(z) & (z > 0), z, 0.0).astype(np.float32)
            if c.segmenter is not None:
                sensor_pos = np.array([P[:3, 3] for P in poses.values() if np.all(np.isfinite(P))])
                res = c.segmenter.segment(
                    z,
                    q,
                    contacts_world=touch_points if len(touch_points) else None,
                    sensor_positions_world=sensor_pos if len(sensor_pos) else None,
                )
                mask = res.mask
                colour_mask = res.colour_mask if res.colour_mask is not None else mask
                if res.info.get("empty_reason"):
                    info.setdefault("segmentation", {})[c.name] = res.info["empty_reason"]
                if m is not None:  # a split oracle: one of the mask's two uses gets the renderer's
                    mask, colour_mask = (m > 0, colour_mask) if self.segmentation == "gt_points" else (mask, m > 0)
            else:
                mask = m > 0 if m is not None else z > 0
                colour_mask = mask
            masks[c.name] = mask
            pts, _ = cam.unproject(z, mask=mask, depth_scale=1.0)
            if len(pts):
                vis.append(se3.transform_points(c.T_wc, pts))
            rgb = raw.get("rgb", {}).get(c.name)
            if c.tracks is not None and rgb is not None:
                # RGB as it is: the tracks convert to grey only the object's box
                ids, P = self._colour_tracks(c, rgb, z, colour_mask, raw.get("depth_full", {}).get(c.name))
                cids.append(ids)
                cpts.append(P)
                corg.append(np.repeat(c.T_wc[None, :3, 3], len(P), axis=0))
        if in_contact and sum(len(v) for v in vis) < self.contact_free_max_vision:
            # gel points beside the contact patches, only in frames without (enough) vision: built only then
            free.extend(se3.transform_points(T_ws, self._beside_patch(s, c)) for s, T_ws, c in in_contact)
        return Frame(
            t=t,
            vision_points=_cat(vis),
            touch_points=touch_points,
            touch_normals=_cat(tn),
            touch_penetration_mm=_cat(pen, 0),
            touch_sensor=_cat(sid, 0).astype(np.int64),
            free_points=_cat(free),
            sensor_poses=poses,
            q=q,
            vision_mask=masks,
            contacts=contacts,
            info=info,
            colour_ids=_cat(cids, 0).astype(np.int64),
            colour_points=_cat(cpts),
            colour_origins=_cat(corg),
        )

    def _colour_tracks(
        self, c: CameraView, image: np.ndarray, z: np.ndarray, mask: np.ndarray, depth_full: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Camera ``c``'s feature tracks in this frame: ids (made unique across cameras) and world points of the
        tracks on the object mask with a valid depth (``z``, ``mask``: metres and mask at the depth stride; the depth
        of a track is read at full resolution from ``depth_full`` when given, and must agree with the strided one
        within ``_COLOUR_DEPTH_AGREE_M``: a track beside an occluding edge reads the occluder)."""
        from vtrack.tracking.colour import backproject

        k = self.depth_stride
        hw = image.shape[:2]  # ``image``: the camera's RGB (H, W, 3) or grey (H, W) image
        full = upsample_mask(mask, hw) if mask.shape != hw else mask
        if c.tracks.opts.shading != "local" and depth_full is not None and depth_full.shape == hw:
            # the shading model's normals come from the full-resolution depth
            scale = c.depth_scale if depth_full.dtype.kind in "ui" else 1.0
            ids, uv = c.tracks.update(image, full[: hw[0], : hw[1]], depth_full, c.cam.K, scale)
        else:
            ids, uv = c.tracks.update(image, full[: hw[0], : hw[1]])
        X, ok = backproject(uv, np.where(mask, z, 0.0), k, c.cam.K)
        if depth_full is not None and depth_full.shape == hw:
            scale = c.depth_scale if depth_full.dtype.kind in "ui" else 1.0
            Xf, okf = backproject(uv, depth_full, 1, c.cam.K, scale, patch=2)
            ok &= okf & (np.abs(Xf[:, 2] - X[:, 2]) < _COLOUR_DEPTH_AGREE_M)
            X = Xf
        cam_no = self.cams.index(c)
        return ids[ok] * len(self.cams) + cam_no, se3.transform_points(c.T_wc, X[ok])

    def _gel(self, sensor: str, n_rows: int = 5, n_cols: int = 4) -> np.ndarray:
        """:func:`~vtrack.frames.touch.gel_free_points` of a sensor (fixed per sensor: built once)."""
        key = (sensor, n_rows, n_cols)
        G = self._gel_grid.get(key)
        if G is None:
            w, h = self.touch.size[sensor]  # type: ignore[union-attr]
            G = self._gel_grid[key] = gel_free_points(w, h, self.touch.mm_per_px[sensor], n_rows, n_cols)  # type: ignore[union-attr]
        return G

    def _beside_patch(self, sensor: str, c: Contact) -> np.ndarray:
        """Gel-surface points (sensor frame, m; a 11 x 8 grid, ~3 mm apart on a DIGIT) farther than
        ``contact_free_margin_m`` from the contact patch ``c.points`` (sensor xy)."""
        from scipy.spatial import cKDTree

        G = self._gel(sensor, 11, 8)
        d, _ = cKDTree(c.points[:, :2]).query(G[:, :2])
        return G[d > self.contact_free_margin_m]

    def frame(self, i: int) -> tuple[Frame, float]:
        """Frame ``i`` and the milliseconds spent building it from decoded arrays."""
        raw = self.read(i)
        t0 = time.perf_counter()
        fr = self.build(raw)
        return fr, (time.perf_counter() - t0) * 1e3

    def __iter__(self) -> Iterator[tuple[Frame, float]]:
        for i in range(len(self)):
            yield self.frame(i)
