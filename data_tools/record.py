#!/usr/bin/env python
"""Record a session from live sensors (thin wrapper over ``vtrack record``).

Examples::

    python data_tools/record.py oak --out sessions/oak_run --seconds 30 --imu
    python data_tools/record.py oak --simulate --out /tmp/oak_sim --frames 60
    python data_tools/record.py tactile --out sessions/grasp1 \\
        --camera digit_index=serial:D20001 --camera digit_thumb=serial:D20004 --joints-topic /allegro/joint_states

Ctrl-C stops cleanly (the session is closed); a crash or kill keeps every committed frame
(``--flush-every`` frames per commit).
"""

from __future__ import annotations

import sys

if __name__ == "__main__":
    from vtrack_apps.cli import main

    sys.argv = ["vtrack", "record", *sys.argv[1:]]
    main()
