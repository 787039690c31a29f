"""Record an OAK-D (Luxonis, depthai 3.x) into a session: colour + stereo depth aligned to
colour, device timestamps, factory calibration, optional IMU.

Pipeline (on the device): colour camera CAM_A -> ``requestOutput((w, h), BGR888i)``; mono CAM_B /
CAM_C -> StereoDepth with ``setDepthAlign(CAM_A)`` and ``setOutputSize(w, h)`` (depth in mm on the
colour image grid); a host ``Sync`` node groups colour and depth by device timestamp; optional IMU
(accelerometer + gyroscope). The host loop (:func:`record_from_queues`) converts each synchronised
group and appends it to the session; it is the same code whether the queues come from a device
or from a host-only pipeline fed with synthetic frames (tests).

Streams: ``camera/<name>`` (rgb, depth uint16 mm; attrs K, depth_scale 0.001, T_world_camera,
and the device calibration), ``imu/<name>`` (accel m/s^2, gyro rad/s, in the IMU frame).
Timestamps are the device's (``getTimestampDevice``, s, monotonic since device boot).
Calibration: depthai reports extrinsics translations in **centimetres**; they are stored in metres.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from datetime import timedelta
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError
from vtrack.io.recorders.base import RecordingStats, StatusLine, StopFlag, recording_writer


@dataclass
class OakConfig:
    """OAK-D recording options.

    Attributes:
        name: camera name in the session (``camera/<name>``).
        width, height: colour (and aligned depth) size, px.
        fps: frame rate, Hz.
        imu: also record the IMU (accelerometer + gyroscope).
        imu_rate_hz: IMU sample rate.
        sync_threshold_ms: max colour/depth timestamp difference in a group, ms.
        T_world_camera: camera placement in the world (4x4, m); identity if unknown.
        device: device id / IP to open (None: the first device found).
    """

    name: str = "oak"
    width: int = 640
    height: int = 400
    fps: float = 30.0
    imu: bool = False
    imu_rate_hz: int = 200
    sync_threshold_ms: float = 10.0
    T_world_camera: np.ndarray | None = None
    device: str | None = None


def build_device_pipeline(pipeline: Any, cfg: OakConfig) -> dict[str, Any]:
    """Create the device nodes on ``pipeline`` and return the host output queues
    (``{"rgbd": MessageQueue, "imu": MessageQueue | None}``)."""
    import depthai as dai

    cam = pipeline.create(dai.node.Camera).build(dai.CameraBoardSocket.CAM_A)
    left = pipeline.create(dai.node.Camera).build(dai.CameraBoardSocket.CAM_B)
    right = pipeline.create(dai.node.Camera).build(dai.CameraBoardSocket.CAM_C)
    stereo = pipeline.create(dai.node.StereoDepth)
    stereo.setDefaultProfilePreset(dai.node.StereoDepth.PresetMode.DEFAULT)
    stereo.setLeftRightCheck(True)
    stereo.setSubpixel(True)
    stereo.setDepthAlign(dai.CameraBoardSocket.CAM_A)
    stereo.setOutputSize(cfg.width, cfg.height)
    left.requestOutput((640, 400), fps=cfg.fps).link(stereo.left)
    right.requestOutput((640, 400), fps=cfg.fps).link(stereo.right)
    rgb = cam.requestOutput((cfg.width, cfg.height), dai.ImgFrame.Type.BGR888i, fps=cfg.fps)
    queues = build_sync(pipeline, rgb, stereo.depth, cfg)
    if cfg.imu:
        imu = pipeline.create(dai.node.IMU)
        imu.enableIMUSensor([dai.IMUSensor.ACCELEROMETER_RAW, dai.IMUSensor.GYROSCOPE_RAW], cfg.imu_rate_hz)
        imu.setBatchReportThreshold(1)
        imu.setMaxBatchReports(10)
        queues["imu"] = imu.out.createOutputQueue(maxSize=64, blocking=False)
    return queues


def build_sync(pipeline: Any, rgb_out: Any, depth_out: Any, cfg: OakConfig, lossless: bool = False) -> dict[str, Any]:
    """Group colour and depth by timestamp with a host-side ``Sync`` node; returns the queue.

    ``lossless``: a blocking output queue (host sources that can wait); devices use a short
    non-blocking queue so that a slow host drops old groups instead of stalling the device.
    """
    import depthai as dai

    sync = pipeline.create(dai.node.Sync)
    sync.setRunOnHost(True)
    sync.setSyncThreshold(timedelta(milliseconds=cfg.sync_threshold_ms))
    rgb_out.link(sync.inputs["rgb"])
    depth_out.link(sync.inputs["depth"])
    # Non-blocking with a short queue: when the host falls behind the device drops old groups
    # instead of stalling the pipeline; drops show up as gaps in the sequence numbers.
    if lossless:
        return {"rgbd": sync.out.createOutputQueue(maxSize=64, blocking=True), "imu": None}
    return {"rgbd": sync.out.createOutputQueue(maxSize=8, blocking=False), "imu": None}


def calibration_attrs(calib: Any, width: int, height: int) -> dict[str, Any]:
    """Intrinsics of the colour camera at (width, height) and the stereo/IMU extrinsics (m)."""
    import depthai as dai

    A, B, C = dai.CameraBoardSocket.CAM_A, dai.CameraBoardSocket.CAM_B, dai.CameraBoardSocket.CAM_C
    K = np.asarray(calib.getCameraIntrinsics(A, width, height), dtype=np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0:
        raise InputError("device calibration has no valid colour intrinsics", field="calibration.CAM_A", got=K)
    out: dict[str, Any] = {"K": K.tolist(), "width": width, "height": height}
    try:
        out["distortion"] = [float(x) for x in calib.getDistortionCoefficients(A)]
    except Exception:
        out["distortion"] = []
    for name, src in (("T_rgb_left", B), ("T_rgb_right", C)):
        try:
            T = np.asarray(calib.getCameraExtrinsics(src, A), dtype=np.float64)
            T[:3, 3] /= 100.0  # depthai: cm -> m
            out[name] = T.tolist()
        except Exception:
            pass
    try:
        T = np.asarray(calib.getCameraToImuExtrinsics(A), dtype=np.float64)
        T[:3, 3] /= 100.0
        out["T_imu_rgb"] = T.tolist()
    except Exception:
        pass
    return out


def group_to_frame(group: Any) -> tuple[float, np.ndarray, np.ndarray, int]:
    """A synchronised ``MessageGroup`` -> (device time s, rgb uint8 HxWx3 RGB, depth uint16 mm, seq)."""
    rgb_msg, depth_msg = group["rgb"], group["depth"]
    bgr = rgb_msg.getCvFrame()
    if bgr.ndim != 3 or bgr.shape[2] != 3:
        raise InputError("colour frame is not 3-channel", field="rgb", got=bgr.shape)
    depth = depth_msg.getFrame()
    if depth.dtype != np.uint16:
        raise InputError("depth frame is not uint16 mm", field="depth", got=str(depth.dtype))
    if depth.shape != bgr.shape[:2]:
        raise InputError(
            "depth is not aligned to colour (sizes differ)", field="depth", expected=str(bgr.shape[:2]), got=depth.shape
        )
    t = rgb_msg.getTimestampDevice().total_seconds()
    return t, np.ascontiguousarray(bgr[..., ::-1]), np.ascontiguousarray(depth), int(rgb_msg.getSequenceNum())


def imu_to_samples(imu_msg: Any) -> list[tuple[float, np.ndarray, np.ndarray]]:
    """``IMUData`` -> [(device time s, accel m/s^2 (3,), gyro rad/s (3,))]."""
    out = []
    fallback = imu_msg.getTimestampDevice().total_seconds()
    for p in imu_msg.packets:
        a, g = p.acceleroMeter, p.gyroscope
        t = a.getTimestampDevice().total_seconds() or fallback
        out.append((t, np.array([a.x, a.y, a.z], np.float64), np.array([g.x, g.y, g.z], np.float64)))
    return out


def declare_streams(writer: Any, cfg: OakConfig, calib: dict[str, Any] | None) -> None:
    """Declare ``camera/<name>`` (and ``imu/<name>``) with the calibration in the stream attrs."""
    from vtrack.io.session import FieldSpec, StreamSpec

    K = (calib or {}).get("K")
    if K is None:
        raise InputError("OAK recording needs the colour intrinsics", field="calibration")
    T = np.eye(4) if cfg.T_world_camera is None else np.asarray(cfg.T_world_camera, dtype=np.float64)
    h, w = cfg.height, cfg.width
    writer.add_stream(
        f"camera/{cfg.name}",
        StreamSpec(
            kind="rgbd",
            frame=f"camera/{cfg.name}",
            rate_hz=cfg.fps,
            fields={"rgb": FieldSpec((h, w, 3), "uint8", "sRGB"), "depth": FieldSpec((h, w), "uint16", "0.001 m")},
            attrs={
                "K": K,
                "width": w,
                "height": h,
                "depth_scale": 0.001,
                "T_world_camera": T.tolist(),
                "device": "oak-d",
                "clock": "device",
                "calibration": calib,
            },
        ),
    )
    if cfg.imu:
        writer.add_stream(
            f"imu/{cfg.name}",
            StreamSpec(
                kind="imu",
                frame=f"imu/{cfg.name}",
                rate_hz=float(cfg.imu_rate_hz),
                fields={"accel": FieldSpec((3,), "float64", "m/s^2"), "gyro": FieldSpec((3,), "float64", "rad/s")},
                attrs={"T_imu_rgb": (calib or {}).get("T_imu_rgb")},
            ),
        )


def oak_scene(cfg: OakConfig, calib: dict[str, Any], base: dict | None = None) -> dict[str, Any]:
    """Scene dict with this camera (merged into ``base`` if given)."""
    from vtrack.io.importers.scene_build import camera_entry, finalize_scene

    scene = dict(base or {"name": f"oak_{cfg.name}", "object": {"name": "object"}})
    cams = [c for c in scene.get("cameras", []) if c.get("name") != cfg.name]
    cams.append(
        camera_entry(cfg.name, np.asarray(calib["K"]), cfg.width, cfg.height, cfg.T_world_camera, 0.001, cfg.fps)
    )
    scene["cameras"] = cams
    return finalize_scene(scene)


def record_from_queues(
    queues: dict[str, Any],
    writer: Any,
    cfg: OakConfig,
    *,
    stop: StopFlag,
    is_running: Any = None,
    max_frames: int | None = None,
    status: StatusLine | None = None,
    stats: RecordingStats | None = None,
    idle_timeout_s: float = 5.0,
    on_frame: Any = None,
) -> RecordingStats:
    """Host loop: pull synchronised colour/depth groups (and IMU) and append them to ``writer``.

    Stops when ``stop`` is set, ``max_frames`` frames were written, or ``is_running()`` turns false
    (after draining what is queued), or nothing arrived for ``idle_timeout_s`` (a stalled or
    unplugged device). Frames whose device timestamp does not increase are dropped and counted;
    sequence-number gaps are counted as frames dropped upstream. ``on_frame(stream, t, fields)`` is
    called after each written frame (e.g. :meth:`vtrack.live.sources.QueueSource.push`).
    """
    stats = stats or RecordingStats()
    cam_stream, imu_stream = f"camera/{cfg.name}", f"imu/{cfg.name}"
    q_rgbd, q_imu = queues["rgbd"], queues.get("imu")
    last_seq: int | None = None
    last_t = -np.inf
    last_imu_t = -np.inf
    last_msg = time.monotonic()
    while not stop.is_set():
        got = False
        grp = q_rgbd.tryGet()
        if grp is not None:
            got = True
            t, rgb, depth, seq = group_to_frame(grp)
            if last_seq is not None and seq > last_seq + 1:
                stats.drop(cam_stream, seq - last_seq - 1)
            last_seq = seq
            if t <= last_t:
                stats.drop(cam_stream)
            else:
                writer.append(cam_stream, t, rgb=rgb, depth=depth)
                last_t = t
                stats.add(cam_stream)
                if on_frame is not None:
                    on_frame(cam_stream, t, {"rgb": rgb, "depth": depth})
        if q_imu is not None and cfg.imu:
            msg = q_imu.tryGet()
            while msg is not None:
                got = True
                for t, a, g in imu_to_samples(msg):
                    if t > last_imu_t:
                        writer.append(imu_stream, t, accel=a, gyro=g)
                        last_imu_t = t
                        stats.add(imu_stream)
                msg = q_imu.tryGet()
        if status is not None:
            status.update(stats, writer)
        if max_frames is not None and stats.written.get(cam_stream, 0) >= max_frames:
            stop.set("frame count reached")
            break
        if got:
            last_msg = time.monotonic()
        else:
            if is_running is not None and not is_running():
                break
            if time.monotonic() - last_msg > idle_timeout_s:
                stop.set(f"no frames for {idle_timeout_s:g} s")
                break
            time.sleep(0.002)
    writer.flush()
    if status is not None:
        status.update(stats, writer, force=True)
    return stats


def synthetic_frame(i: int, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Deterministic test frame ``i``: BGR colour encoding ``i`` in its first pixels, depth in mm."""
    bgr = np.zeros((height, width, 3), np.uint8)
    bgr[..., 2] = i % 256  # red channel (RGB[0]) = i mod 256
    bgr[..., 1] = (i // 256) % 256  # green = i div 256
    bgr[:, : width // 2, 0] = 255  # left half blue, so channel order errors are visible
    depth = np.full((height, width), 500 + (i % 1000), np.uint16)
    depth[0, 0] = 0  # an invalid pixel, as stereo produces
    return bgr, depth


def synthetic_calibration(width: int, height: int) -> Any:
    """A ``dai.CalibrationHandler`` built on the host (OAK-D-like numbers; 7.5 cm baseline)."""
    import depthai as dai

    c = dai.CalibrationHandler()
    A, B, C = dai.CameraBoardSocket.CAM_A, dai.CameraBoardSocket.CAM_B, dai.CameraBoardSocket.CAM_C
    f = 0.8 * width
    c.setCameraIntrinsics(A, [[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]], width, height)
    c.setCameraIntrinsics(B, [[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]], width, height)
    c.setCameraIntrinsics(C, [[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]], width, height)
    eye = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]
    c.setCameraExtrinsics(B, A, eye, [3.75, 0, 0])  # cm, as depthai stores them
    c.setCameraExtrinsics(C, A, eye, [-3.75, 0, 0])
    return c


def make_synthetic_source(pipeline: Any, cfg: OakConfig, n_frames: int, realtime: bool = True) -> Any:
    """A host node on ``pipeline`` that sends ``n_frames`` synthetic colour/depth ImgFrames (and IMU
    packets at 4 per frame) with device timestamps, like the device pipeline's outputs.

    Used for tests and ``vtrack record oak --simulate``: the rest of the recording path (Sync node,
    queues, conversion, writing) is the real one.
    """
    import depthai as dai

    class SyntheticOak(dai.node.ThreadedHostNode):
        def __init__(self) -> None:
            super().__init__()
            self.rgb = self.createOutput()
            self.depth = self.createOutput()
            self.imu = self.createOutput()

        def run(self) -> None:
            t0 = time.monotonic()
            for i in range(n_frames):
                if not self.isRunning():
                    return
                if realtime:
                    delay = t0 + i / cfg.fps - time.monotonic()
                    if delay > 0:
                        time.sleep(delay)
                ts = timedelta(seconds=10.0 + i / cfg.fps)
                bgr, depth = synthetic_frame(i, cfg.width, cfg.height)
                f = dai.ImgFrame()
                f.setCvFrame(bgr, dai.ImgFrame.Type.BGR888i)
                d = dai.ImgFrame()
                d.setFrame(depth)
                d.setType(dai.ImgFrame.Type.RAW16)
                d.setWidth(cfg.width)
                d.setHeight(cfg.height)
                for m in (f, d):
                    m.setTimestamp(ts)
                    m.setTimestampDevice(ts)
                    m.setSequenceNum(i)
                self.rgb.send(f)
                self.depth.send(d)
                if cfg.imu:
                    for k in range(4):
                        pkt = dai.IMUPacket()
                        a = dai.IMUReportAccelerometer()
                        a.x, a.y, a.z = 0.0, 0.0, 9.81
                        g = dai.IMUReportGyroscope()
                        g.x, g.y, g.z = 0.01 * i, 0.0, 0.0
                        pkt.acceleroMeter, pkt.gyroscope = a, g
                        msg = dai.IMUData()
                        msg.packets = [pkt]
                        msg.setTimestampDevice(ts + timedelta(seconds=k / (4 * cfg.fps)))
                        self.imu.send(msg)

    return pipeline.create(SyntheticOak)


def record_oak_simulated(
    out: str | Path,
    cfg: OakConfig | None = None,
    *,
    n_frames: int = 60,
    flush_every: int = 10,
    overwrite: bool = False,
    scene: dict | None = None,
    status: bool = True,
    realtime: bool = True,
    on_frame: Any = None,
) -> RecordingStats:
    """Record ``n_frames`` synthetic frames through a host-only depthai pipeline (no device):
    ``dai.Pipeline(False)`` + :func:`make_synthetic_source` + the same Sync node, queues and host loop
    as :func:`record_oak`."""
    import depthai as dai

    cfg = cfg or OakConfig()
    pipeline = dai.Pipeline(False)
    src = make_synthetic_source(pipeline, cfg, n_frames, realtime=realtime)
    queues = build_sync(pipeline, src.rgb, src.depth, cfg, lossless=True)
    if cfg.imu:
        queues["imu"] = src.imu.createOutputQueue(maxSize=256, blocking=True)
    calib_h = synthetic_calibration(cfg.width, cfg.height)
    calib = calibration_attrs(calib_h, cfg.width, cfg.height)
    scene_dict = oak_scene(cfg, calib, scene)
    info = {"recorder": "oakd", "device": "simulated"}
    with recording_writer(out, scene_dict, overwrite=overwrite, flush_every=flush_every, info=info, status=status) as (
        w,
        line,
    ):
        declare_streams(w, cfg, calib)
        return _record_pipeline(pipeline, queues, w, cfg, line, None, n_frames, on_frame, "source finished", wait=True)


def _record_pipeline(
    pipeline: Any,
    queues: dict[str, Any],
    w: Any,
    cfg: OakConfig,
    line: StatusLine,
    seconds: float | None,
    max_frames: int | None,
    on_frame: Any,
    end_reason: str,
    wait: bool = False,
) -> RecordingStats:
    """Start ``pipeline``, record its ``queues`` into the session writer ``w`` until Ctrl-C, ``seconds``,
    ``max_frames`` or the pipeline ends (``end_reason``), stop it (and ``wait`` for a host-only one to
    finish) and note why it stopped in the session info."""
    pipeline.start()
    try:
        with StopFlag(seconds) as stop:
            stats = record_from_queues(
                queues,
                w,
                cfg,
                stop=stop,
                is_running=pipeline.isRunning,
                max_frames=max_frames,
                status=line,
                on_frame=on_frame,
            )
    finally:
        pipeline.stop()
        if wait:
            pipeline.wait()
    line.close()
    w.set_info(stop_reason=stop.reason or end_reason, stats=stats.to_dict())
    return stats


def record_oak(
    out: str | Path,
    cfg: OakConfig | None = None,
    *,
    seconds: float | None = None,
    max_frames: int | None = None,
    flush_every: int = 10,
    overwrite: bool = False,
    scene: dict | None = None,
    status: bool = True,
    on_frame: Any = None,
) -> RecordingStats:
    """Record from a connected OAK-D until Ctrl-C, ``seconds`` or ``max_frames``.

    Raises:
        InputError: no device found / cannot open it (message says what to check).
    """
    import depthai as dai

    cfg = cfg or OakConfig()
    try:
        device = dai.Device(cfg.device) if cfg.device else dai.Device()
    except Exception as e:
        raise InputError(
            f"cannot open an OAK device ({type(e).__name__}: {e}); check the USB connection, "
            "udev rules and that no other program uses it",
            field="device",
            got=cfg.device,
        ) from None
    with dai.Pipeline(device) as pipeline:
        calib_h = device.readCalibration()
        calib = calibration_attrs(calib_h, cfg.width, cfg.height)
        queues = build_device_pipeline(pipeline, cfg)
        scene_dict = oak_scene(cfg, calib, scene)
        info = {"recorder": "oakd", "device": device.getDeviceId()}
        with recording_writer(
            out, scene_dict, overwrite=overwrite, flush_every=flush_every, info=info, status=status
        ) as (w, line):
            (w.path / "assets" / "oak_calibration.json").write_text(json.dumps(calib_h.eepromToJson(), indent=1))
            declare_streams(w, cfg, calib)
            return _record_pipeline(pipeline, queues, w, cfg, line, seconds, max_frames, on_frame, "device stopped")
