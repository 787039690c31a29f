"""Import ROS 1 bags (``.bag``) and ROS 2 bag folders (sqlite3 or mcap storage) with ``rosbags``.

Message handling (topics -> streams, colour/depth pairing, tf) is in
:mod:`vtrack.io.importers.ros_messages`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from vtrack.errors import InputError
from vtrack.io.importers.report import ImportReport
from vtrack.io.importers.ros_messages import INFO_TYPES, TF_TYPES, RosSessionBuilder, norm_type, run_ros_import


def _check_bag_path(src: Path) -> None:
    if not src.exists():
        raise InputError("bag does not exist", path=src)
    if src.is_file():
        with open(src, "rb") as f:
            head = f.read(13)
        if src.suffix == ".bag" and not head.startswith(b"#ROSBAG V2.0"):
            kind = "an MCAP file (use `vtrack import mcap`)" if head.startswith(b"\x89MCAP") else "not a ROS 1 bag"
            raise InputError(
                f"file has a .bag name but is {kind}", path=src, expected="'#ROSBAG V2.0' header", got=head[:13]
            )
        if head.startswith(b"\x89MCAP"):
            raise InputError("this is an MCAP file: use `vtrack import mcap`", path=src)
    elif not (src / "metadata.yaml").exists():
        raise InputError("ROS 2 bag folder has no metadata.yaml", path=src)


def import_rosbag(src: str | Path, out: str | Path, **options: Any) -> ImportReport:
    """Convert a ROS 1 ``.bag`` or a ROS 2 bag folder into a session at ``out``; ``options`` as for
    :func:`vtrack.io.importers.ros_messages.run_ros_import` (topic_map, overwrite, pair_tolerance_s, ...).

    Raises:
        InputError: missing / truncated / corrupt / mislabelled bag (the message names the file),
            or no importable message.
    """
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    src = Path(src)
    _check_bag_path(src)

    def read(b: RosSessionBuilder) -> None:
        with AnyReader([src], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
            first = [
                c for c in reader.connections if norm_type(c.msgtype) in INFO_TYPES or norm_type(c.msgtype) in TF_TYPES
            ]
            for conn, _ts, raw in reader.messages(connections=first):
                b.prepare(conn.topic, conn.msgtype, reader.deserialize(raw, conn.msgtype))
            for conn, ts, raw in reader.messages():
                try:
                    msg = reader.deserialize(raw, conn.msgtype)
                except Exception as e:
                    b.report.skip(f"topic {conn.topic}: undecodable message ({type(e).__name__})")
                    continue
                b.add(conn.topic, conn.msgtype, msg, ts * 1e-9)

    return run_ros_import(src, out, "bag", read, **options)
