#!/usr/bin/env python
"""Convert recordings from other tools into vtrack sessions (thin wrapper over ``vtrack import``).

Examples::

    python data_tools/convert.py feelsight feelsight/077_rubiks_cube/00 --out sessions/rubiks_00
    python data_tools/convert.py rosbag recording.bag --out sessions/bag1 --object-frame object
    python data_tools/convert.py rosbag ros2_bag_dir/ --out sessions/bag2 \\
        --map /camera/color/image_raw=camera/cam0:rgb --map /camera/depth/image_rect_raw=camera/cam0:depth
    python data_tools/convert.py mcap recording.mcap --out sessions/mcap1

    # several FeelSight logs at once:
    python data_tools/convert.py feelsight-all feelsight/ --out sessions/feelsight
"""

from __future__ import annotations

import sys
from pathlib import Path


def convert_all_feelsight(root: Path, out: Path) -> None:
    """Import every ``<object>/<log>/`` folder (with a data.pkl) under ``root`` into ``out/<object>_<log>``."""
    from vtrack.errors import InputError
    from vtrack.io.importers.feelsight import import_feelsight

    logs = sorted(p.parent for p in root.glob("*/*/data.pkl"))
    if not logs:
        raise SystemExit(f"no FeelSight logs (<object>/<log>/data.pkl) under {root}")
    for log in logs:
        dst = out / f"{log.parent.name}_{log.name}"
        try:
            rep = import_feelsight(log, dst, overwrite=True)
            print(f"{log} -> {dst}: {rep.total_frames} frames in {rep.seconds:.1f} s")
        except InputError as e:
            print(f"skipped {log}: {e}", file=sys.stderr)


if __name__ == "__main__":
    if len(sys.argv) >= 2 and sys.argv[1] == "feelsight-all":
        import argparse

        ap = argparse.ArgumentParser(prog="convert.py feelsight-all")
        ap.add_argument("root", type=Path)
        ap.add_argument("--out", type=Path, required=True)
        a = ap.parse_args(sys.argv[2:])
        convert_all_feelsight(a.root, a.out)
    else:
        from vtrack_apps.cli import main

        sys.argv = ["vtrack", "import", *sys.argv[1:]]
        main()
