"""Writers of small recordings in other tools' exact on-disk layouts (FeelSight log folders, ROS 1/2 bags,
MCAP) and tactile videos, for the importer / recorder tests (needs ``rosbags``, ``mcap``, ``cv2``)."""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np

FINGERS = ("index", "middle", "ring", "thumb")


def tactile_image(i: int, h: int = 40, w: int = 30) -> np.ndarray:
    """A BGR tactile-like image whose content encodes the frame index (smooth, JPEG-friendly)."""
    yy, xx = np.mgrid[0:h, 0:w]
    base = np.stack([xx * 4, yy * 3, np.full_like(xx, 100)], -1)
    cx, cy = (i * 3) % w, (i * 2) % h
    blob = 80 * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / 30.0)
    return np.clip(base + blob[..., None], 0, 255).astype(np.uint8)


def write_feelsight(
    root: Path,
    n: int = 10,
    cams: tuple[str, ...] = ("front-left",),
    cam_hw=(48, 64),
    tac_hw=(40, 30),
    sim: bool = True,
    rate_hz: float = 30.0,
) -> Path:
    """Write a FeelSight log folder ``root`` with ``n`` frames; returns ``root``.

    Tactile image content repeats every 50 frames (encoded once, written as bytes) to keep large
    fixtures quick to write; the importer still decodes every file.
    """
    import cv2

    root.mkdir(parents=True, exist_ok=True)
    enc_cache: dict = {}

    def imwrite(path: Path, img: np.ndarray, key) -> None:
        if key not in enc_cache:
            ok, buf = cv2.imencode(path.suffix, img)
            enc_cache[key] = buf.tobytes()
        path.write_bytes(enc_cache[key])

    H, W = cam_hw
    for f in FINGERS:
        for sub in ("image", *(("depth", "mask") if sim else ())):
            (root / "allegro" / f / sub).mkdir(parents=True, exist_ok=True)
        for i in range(n):
            imwrite(root / "allegro" / f / "image" / f"{i}.jpg", tactile_image(i % 50, *tac_hw), ("tac", i % 50))
            if sim:
                d = np.zeros(tac_hw, np.uint8)
                d[5:15, 5:15] = 200
                imwrite(root / "allegro" / f / "depth" / f"{i}.jpg", d, "depth")
                imwrite(root / "allegro" / f / "mask" / f"{i}.jpg", (d > 0).astype(np.uint8) * 255, "mask")
    cam_info = {}
    for c in cams:
        (root / "realsense" / c / "image").mkdir(parents=True, exist_ok=True)
        if sim:
            (root / "realsense" / c / "seg").mkdir(parents=True, exist_ok=True)
        depth = np.zeros((n, H, W), np.float32)
        for i in range(n):
            rgb = np.zeros((H, W, 3), np.uint8)
            rgb[..., 0] = 200  # red in RGB -> stored as BGR by cv2.imwrite after conversion
            rgb[H // 4 : H // 2, W // 4 : W // 2] = (0, 255, 0)
            imwrite(root / "realsense" / c / "image" / f"{i}.jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), "rgb")
            depth[i] = 0.5 + 0.001 * i
            depth[i, 0, 0] = np.nan  # invalid pixel
            if sim:
                seg = np.zeros((H, W), np.uint8)
                seg[H // 4 : H // 2, W // 4 : W // 2] = 255
                imwrite(root / "realsense" / c / "seg" / f"{i}.jpg", seg, "seg")
        np.savez_compressed(root / "realsense" / c / "depth.npz", depth=depth)
        T = np.eye(4)
        T[:3, 3] = [0.4, 0.1, 0.2]
        cam_info[c] = {"intrinsics": np.array([[50.0, 0, W / 2], [0, 50.0, H / 2], [0, 0, 1]]), "pose": T}
    t = np.arange(n) / rate_hz + 100.0
    q = np.tile(np.linspace(0, 1.5, 16), (n, 1)) + 0.01 * np.arange(n)[:, None]
    obj = np.tile(np.eye(4), (n, 1, 1))
    obj[:, 0, 3] = 0.001 * np.arange(n)
    data = {
        "time": t,
        "allegro": {"joint_state": q, "base_pose": np.eye(4)},
        "object": {"pose": obj},
        "realsense": cam_info,
        "digit_info": {"depth_scale": 0.002, "cam_dist": 0.022, "serials": ["D0001"]},
    }
    with open(root / "data.pkl", "wb") as fh:
        pickle.dump(data, fh)
    return root


# --- ROS -------------------------------------------------------------------------------------
def _ros_messages(store, n: int, cam_hw=(24, 32), tac_hw=(40, 30), compressed_tactile: bool = False):
    """Yield (topic, msgtype, t_ns, message) in time order: 30 Hz RGB-D camera (+ CameraInfo),
    60 Hz DIGIT (Image or CompressedImage), 60 Hz JointState, object tf, one static tf."""
    import cv2

    T = store.types
    Header = T["std_msgs/msg/Header"]
    Time = T["builtin_interfaces/msg/Time"]
    H, W = cam_hw
    ros1 = "seq" in Header.__dataclass_fields__

    def header(t_ns: int, frame: str):
        extra = {"seq": 0} if ros1 else {}
        return Header(stamp=Time(sec=t_ns // 10**9, nanosec=t_ns % 10**9), frame_id=frame, **extra)

    def tf(t_ns, parent, child, xyz):
        TS = T["geometry_msgs/msg/TransformStamped"]
        Tr = T["geometry_msgs/msg/Transform"]
        V = T["geometry_msgs/msg/Vector3"]
        Q = T["geometry_msgs/msg/Quaternion"]
        return T["tf2_msgs/msg/TFMessage"](
            transforms=[
                TS(
                    header=header(t_ns, parent),
                    child_frame_id=child,
                    transform=Tr(translation=V(x=xyz[0], y=xyz[1], z=xyz[2]), rotation=Q(x=0.0, y=0.0, z=0.0, w=1.0)),
                )
            ]
        )

    t0 = 1_700_000_000 * 10**9
    yield "/tf_static", "tf2_msgs/msg/TFMessage", t0, tf(t0, "world", "camera_color_optical_frame", (0.5, 0, 0.3))
    calib = {
        "d": np.zeros(5),
        "k": np.array([40.0, 0, W / 2, 0, 40.0, H / 2, 0, 0, 1]),
        "r": np.eye(3).ravel(),
        "p": np.zeros(12),
    }
    if ros1:
        calib = {k.upper(): v for k, v in calib.items()}
    info = T["sensor_msgs/msg/CameraInfo"](
        header=header(t0, "camera_color_optical_frame"),
        height=H,
        width=W,
        distortion_model="plumb_bob",
        binning_x=0,
        binning_y=0,
        **calib,
        roi=T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
    )
    yield "/camera/color/camera_info", "sensor_msgs/msg/CameraInfo", t0, info
    Image = T["sensor_msgs/msg/Image"]
    Comp = T["sensor_msgs/msg/CompressedImage"]
    Joint = T["sensor_msgs/msg/JointState"]
    period60 = 10**9 // 60
    for k in range(2 * n):  # 60 Hz ticks; camera on every other tick
        t = t0 + 1000 + k * period60
        if k % 2 == 0:
            i = k // 2
            rgb = np.zeros((H, W, 3), np.uint8)
            rgb[..., 0] = i % 256
            yield (
                "/camera/color/image_raw",
                "sensor_msgs/msg/Image",
                t,
                Image(
                    header=header(t, "camera_color_optical_frame"),
                    height=H,
                    width=W,
                    encoding="rgb8",
                    is_bigendian=0,
                    step=W * 3,
                    data=rgb.ravel(),
                ),
            )
            d = np.full((H, W), 500 + i, np.uint16)
            yield (
                "/camera/aligned_depth_to_color/image_raw",
                "sensor_msgs/msg/Image",
                t + 2_000_000,
                Image(
                    header=header(t + 2_000_000, "camera_color_optical_frame"),
                    height=H,
                    width=W,
                    encoding="16UC1",
                    is_bigendian=0,
                    step=W * 2,
                    data=d.view(np.uint8).ravel(),
                ),
            )
            yield "/tf", "tf2_msgs/msg/TFMessage", t, tf(t, "world", "object", (0.001 * i, 0.0, 0.1))
        img = tactile_image(k, *tac_hw)
        if compressed_tactile:
            ok, buf = cv2.imencode(".png", img)
            yield (
                "/digit_index/image_raw/compressed",
                "sensor_msgs/msg/CompressedImage",
                t,
                Comp(header=header(t, "digit"), format="png", data=buf.ravel()),
            )
        else:
            yield (
                "/digit_index/image_raw",
                "sensor_msgs/msg/Image",
                t,
                Image(
                    header=header(t, "digit"),
                    height=tac_hw[0],
                    width=tac_hw[1],
                    encoding="bgr8",
                    is_bigendian=0,
                    step=tac_hw[1] * 3,
                    data=img.ravel(),
                ),
            )
        yield (
            "/joint_states",
            "sensor_msgs/msg/JointState",
            t,
            Joint(
                header=header(t, ""),
                name=[f"joint_{j}.0" for j in range(16)],
                position=np.full(16, 0.01 * k),
                velocity=np.zeros(0),
                effort=np.zeros(0),
            ),
        )
        yield "/chatter", "std_msgs/msg/String", t, T["std_msgs/msg/String"](data="hello")


def write_ros1_bag(path: Path, n: int = 10, **kw) -> Path:
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    # Noetic's built-in store lacks tf2_msgs: register it from its message definition.
    store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"))
    conns = {}
    with Writer(path) as w:
        for topic, mt, t, msg in _ros_messages(store, n, **kw):
            if topic not in conns:
                conns[topic] = w.add_connection(topic, mt, typestore=store)
            w.write(conns[topic], t, store.serialize_ros1(msg, mt))
    return path


def write_ros2_bag(path: Path, n: int = 10, storage: str = "sqlite3", **kw) -> Path:
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    plugin = StoragePlugin.SQLITE3 if storage == "sqlite3" else StoragePlugin.MCAP
    conns = {}
    with Writer(path, version=9, storage_plugin=plugin) as w:
        for topic, mt, t, msg in _ros_messages(store, n, **kw):
            if topic not in conns:
                conns[topic] = w.add_connection(topic, mt, typestore=store)
            w.write(conns[topic], t, store.serialize_cdr(msg, mt))
    return path


def write_mcap(path: Path, n: int = 10, **kw) -> Path:
    """An MCAP file written with ``mcap``'s writer, ROS 2 CDR payloads serialised by rosbags."""
    from mcap.writer import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="ros2", library="vtrack-tests")
        schemas, channels = {}, {}
        for topic, mt, t, msg in _ros_messages(store, n, **kw):
            if mt not in schemas:
                text, _ = store.generate_msgdef(mt, ros_version=2)
                schemas[mt] = w.register_schema(name=mt, encoding="ros2msg", data=text.encode())
            if topic not in channels:
                channels[topic] = w.register_channel(topic=topic, message_encoding="cdr", schema_id=schemas[mt])
            w.add_message(channel_id=channels[topic], log_time=t, publish_time=t, data=store.serialize_cdr(msg, mt))
        # One channel with a non-ROS encoding, to be reported as skipped.
        sid = w.register_schema(name="Note", encoding="jsonschema", data=b"{}")
        cid = w.register_channel(topic="/notes", message_encoding="json", schema_id=sid)
        w.add_message(channel_id=cid, log_time=t + 1, publish_time=t + 1, data=b'{"a": 1}')
        w.finish()
    return path


def write_tactile_video(path: Path, n: int = 30, fps: float = 60.0, size=(320, 240)) -> Path:
    """A lossless (FFV1) video whose frame i is ``tactile_image(i)`` resized to ``size`` (w, h):
    stands in for a DIGIT's UVC stream (320x240 landscape)."""
    import cv2

    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), fps, size)
    if not vw.isOpened():
        raise RuntimeError("FFV1 writer unavailable")
    for i in range(n):
        vw.write(video_frame(i, size))
    vw.release()
    return path


def video_frame(i: int, size=(320, 240)) -> np.ndarray:
    import cv2

    return cv2.resize(tactile_image(i % 200, 40, 30), size, interpolation=cv2.INTER_NEAREST)
