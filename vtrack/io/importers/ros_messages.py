"""Turn decoded ROS messages (sensor_msgs Image / CompressedImage / CameraInfo / JointState,
tf2_msgs TFMessage) into session frames. Shared by the ROS bag and MCAP importers.

Topic roles (automatic, overridable with ``topic_map``):

- ``Image``/``CompressedImage`` on a topic whose name contains ``digit``, ``gelsight`` or ``tactile``
  -> ``tactile/<name>`` (BGR image); name from the topic (``/digit_index/image_raw`` -> ``digit_index``).
- other ``Image``/``CompressedImage``: depth if the topic or encoding says depth (``16UC1``/``32FC1``,
  ``depth`` in the name), else colour -> ``camera/<name>`` with ``<name>`` = the topic's first
  component (``/camera/color/image_raw`` -> ``camera``). Colour and depth are paired by header time
  (within ``pair_tolerance_s``); unpaired frames are skipped and counted.
- ``CameraInfo`` -> the camera's intrinsics (first message).
- ``JointState`` -> ``joints`` (positions, columns in the first message's name order).
- ``TFMessage`` -> ``gt/object_pose`` for transforms whose child frame is ``object_frame``
  (relative to ``world_frame``); static transforms world->camera give camera extrinsics.

``topic_map`` entries: ``{"/topic": "camera/<cam>:rgb" | "camera/<cam>:depth" | "camera/<cam>:info" |
"tactile/<name>" | "joints" | "ignore"}``.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError
from vtrack.io.importers.report import ImportReport
from vtrack.io.streams import encode_depth

IMAGE_TYPES = {"sensor_msgs/msg/Image", "sensor_msgs/Image"}
COMPRESSED_TYPES = {"sensor_msgs/msg/CompressedImage", "sensor_msgs/CompressedImage"}
INFO_TYPES = {"sensor_msgs/msg/CameraInfo", "sensor_msgs/CameraInfo"}
JOINT_TYPES = {"sensor_msgs/msg/JointState", "sensor_msgs/JointState"}
TF_TYPES = {"tf2_msgs/msg/TFMessage", "tf2_msgs/TFMessage"}
_TACTILE_HINTS = ("digit", "gelsight", "tactile", "gel")


def norm_type(msgtype: str) -> str:
    """``sensor_msgs/Image`` (ROS 1) -> ``sensor_msgs/msg/Image``."""
    parts = msgtype.split("/")
    return f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else msgtype


def stamp_seconds(header: Any) -> float:
    st = header.stamp
    return float(st.sec) + 1e-9 * float(st.nanosec)


def _name_from_topic(topic: str, tactile: bool) -> str:
    parts = [p for p in topic.strip("/").split("/") if p]
    if not parts:
        return "cam0"
    if tactile:
        for p in parts:
            if any(h in p.lower() for h in _TACTILE_HINTS):
                return p.replace("-", "_")
        return parts[0]
    return parts[0].replace("-", "_")


def classify(topic: str, msgtype: str, topic_map: dict[str, str]) -> tuple[str, str] | None:
    """Role of a topic as ``(stream, part)``, or None when it is not imported."""
    mt = norm_type(msgtype)
    if topic in topic_map:
        role = topic_map[topic]
        if role == "ignore":
            return None
        stream, _, part = role.partition(":")
        return stream, part
    low = topic.lower()
    if mt in IMAGE_TYPES or mt in COMPRESSED_TYPES:
        if any(h in low for h in _TACTILE_HINTS):
            return f"tactile/{_name_from_topic(topic, True)}", "image"
        part = "depth" if "depth" in low else "rgb"
        return f"camera/{_name_from_topic(topic, False)}", part
    if mt in INFO_TYPES:
        if any(h in low for h in _TACTILE_HINTS):
            return None
        # Depth camera infos of aligned depth duplicate the colour one; prefer colour.
        if "depth" in low and "aligned" not in low:
            return None
        return f"camera/{_name_from_topic(topic, False)}", "info"
    if mt in JOINT_TYPES:
        return "joints", "q"
    if mt in TF_TYPES:
        return "tf", "static" if "static" in low else "dynamic"
    return None


def decode_image(msg: Any, msgtype: str, where: str) -> np.ndarray:
    """Decode an Image / CompressedImage message to a numpy array.

    Colour -> uint8 HxWx3 in **RGB** order; mono8 -> HxW uint8; ``16UC1`` -> uint16 (mm);
    ``32FC1`` -> float32 (m).
    """
    import cv2

    mt = norm_type(msgtype)
    if mt in COMPRESSED_TYPES:
        fmt = str(msg.format).lower()
        buf = np.asarray(msg.data, dtype=np.uint8)
        if "compresseddepth" in fmt:
            # image_transport's compressedDepth: 12-byte config header, then a PNG.
            buf = buf[12:]
            img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
        else:
            img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
        if img is None:
            raise InputError("cannot decode compressed image", field=where, got=msg.format)
        if img.ndim == 3 and img.shape[2] == 3:
            img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
        elif img.ndim == 3 and img.shape[2] == 4:
            img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGB)
        return img
    enc = str(msg.encoding).lower()
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    raw = np.asarray(msg.data, dtype=np.uint8)
    table = {
        "rgb8": (np.uint8, 3),
        "bgr8": (np.uint8, 3),
        "rgba8": (np.uint8, 4),
        "bgra8": (np.uint8, 4),
        "mono8": (np.uint8, 1),
        "8uc1": (np.uint8, 1),
        "8uc3": (np.uint8, 3),
        "16uc1": (np.uint16, 1),
        "mono16": (np.uint16, 1),
        "32fc1": (np.float32, 1),
    }
    if enc not in table:
        raise InputError("unsupported image encoding", field=where, expected=f"one of {sorted(table)}", got=enc)
    dt, ch = table[enc]
    item = np.dtype(dt).itemsize
    if raw.size < h * step or step < w * ch * item:
        raise InputError(
            "image data shorter than height x step (truncated message?)",
            field=where,
            expected=f"{h}x{step} bytes",
            got=raw.size,
        )
    rows = raw[: h * step].reshape(h, step)[:, : w * ch * item]
    arr = np.ascontiguousarray(rows).view(dt)
    if int(getattr(msg, "is_bigendian", 0)) and item > 1:
        arr = arr.byteswap()
    arr = arr.reshape(h, w, ch) if ch > 1 else arr.reshape(h, w)
    if enc in ("bgr8", "8uc3"):
        arr = arr[..., ::-1]
    elif enc == "rgba8":
        arr = arr[..., :3]
    elif enc == "bgra8":
        arr = arr[..., 2::-1]
    return np.ascontiguousarray(arr)


class _Cam:
    def __init__(self) -> None:
        self.rgb: deque = deque()
        self.depth: deque = deque()
        self.K: np.ndarray | None = None
        self.size: tuple[int, int] | None = None
        self.frame_id = ""


class RosSessionBuilder:
    """Collects decoded ROS messages and writes them to a session (streams declared lazily).

    Call :meth:`prepare` with CameraInfo / static tf messages first (a quick first pass), then
    :meth:`add` every message in log order, then :meth:`finish`.
    """

    def __init__(
        self,
        out: str | Path,
        report: ImportReport,
        *,
        topic_map: dict[str, str] | None = None,
        overwrite: bool = False,
        flush_every: int = 256,
        pair_tolerance_s: float = 0.02,
        world_frame: str = "world",
        object_frame: str = "object",
        source: Path | None = None,
        tactile_type: str | None = None,
    ) -> None:
        self.out = Path(out)
        self.report = report
        self.topic_map = dict(topic_map or {})
        self.overwrite = overwrite
        self.flush_every = flush_every
        self.tol = pair_tolerance_s
        self.world_frame = world_frame
        self.object_frame = object_frame
        self.source = source
        self.tactile_type = tactile_type
        self.cams: dict[str, _Cam] = {}
        self.static_tf: dict[str, np.ndarray] = {}  # child frame -> T_world_child
        self.pending: list[tuple[str, float, dict]] = []  # frames buffered before the writer exists
        self.writer: Any = None
        self.joint_names: list[str] | None = None
        self.tactile: dict[str, tuple[int, int]] = {}
        self.last_t: dict[str, float] = {}
        self.rates: dict[str, list[float]] = {}

    # -- first pass ---------------------------------------------------------------------------
    def prepare(self, topic: str, msgtype: str, msg: Any) -> None:
        role = classify(topic, msgtype, self.topic_map)
        if role is None:
            return
        stream, part = role
        if part == "info":
            cam = self.cams.setdefault(stream, _Cam())
            if cam.K is None:
                K = np.asarray(getattr(msg, "k", getattr(msg, "K", None)), dtype=np.float64).reshape(3, 3)
                if K[0, 0] > 0 and K[1, 1] > 0:
                    cam.K = K
                    cam.size = (int(msg.width), int(msg.height))
                    cam.frame_id = str(msg.header.frame_id)
        elif stream == "tf" and part == "static":
            self._tf(msg, static=True)

    def _tf(self, msg: Any, static: bool, t_log: float | None = None) -> None:
        from vtrack.geometry import se3

        for tr in msg.transforms:
            parent = str(tr.header.frame_id).lstrip("/")
            child = str(tr.child_frame_id).lstrip("/")
            r, p = tr.transform.rotation, tr.transform.translation
            T = se3.make_transform(se3.quat_to_matrix(np.array([r.x, r.y, r.z, r.w])), np.array([p.x, p.y, p.z]))
            if parent != self.world_frame:
                if not static:
                    self.report.skip(f"tf {parent}->{child}: parent is not '{self.world_frame}'")
                continue
            if static:
                self.static_tf[child] = T
            elif child == self.object_frame:
                t = stamp_seconds(tr.header)
                self._emit("gt/object_pose", t, {"T_world_object": T})
            else:
                self.report.skip(f"tf {parent}->{child}: not the object frame '{self.object_frame}'")

    # -- second pass --------------------------------------------------------------------------
    def add(self, topic: str, msgtype: str, msg: Any, t_log: float) -> None:
        role = classify(topic, msgtype, self.topic_map)
        if role is None:
            why = "ignored (--map)" if self.topic_map.get(topic) == "ignore" else "not imported"
            self.report.skip(f"topic {topic} ({norm_type(msgtype)}): {why}")
            return
        stream, part = role
        if part == "info" or (stream == "tf" and part == "static"):
            return  # handled in prepare()
        if stream == "tf":
            self._tf(msg, static=False, t_log=t_log)
            return
        if stream == "joints":
            names = [str(n) for n in msg.name]
            pos = np.asarray(msg.position, dtype=np.float64)
            if self.joint_names is None:
                self.joint_names = names
            if names != self.joint_names:
                # Reorder when the same joints come in another order; skip other subsets.
                if sorted(names) == sorted(self.joint_names) and len(pos) == len(names):
                    idx = {n: i for i, n in enumerate(names)}
                    pos = pos[[idx[n] for n in self.joint_names]]
                else:
                    self.report.skip(f"topic {topic}: JointState with different joint names")
                    return
            if pos.shape != (len(self.joint_names),) or not np.all(np.isfinite(pos)):
                self.report.skip(f"topic {topic}: JointState with missing or non-finite positions")
                return
            t = stamp_seconds(msg.header) or t_log
            self._emit("joints", t, {"q": pos})
            return
        t = stamp_seconds(msg.header) or t_log
        img = decode_image(msg, msgtype, where=f"{self.source}:{topic}")
        if stream.startswith("tactile/"):
            if img.ndim == 2:
                img = np.repeat(img[..., None], 3, axis=2)
            if img.dtype != np.uint8:
                self.report.skip(f"topic {topic}: non-8-bit tactile image")
                return
            self._emit(stream, t, {"image": np.ascontiguousarray(img[..., ::-1])})  # RGB -> BGR
            return
        cam = self.cams.setdefault(stream, _Cam())
        if part == "depth" or img.dtype != np.uint8:
            if img.ndim != 2:
                self.report.skip(f"topic {topic}: depth image with channels")
                return
            cam.depth.append((t, encode_depth(img, 0.001)))
        else:
            if img.ndim == 2:
                img = np.repeat(img[..., None], 3, axis=2)
            cam.rgb.append((t, img))
        self._pair(stream, cam)

    def _pair(self, stream: str, cam: _Cam) -> None:
        while cam.rgb and cam.depth:
            (ta, a), (tb, b) = cam.rgb[0], cam.depth[0]
            if abs(ta - tb) <= self.tol:
                cam.rgb.popleft()
                cam.depth.popleft()
                if a.shape[:2] != b.shape:
                    self.report.skip(f"{stream}: colour/depth size mismatch (depth not aligned to colour)")
                    continue
                self._emit(stream, ta, {"rgb": a, "depth": b})
            elif ta < tb:
                cam.rgb.popleft()
                self.report.skip(f"{stream}: colour frame without depth within {self.tol * 1000:.0f} ms")
            else:
                cam.depth.popleft()
                self.report.skip(f"{stream}: depth frame without colour within {self.tol * 1000:.0f} ms")

    # -- writing --------------------------------------------------------------------------------
    _PENDING_LIMIT = 200  # frames buffered to learn rates/shapes before the writer is created

    def _emit(self, stream: str, t: float, values: dict) -> None:
        if t <= self.last_t.get(stream, -np.inf):
            self.report.skip(f"{stream}: non-increasing timestamp")
            return
        self.last_t[stream] = t
        self.rates.setdefault(stream, []).append(t)
        if self.writer is None:
            self.pending.append((stream, t, values))
            if len(self.pending) >= self._PENDING_LIMIT:
                self._open()
            return
        self._write(stream, t, values)

    def _write(self, stream: str, t: float, values: dict) -> None:
        w = self.writer
        if stream not in w._streams:
            self._declare(stream, values)
        spec = w._streams[stream]["spec"]
        for k, v in values.items():
            if tuple(spec.fields[k].shape) != v.shape:
                self.report.skip(f"{stream}: frame size changed mid-recording")
                return
        w.append(stream, t, **values)

    def _rate(self, stream: str, default: float) -> float:
        ts = np.asarray(self.rates.get(stream, []))
        if len(ts) < 2:
            return default
        dt = np.median(np.diff(ts))
        return float(1.0 / dt) if dt > 0 else default

    def _scene_entry(self, stream: str, v: dict) -> None:
        from vtrack.io.importers.scene_build import camera_entry, tactile_entry
        from vtrack.tactile.sensors import guess_sensor_type

        if stream.startswith("camera/"):
            name = stream.split("/", 1)[1]
            h, w = v["depth"].shape
            cam = self.cams.get(stream) or _Cam()
            K = cam.K
            if K is None:
                K = np.array([[float(w), 0, (w - 1) / 2], [0, float(w), (h - 1) / 2], [0, 0, 1]])
                self.report.note(f"{stream}: no CameraInfo, assumed fx = fy = width px")
            elif cam.size != (w, h):
                self.report.note(f"{stream}: CameraInfo size {cam.size} differs from images ({w}x{h})")
            T = self.static_tf.get(cam.frame_id) if cam.frame_id else None
            if T is None:
                self.report.note(f"{stream}: no static tf {self.world_frame}->camera, camera at world origin")
            self.scene.setdefault("cameras", []).append(camera_entry(name, K, w, h, T, 0.001, self._rate(stream, 30.0)))
        elif stream.startswith("tactile/"):
            name = stream.split("/", 1)[1]
            h, w = v["image"].shape[:2]
            ttype = self.tactile_type or guess_sensor_type(name)
            self.scene.setdefault("tactile", []).append(tactile_entry(name, ttype, w, h, self._rate(stream, 60.0)))

    def _declare(self, stream: str, v: dict) -> None:
        """Add a stream (and its scene entry) to the open writer."""
        from vtrack.io.importers.scene_build import finalize_scene, write_scene_yaml
        from vtrack.io.streams import camera_stream, joints_stream, pose_stream, tactile_stream
        from vtrack.scene.load import scene_from_dict

        self._scene_entry(stream, v)
        scene_dict = finalize_scene(self.scene, source=self.source)
        self.writer.manifest["scene"] = scene_dict
        write_scene_yaml(self.writer, scene_dict)
        sc = scene_from_dict(scene_dict, check_files=False)
        name = stream.split("/", 1)[-1]
        if stream.startswith("camera/"):
            spec = camera_stream(sc.camera_by_name(name), with_mask=False)
        elif stream.startswith("tactile/"):
            spec = tactile_stream(sc.tactile_by_name(name))
        elif stream == "joints":
            spec = joints_stream(self.joint_names or [], self._rate(stream, 0) or None)
        else:
            spec = pose_stream(rate_hz=self._rate(stream, 0) or None)
        self.writer.add_stream(stream, spec)

    def _open(self) -> None:
        from vtrack.io.importers.scene_build import finalize_scene
        from vtrack.io.session import SessionWriter

        name = (self.source or self.out).stem
        self.scene: dict[str, Any] = {
            "name": f"import_{name}",
            "description": f"imported from {self.source}",
            "object": {"name": "object"},
        }
        self.writer = SessionWriter(
            self.out,
            finalize_scene(self.scene),
            overwrite=self.overwrite,
            flush_every=self.flush_every,
            info={"importer": "ros", "source": str(self.source)},
        )
        for stream, t, v in self.pending:
            self._write(stream, t, v)
        self.pending = []

    def finish(self) -> ImportReport:
        for stream, cam in self.cams.items():
            if cam.rgb:
                self.report.skip(f"{stream}: colour frame without depth within {self.tol * 1000:.0f} ms", len(cam.rgb))
            if cam.depth:
                self.report.skip(
                    f"{stream}: depth frame without colour within {self.tol * 1000:.0f} ms", len(cam.depth)
                )
        if self.writer is None:
            if not self.pending:
                raise InputError(
                    "no importable message (Image, CompressedImage, JointState, tf) found", path=self.source
                )
            self._open()
        self.writer.close()
        self.report.frames = {k: v["n"] for k, v in self.writer._streams.items()}
        return self.report


def run_ros_import(
    src: Path, out: str | Path, what: str, read: Callable[[RosSessionBuilder], None], **options: Any
) -> ImportReport:
    """The frame every ROS importer shares: a :class:`RosSessionBuilder` for ``out`` (``options`` = its
    keyword options: topic_map, overwrite, flush_every, pair_tolerance_s, world_frame, object_frame,
    tactile_type), ``read(builder)`` feeds it the file's messages, a reader's own exception (truncated or
    corrupt file) becomes one :class:`InputError` naming ``src`` (what was written so far is flushed),
    then the session is finished and the import timed (``report.seconds``)."""
    t0 = time.perf_counter()
    report = ImportReport(source=src, session=Path(out))
    b = RosSessionBuilder(out, report, source=src, **options)
    try:
        read(b)
    except InputError:
        raise
    except Exception as e:  # readers raise their own errors, EndOfFile, struct / sqlite errors for bad files
        if b.writer is not None:
            b.writer.flush()
        raise InputError(f"cannot read {what} ({type(e).__name__}: {e})", path=src) from None
    report = b.finish()
    report.seconds = time.perf_counter() - t0
    return report
