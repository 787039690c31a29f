"""CPU of the SLAM map's grid updates per frame: ``SLAMTracker._refresh`` and, with the lazy band grid
(``vtrack.tracking.sdf_grid.LazyBandGrid``), the band voxels computed later when queries read them. One thread, blind
SLAM with default options over the 12 2 s YCB sessions (6 objects x none / medium, seed 0); the second pass (offline)
included, as it reads the final grid.

Usage: ``python data_tools/map_update_cost.py`` for this tree; for another tree (e.g. ``git worktree add --detach
/tmp/base COMMIT``) run ``cd /tmp && PYTHONPATH=/tmp/base python /work/main/data_tools/map_update_cost.py``.
"""

import time

from vtrack.threads import limit_threads


def main() -> None:
    limit_threads(1)
    import vtrack.tracking.sdf_grid as sg
    import vtrack.tracking.slam as sl
    from vtrack.testing.sim import ycb_objects, ycb_session
    from vtrack.tracking.run import track_session

    print("tree:", sg.__file__)
    cpu = {"refresh": 0.0, "lazy": 0.0}
    refresh = sl.SLAMTracker._refresh

    def timed_refresh(self) -> None:
        c0 = time.process_time()
        refresh(self)
        cpu["refresh"] += time.process_time() - c0

    sl.SLAMTracker._refresh = timed_refresh
    if hasattr(sg, "LazyBandGrid"):
        resolve = sg.LazyBandGrid._resolve

        def timed_resolve(self, flat) -> None:
            c0 = time.process_time()
            resolve(self, flat)
            cpu["lazy"] += time.process_time() - c0

        sg.LazyBandGrid._resolve = timed_resolve
    frames = 0
    for occ in ("none", "medium"):
        for name in ycb_objects():
            m = track_session(ycb_session(name, occ, seconds=2.0), "", shape="slam", write=False)
            frames += m["frames"]
    per = {k: v / frames * 1e3 for k, v in cpu.items()}
    print(
        f"frames {frames}: update {per['refresh']:.2f} + lazy {per['lazy']:.2f} = "
        f"{per['refresh'] + per['lazy']:.2f} ms CPU per frame"
    )


if __name__ == "__main__":
    main()
