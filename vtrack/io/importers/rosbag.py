"""Import ROS 1 bags (``.bag``) and ROS 2 bag folders (sqlite3 or mcap storage) with ``rosbags``.

Message handling (topics -> streams, colour/depth pairing, tf) is in
:mod:`vtrack.io.importers.ros_messages`.
"""

from __future__ import annotations

import time
from pathlib import Path

from vtrack.errors import InputError
from vtrack.io.importers.report import ImportReport
from vtrack.io.importers.ros_messages import INFO_TYPES, TF_TYPES, RosSessionBuilder, norm_type


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


def import_rosbag(
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
    """Convert a ROS 1 ``.bag`` or a ROS 2 bag folder into a session at ``out``.

    Raises:
        InputError: missing / truncated / corrupt / mislabelled bag (the message names the file),
            or no importable message.
    """
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    t0 = time.perf_counter()
    src = Path(src)
    _check_bag_path(src)
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
    try:
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
                    report.skip(f"topic {conn.topic}: undecodable message ({type(e).__name__})")
                    continue
                b.add(conn.topic, conn.msgtype, msg, ts * 1e-9)
    except InputError:
        raise
    except Exception as e:  # rosbags raises ReaderError / struct errors / sqlite errors for bad files
        if b.writer is not None:
            b.writer.flush()
        raise InputError(f"cannot read bag ({type(e).__name__}: {e})", path=src) from None
    report = b.finish()
    report.seconds = time.perf_counter() - t0
    return report
