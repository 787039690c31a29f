"""Import MCAP files with the ``mcap`` reader; ROS 2 (CDR) and ROS 1 payloads are decoded with
``rosbags``' type store (standard message types: sensor_msgs, tf2_msgs, geometry_msgs, std_msgs).
Channels with other encodings (JSON, protobuf, ...) are skipped and reported.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from vtrack.errors import InputError
from vtrack.io.importers.report import ImportReport
from vtrack.io.importers.ros_messages import INFO_TYPES, TF_TYPES, RosSessionBuilder, norm_type, run_ros_import

MCAP_MAGIC = b"\x89MCAP0\r\n"


def import_mcap(src: str | Path, out: str | Path, **options: Any) -> ImportReport:
    """Convert an MCAP file into a session at ``out``; ``options`` as for
    :func:`vtrack.io.importers.ros_messages.run_ros_import` (topic_map, overwrite, pair_tolerance_s, ...).

    Raises:
        InputError: missing / truncated / corrupt / mislabelled file (the message names it).
    """
    from mcap.reader import make_reader
    from rosbags.typesys import Stores, get_typestore

    src = Path(src)
    if not src.is_file():
        raise InputError("MCAP file does not exist", path=src)
    with open(src, "rb") as f:
        head = f.read(8)
    if head != MCAP_MAGIC:
        what = "a ROS 1 bag (use `vtrack import rosbag`)" if head.startswith(b"#ROSBAG") else "not an MCAP file"
        raise InputError(f"file is {what}", path=src, expected="MCAP magic bytes", got=head)
    store2 = get_typestore(Stores.ROS2_HUMBLE)
    store1 = get_typestore(Stores.ROS1_NOETIC)

    def decode(schema, data: bytes):
        name = norm_type(schema.name)
        if schema.encoding == "ros2msg":
            return name, store2.deserialize_cdr(data, name)
        if schema.encoding == "ros1msg":
            return name, store1.deserialize_ros1(data, name)
        return name, None

    def read(b: RosSessionBuilder) -> None:
        with open(src, "rb") as f:
            reader = make_reader(f)
            # First pass: calibration and static transforms only.
            for schema, channel, message in reader.iter_messages():
                if schema is None or norm_type(schema.name) not in INFO_TYPES | TF_TYPES:
                    continue
                name, msg = decode(schema, message.data)
                if msg is not None:
                    b.prepare(channel.topic, name, msg)
            f.seek(0)
            reader = make_reader(f)
            for schema, channel, message in reader.iter_messages():
                if schema is None:
                    b.report.skip(f"topic {channel.topic}: no schema")
                    continue
                try:
                    name, msg = decode(schema, message.data)
                except Exception as e:
                    b.report.skip(f"topic {channel.topic}: undecodable {schema.name} ({type(e).__name__})")
                    continue
                if msg is None:
                    b.report.skip(f"topic {channel.topic}: unsupported encoding '{schema.encoding}'")
                    continue
                b.add(channel.topic, name, msg, message.log_time * 1e-9)

    return run_ros_import(src, out, "MCAP", read, **options)
