"""Record DIGIT / GelSight Mini tactile cameras (UVC, read with OpenCV) into a session, together
with the hand's joint states.

Each camera is read by its own thread (``cv2.VideoCapture.read`` blocks until the next frame) into
a short queue; the main thread writes frames and polls the joint source, so one slow camera never
stalls the others. When the writer falls behind, the oldest queued frames are dropped and counted.

Sources: a device index (``0``), a device path (``/dev/video2``), ``serial:<S>`` (resolved through
``/dev/v4l/by-id/*<S>*``, which is how DIGIT and GelSight Mini serials appear on Linux), or a
video file (for tests and replays). For devices the resolution and frame rate are set from the
sensor type (:data:`~vtrack.tactile.sensors.SENSOR_PRESETS`).

Clock: devices are stamped with ``time.time()`` at frame arrival (s, same clock as ROS stamps);
video files with the file's own frame times (``CAP_PROP_POS_MSEC``) offset to the start time.
"""

from __future__ import annotations

import glob
import os
import queue
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError
from vtrack.io.recorders.base import RecordingStats, StopFlag, recording_writer
from vtrack.io.recorders.joints import JointSource
from vtrack.tactile.sensors import SENSOR_PRESETS


@dataclass
class TactileCamera:
    """One tactile camera to record.

    Attributes:
        name: sensor name in the session (``tactile/<name>``), e.g. ``digit_index``.
        source: device index, ``/dev/videoN``, ``serial:<S>`` or a video file path.
        type: ``digit``, ``gelsight_mini`` or ``gelsight``.
        rotate: rotate frames by this many degrees clockwise (0/90/180/270); ``None`` = DIGIT
            landscape frames are turned portrait (90), others unchanged.
    """

    name: str
    source: str | int
    type: str = "digit"
    rotate: int | None = None


def resolve_source(source: str | int) -> tuple[Any, bool]:
    """Turn a source spec into something ``cv2.VideoCapture`` opens; returns (arg, is_file)."""
    if isinstance(source, int) or (isinstance(source, str) and source.isdigit()):
        return int(source), False
    s = str(source)
    if s.startswith("serial:"):
        serial = s.split(":", 1)[1]
        hits = sorted(glob.glob(f"/dev/v4l/by-id/*{serial}*index0")) or sorted(glob.glob(f"/dev/v4l/by-id/*{serial}*"))
        if not hits:
            raise InputError("no video device with this serial under /dev/v4l/by-id", field="source", got=serial)
        return os.path.realpath(hits[0]), False
    p = Path(s)
    if s.startswith("/dev/"):
        if not p.exists():
            raise InputError("video device does not exist", path=p)
        return s, False
    if not p.exists():
        raise InputError("video source does not exist (device index, /dev/videoN, serial:<S> or a file)", path=p)
    return str(p), True


def open_capture(cam: TactileCamera) -> tuple[Any, bool]:
    """Open a camera; sets size/fps from the sensor type for devices. Returns (capture, is_file)."""
    import cv2

    arg, is_file = resolve_source(cam.source)
    cap = cv2.VideoCapture(arg) if is_file else cv2.VideoCapture(arg, cv2.CAP_ANY)
    if not cap.isOpened():
        raise InputError("cannot open video source", path=None if not is_file else arg, field=cam.name, got=cam.source)
    if not is_file:
        p = SENSOR_PRESETS.get(cam.type)
        if p is None:
            raise InputError(
                "unknown tactile sensor type", field=cam.name, expected=str(sorted(SENSOR_PRESETS)), got=cam.type
            )
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, p.width)
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, p.height)
        cap.set(cv2.CAP_PROP_FPS, p.fps)
    return cap, is_file


def _rotation(cam: TactileCamera, frame: np.ndarray) -> int:
    """Clockwise degrees to store ``frame`` by: the camera's own setting, else the preset's (only when the
    frame still has the camera's landscape format, so an already rotated video is left alone)."""
    if cam.rotate is not None:
        return cam.rotate
    p = SENSOR_PRESETS.get(cam.type)
    return p.rotate_deg if (p is not None and p.rotate_deg and frame.shape[1] > frame.shape[0]) else 0


def _rotate(img: np.ndarray, deg: int) -> np.ndarray:
    import cv2

    return {
        0: img,
        90: cv2.rotate(img, cv2.ROTATE_90_CLOCKWISE),
        180: cv2.rotate(img, cv2.ROTATE_180),
        270: cv2.rotate(img, cv2.ROTATE_90_COUNTERCLOCKWISE),
    }[deg % 360]


class _Reader(threading.Thread):
    """Reads one camera into a bounded queue (drops the oldest frame when full)."""

    def __init__(
        self,
        cam: TactileCamera,
        cap: Any,
        is_file: bool,
        t0: float,
        realtime: bool,
        stats: RecordingStats,
        maxsize: int = 8,
    ) -> None:
        super().__init__(daemon=True, name=f"tactile-{cam.name}")
        self.cam, self.cap, self.is_file, self.t0, self.realtime = cam, cap, is_file, t0, realtime
        self.q: queue.Queue = queue.Queue(maxsize=maxsize)
        self.stats = stats
        self.done = threading.Event()
        self.halt = threading.Event()
        self.rotate = 0
        self.error: BaseException | None = None

    def run(self) -> None:
        import cv2

        try:
            fps = self.cap.get(cv2.CAP_PROP_FPS) or 30.0
            k = 0
            while not self.halt.is_set():
                ok, frame = self.cap.read()
                if not ok or frame is None:
                    break
                if self.is_file:
                    t_rel = self.cap.get(cv2.CAP_PROP_POS_MSEC) / 1000.0
                    if t_rel <= 0 and k > 0:
                        t_rel = k / fps
                    if self.realtime:  # pace the file like a live camera
                        delay = self.t0 + t_rel - time.time()
                        if delay > 0:
                            time.sleep(delay)
                    t = self.t0 + t_rel
                else:
                    t = time.time()
                k += 1
                frame = _rotate(frame, _rotation(self.cam, frame))
                if self.is_file and not self.realtime:
                    # Not a live stream: wait for the writer instead of dropping.
                    while not self.halt.is_set():
                        try:
                            self.q.put((t, frame), timeout=0.1)
                            break
                        except queue.Full:
                            pass
                    continue
                while True:
                    try:
                        self.q.put_nowait((t, frame))
                        break
                    except queue.Full:
                        try:
                            self.q.get_nowait()
                            self.stats.drop(f"tactile/{self.cam.name}")
                        except queue.Empty:
                            pass
        except BaseException as e:  # surfaced by the main loop
            self.error = e
        finally:
            self.done.set()


def _probe(cam: TactileCamera) -> np.ndarray:
    """First frame of a camera (after rotation), to fix the stream's image size."""
    cap, _ = open_capture(cam)
    ok, frame = cap.read()
    cap.release()
    if not ok or frame is None:
        raise InputError("camera delivered no frame", field=cam.name, got=cam.source)
    return _rotate(frame, _rotation(cam, frame))


def tactile_scene(
    cams: list[TactileCamera], shapes: dict[str, tuple[int, int]], base: dict | None = None
) -> dict[str, Any]:
    """Scene with these tactile sensors (kept from ``base`` when it already declares them)."""
    from vtrack.io.importers.scene_build import finalize_scene, tactile_entry

    scene = dict(base or {"name": "tactile_recording", "object": {"name": "object"}})
    known = {t["name"]: t for t in scene.get("tactile", [])}
    tac = list(scene.get("tactile", []))
    for c in cams:
        h, w = shapes[c.name]
        if c.name in known:
            if (known[c.name]["height"], known[c.name]["width"]) != (h, w):
                raise InputError(
                    "camera image size differs from the scene's tactile entry",
                    field=c.name,
                    expected=f"{known[c.name]['width']}x{known[c.name]['height']}",
                    got=f"{w}x{h}",
                )
            continue
        tac.append(tactile_entry(c.name, c.type, w, h, SENSOR_PRESETS.get(c.type, SENSOR_PRESETS["digit"]).fps))
    scene["tactile"] = tac
    return finalize_scene(scene)


def record_tactile(
    out: str | Path,
    cams: list[TactileCamera],
    *,
    joints: JointSource | None = None,
    seconds: float | None = None,
    max_frames: int | None = None,
    flush_every: int = 10,
    overwrite: bool = False,
    scene: dict | None = None,
    realtime: bool = True,
    status: bool = True,
    joint_poll_hz: float = 200.0,
    on_frame: Any = None,
) -> RecordingStats:
    """Record tactile cameras (+ joint states) until Ctrl-C, ``seconds``, ``max_frames`` per
    camera, or every source ended (video files).

    Args:
        out: session directory.
        cams: the cameras.
        joints: joint-state source (``joints`` stream), optional.
        flush_every: commit every this many frames per stream (the crash-safety granularity).
        scene: base scene dict (hand, object, ...); tactile entries are added for the cameras.
        realtime: pace video-file sources at their frame rate (devices are always real time).
        on_frame: ``on_frame(stream, t, fields)`` after each written frame (feeds a live pipeline).
    """
    from vtrack.io.streams import joints_stream, tactile_stream
    from vtrack.scene.load import scene_from_dict

    if not cams:
        raise InputError("no tactile camera given", field="--camera")
    names = [c.name for c in cams]
    if len(set(names)) != len(names):
        raise InputError("duplicate camera names", field="--camera", got=names)
    shapes = {c.name: _probe(c).shape[:2] for c in cams}
    scene_dict = tactile_scene(cams, shapes, scene)
    sc = scene_from_dict(scene_dict, check_files=False)
    stats = RecordingStats()
    info = {"recorder": "tactile", "sources": {c.name: str(c.source) for c in cams}}
    with recording_writer(out, scene_dict, overwrite=overwrite, flush_every=flush_every, info=info, status=status) as (
        w,
        line,
    ):
        for c in cams:
            w.add_stream(f"tactile/{c.name}", tactile_stream(sc.tactile_by_name(c.name)))
        if joints is not None:
            names_j = joints.names or (sc.hand.joint_names if sc.hand and sc.hand.joint_names else [])
            if not names_j:
                raise InputError("joint source has no joint names", field="--joints")
            w.add_stream("joints", joints_stream(names_j, rate_hz=None))
        t0 = time.time()
        readers = []
        for c in cams:
            cap, is_file = open_capture(c)
            r = _Reader(c, cap, is_file, t0, realtime, stats)
            readers.append(r)
        if joints is not None:
            joints.start(t0)
        for r in readers:
            r.start()
        last_t = {c.name: -np.inf for c in cams}
        last_jt = -np.inf
        next_poll = 0.0
        # Clock for the joint source: wall time, or the media time when files are read unpaced.
        media_clock = not realtime and all(r.is_file for r in readers)
        latest_t = t0
        try:
            with StopFlag(seconds) as stop:
                while not stop.is_set():
                    got = False
                    for r in readers:
                        if r.error is not None:
                            raise InputError(
                                f"camera read failed ({type(r.error).__name__}: {r.error})", field=r.cam.name
                            )
                        while True:
                            try:
                                t, frame = r.q.get_nowait()
                            except queue.Empty:
                                break
                            got = True
                            key = f"tactile/{r.cam.name}"
                            if t <= last_t[r.cam.name] or frame.shape[:2] != shapes[r.cam.name]:
                                stats.drop(key)
                                continue
                            if max_frames is not None and stats.written.get(key, 0) >= max_frames:
                                continue
                            w.append(key, t, image=frame)
                            last_t[r.cam.name] = t
                            latest_t = max(latest_t, t)
                            stats.add(key)
                            if on_frame is not None:
                                on_frame(key, t, {"image": frame})
                    now = latest_t if media_clock else time.time()
                    if joints is not None and now >= next_poll:
                        next_poll = now + 1.0 / joint_poll_hz
                        for tj, q in joints.poll(now):
                            if tj > last_jt:
                                w.append("joints", tj, q=q)
                                last_jt = tj
                                stats.add("joints")
                    line.update(stats, w)
                    finished = all(r.done.is_set() and r.q.empty() for r in readers)
                    full = max_frames is not None and all(
                        stats.written.get(f"tactile/{c.name}", 0) >= max_frames for c in cams
                    )
                    if finished or full:
                        stop.set("sources ended" if finished else "frame count reached")
                        if joints is not None:  # samples up to the last frame's time
                            for tj, q in joints.poll(latest_t):
                                if tj > last_jt:
                                    w.append("joints", tj, q=q)
                                    last_jt = tj
                                    stats.add("joints")
                        break
                    if not got:
                        time.sleep(0.002)
        finally:
            for r in readers:
                r.halt.set()
            for r in readers:
                r.join(timeout=2.0)
                r.cap.release()
            if joints is not None:
                joints.close()
            w.flush()
            line.update(stats, w, force=True)
            line.close()
        w.set_info(stop_reason=stop.reason, stats=stats.to_dict())
    return stats
