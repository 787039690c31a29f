"""Turn a recorded session into :class:`~vtrack.tracking.frame.TrackingFrame` objects.

- Time base: the first camera's timestamps when the session has a camera (also for touch-only
  runs, so modes are compared on the same frames), else the first tactile stream's, else the
  ground-truth pose stream's.
- Vision: each camera's nearest depth frame, segmented with its ``mask`` when present,
  unprojected with a pixel stride and transformed by the stream's ``T_world_camera``.
- Touch: the ground-truth tactile height maps ``gt/tactile/<sensor>`` (``height_mm``,
  ``contact``) lifted with :func:`vtrack.geometry.tactile_frame.height_to_points`, placed in the
  world with ``HandKinematics.sensor_poses_at`` (joints interpolated at the frame time). Object
  normals are minus the gel normals. Sensors without contact contribute gel-surface points
  (``free_points``) for the non-penetration term.
- Robustness: NaN joints or depth pixels drop the affected data for that frame only.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vtrack.errors import InputError
from vtrack.geometry import se3
from vtrack.geometry.camera import PinholeCamera
from vtrack.geometry.tactile_frame import height_to_points, pixel_grid_to_sensor_xy
from vtrack.tracking.frame import TrackingFrame


@dataclass
class _Cam:
    name: str
    stream: object
    cam: PinholeCamera
    T_wc: np.ndarray
    depth_scale: float
    has_mask: bool
    _strided: dict = field(default_factory=dict)

    def strided(self, k: int, shape: tuple[int, int]) -> PinholeCamera:
        """The camera of the image subsampled as ``image[::k, ::k]`` (pixel (r, c) -> (k r, k c))."""
        if k not in self._strided:
            c = self.cam
            self._strided[k] = PinholeCamera(shape[1], shape[0], c.fx / k, c.fy / k, c.cx / k, c.cy / k)
        return self._strided[k]


def _lift_contact(h: np.ndarray, contact: np.ndarray, mm_per_px: float, stride: int
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Sensor-frame contact points + gel normals, computed on the contact's bounding box only.

    Equivalent to ``height_to_points(h, mm_per_px, mask=contact, stride)`` up to the sampling phase,
    but the gradient is taken on a small crop (the full 320x240 map is mostly empty).
    """
    H, W = h.shape
    rows, cols = np.nonzero(contact)
    r0, r1 = max(rows.min() - 2, 0), min(rows.max() + 3, H)
    c0, c1 = max(cols.min() - 2, 0), min(cols.max() + 3, W)
    hc, mc = h[r0:r1, c0:c1], contact[r0:r1, c0:c1]
    P, N = height_to_points(hc, mm_per_px, mask=mc, stride=stride)
    if len(P) == 0:  # the stride missed a tiny patch: take it whole
        P, N = height_to_points(hc, mm_per_px, mask=mc, stride=1)
    s = mm_per_px / 1000.0
    # crop-centred -> full-image-centred coordinates
    P[:, 0] += ((c0 + (c1 - c0 - 1) / 2.0) - (W - 1) / 2.0) * s
    P[:, 1] += ((r0 + (r1 - r0 - 1) / 2.0) - (H - 1) / 2.0) * s
    return P, N


@dataclass
class SessionFrames:
    """Frames of a session for tracking, with ground truth where the session has it.

    Args:
        session_dir: session directory.
        modalities: subset of ("vision", "touch").
        depth_stride: pixel stride for unprojection.
        touch_stride: pixel stride for lifting tactile height maps.
        max_frames: keep only the first frames (0 = all).
    """

    session_dir: str | Path
    modalities: tuple[str, ...] = ("vision", "touch")
    depth_stride: int = 4
    touch_stride: int = 6
    max_frames: int = 0
    cams: list[_Cam] = field(default_factory=list, init=False)
    times: np.ndarray = field(default=None, init=False)  # type: ignore[assignment]
    gt: np.ndarray | None = field(default=None, init=False)

    def __post_init__(self) -> None:
        from vtrack.io.session import open_session

        bad = set(self.modalities) - {"vision", "touch"}
        if bad or not self.modalities:
            raise InputError("unknown modality", field="modalities", expected="vision and/or touch",
                             got=list(self.modalities))
        self.reader = r = open_session(self.session_dir)
        self.path = Path(self.session_dir)
        self.scene = r.scene(check_files=False)
        cam_streams = {k: s for k, s in r.streams.items() if k.startswith("camera/") and s.n}
        self.tactile_gt = {k.split("/", 2)[2]: s for k, s in r.streams.items()
                           if k.startswith("gt/tactile/") and s.n}
        for name, s in cam_streams.items():
            a = s.attrs
            K = np.asarray(a["K"], dtype=np.float64)
            cam = PinholeCamera(int(a["width"]), int(a["height"]), K[0, 0], K[1, 1], K[0, 2], K[1, 2])
            self.cams.append(_Cam(name, s, cam, np.asarray(a["T_world_camera"], dtype=np.float64),
                                  float(a.get("depth_scale", 0.001)), "mask" in s.fields))
        if self.cams:
            t = self.cams[0].stream.t
        elif self.tactile_gt:
            t = next(iter(self.tactile_gt.values())).t
        elif "gt/object_pose" in r:
            t = r["gt/object_pose"].t
        else:
            raise InputError("session has no camera, tactile or pose stream to track on", path=self.path)
        if "gt/object_pose" in r and r["gt/object_pose"].n:
            gs = r["gt/object_pose"]
            t = t[(t >= gs.t[0] - 1e-9) & (t <= gs.t[-1] + 1e-9)]  # GT defined for every tracked frame
        if self.max_frames:
            t = t[: self.max_frames]
        if len(t) == 0:
            raise InputError("no frames to track", path=self.path)
        self.times = np.asarray(t, dtype=np.float64)
        if "gt/object_pose" in r and r["gt/object_pose"].n:
            self.gt = r["gt/object_pose"].sample("T_world_object", self.times, mode="linear")
        self.mesh_path = self.path / "assets" / "object.ply"
        self._sensor_poses = self._compute_sensor_poses() if "touch" in self.modalities else {}

    def _compute_sensor_poses(self) -> dict[str, np.ndarray]:
        """T_world_sensor (N, 4, 4) per sensor at the frame times; NaN rows where joints are NaN."""
        if not self.tactile_gt:
            return {}
        if self.scene.hand is None or "joints" not in self.reader:
            raise InputError("touch needs the hand (scene.hand) and the joints stream", path=self.path,
                             field="joints")
        from vtrack.kinematics.hand import HandKinematics

        kin = HandKinematics.from_scene(self.scene)
        js = self.reader["joints"]
        q = js.sample("q", self.times, mode="linear")
        q = kin.reorder(q, js.attrs.get("joint_names"))
        ok = np.isfinite(q).all(1)
        out = {s: np.full((len(self.times), 4, 4), np.nan) for s in kin.sensor_names}
        if ok.any():
            poses = kin.sensor_poses(q[ok])
            for s, P in poses.items():
                out[s][ok] = P
        return out

    def __len__(self) -> int:
        return len(self.times)

    def frame(self, i: int) -> tuple[TrackingFrame, float]:
        """Frame ``i`` and the milliseconds spent turning decoded arrays into points."""
        t = float(self.times[i])
        raw = self.read(i)
        t0 = time.perf_counter()
        fr = self.build(t, raw)
        return fr, (time.perf_counter() - t0) * 1e3

    def read(self, i: int) -> dict:
        """Decoded arrays for frame i (disk IO, not counted as tracking time)."""
        t = float(self.times[i])
        raw: dict = {"cams": [], "touch": []}
        if "vision" in self.modalities:
            for c in self.cams:
                j = int(c.stream.index_at(t)[0])
                d = c.stream["depth"][j]
                m = c.stream["mask"][j] if c.has_mask else None
                raw["cams"].append((c, d, m))
        if "touch" in self.modalities:
            for s, st in self.tactile_gt.items():
                if s not in self._sensor_poses:
                    continue
                j = int(st.index_at(t)[0])
                raw["touch"].append((s, st["height_mm"][j], st["contact"][j],
                                     float(st.attrs.get("mm_per_px", 0.1)), self._sensor_poses[s][i]))
        return raw

    def build(self, t: float, raw: dict) -> TrackingFrame:
        """Points from decoded arrays (the per-frame work a live pipeline does)."""
        vis = []
        info: dict = {}
        k = max(1, int(self.depth_stride))
        for c, d, m in raw["cams"]:
            info.setdefault("camera_origin", c.T_wc[:3, 3].copy())
            # Subsample the image first (a strided image is exactly a camera with scaled intrinsics):
            # far cheaper than converting the whole image and discarding most of it.
            ds = np.asarray(d)[::k, ::k]
            cam = c.strided(k, ds.shape)
            mask = None if m is None else (np.asarray(m)[::k, ::k] > 0)
            pts, _ = cam.unproject(ds, mask=mask, depth_scale=c.depth_scale)
            if len(pts):
                vis.append(se3.transform_points(c.T_wc, pts))
        tp, tn, free = [], [], []
        for _s, h, contact, mmpp, T_ws in raw["touch"]:
            if not np.all(np.isfinite(T_ws)):
                continue
            cm = (np.asarray(contact) > 0) & np.isfinite(h)
            if cm.sum() >= 3:
                P, N = _lift_contact(np.asarray(h), cm, mmpp, self.touch_stride)
                tp.append(se3.transform_points(T_ws, P))
                tn.append(-se3.rotate_vectors(T_ws, N))
            elif not cm.any():  # a sensor with 1-2 contact pixels is neither reliable contact nor free
                H, W = np.shape(h)
                rows, cols = np.meshgrid(np.linspace(0, H - 1, 5), np.linspace(0, W - 1, 4), indexing="ij")
                xy = pixel_grid_to_sensor_xy(rows.ravel(), cols.ravel(), W, H, mmpp)
                Pf = np.concatenate([xy, np.zeros((len(xy), 1))], axis=1)
                free.append(se3.transform_points(T_ws, Pf))
        return TrackingFrame(
            t=t,
            vision_points=np.concatenate(vis) if vis else None,
            touch_points=np.concatenate(tp) if tp else None,
            touch_normals=np.concatenate(tn) if tn else None,
            free_points=np.concatenate(free) if free else None,
            info=info,
        )

    def __iter__(self) -> Iterator[tuple[TrackingFrame, float]]:
        for i in range(len(self)):
            yield self.frame(i)
