"""Import MCAP files with the ``mcap`` reader; ROS 2 (CDR) and ROS 1 payloads are decoded with
``rosbags``' type store (standard message types: sensor_msgs, tf2_msgs, geometry_msgs, std_msgs).
Channels with other encodings (JSON, protobuf, ...) are skipped and reported.
"""

from __future__ import annotations

import time
from pathlib import Path

from vtrack.errors import InputError
from vtrack.io.importers.report import ImportReport
from vtrack.io.importers.ros_messages import INFO_TYPES, TF_TYPES, RosSessionBuilder, norm_type

MCAP_MAGIC = b"\x89MCAP0\r\n"


def import_mcap(
    src: str | Path,
    out: str | Path,
    *,
    topic_map: dict[str, str] | None = None,
    overwrite: bool = False,
    flush_every: int = 256,
    pair_tolerance_s: float = 0.02,
    world_frame: str = "world",
    object_frame: str = "object",
    tactile_type: str | None = None,
) -> ImportReport:
    """Convert an MCAP file into a session at ``out``.

    Raises:
        InputError: missing / truncated / corrupt / mislabelled file (the message names it).
    """
    from mcap.reader import make_reader
    from rosbags.typesys import Stores, get_typestore

    t0 = time.perf_counter()
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
    report = ImportReport(source=src, session=Path(out))
    b = RosSessionBuilder(
        out,
        report,
        topic_map=topic_map,
        overwrite=overwrite,
        flush_every=flush_every,
        pair_tolerance_s=pair_tolerance_s,
        world_frame=world_frame,
        object_frame=object_frame,
        source=src,
        tactile_type=tactile_type,
    )

    def decode(schema, data: bytes):
        name = norm_type(schema.name)
        if schema.encoding == "ros2msg":
            return name, store2.deserialize_cdr(data, name)
        if schema.encoding == "ros1msg":
            return name, store1.deserialize_ros1(data, name)
        return name, None

    try:
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
                    report.skip(f"topic {channel.topic}: no schema")
                    continue
                try:
                    name, msg = decode(schema, message.data)
                except Exception as e:
                    report.skip(f"topic {channel.topic}: undecodable {schema.name} ({type(e).__name__})")
                    continue
                if msg is None:
                    report.skip(f"topic {channel.topic}: unsupported encoding '{schema.encoding}'")
                    continue
                b.add(channel.topic, name, msg, message.log_time * 1e-9)
    except InputError:
        raise
    except Exception as e:  # mcap raises its own errors, EndOfFile, struct errors for truncated files
        if b.writer is not None:
            b.writer.flush()
        raise InputError(f"cannot read MCAP ({type(e).__name__}: {e})", path=src) from None
    report = b.finish()
    report.seconds = time.perf_counter() - t0
    return report
