"""Quiet-machine speed of blind SLAM: CPU ms per frame (segmentation + 4 tactile pipelines + tracker, one thread) and
object-motion error (mm, scored against gt/ by eval code) of the default (colour term on, 5 LM iterations) and of
``iterations=3``, alternated per session over the 12 2 s YCB sessions, R rounds.

Usage: ``python data_tools/slam_speed_quiet.py [R]`` (run it on an otherwise idle machine).
"""

import sys

from vtrack.threads import limit_threads

CONF = {"default": {}, "it3": {"iterations": 3}}


def main(rounds: int) -> None:
    limit_threads(1)
    from vtrack.testing.sim import ycb_objects, ycb_session
    from vtrack.tracking.run import track_session

    res = {k: {o: {"cpu": [], "err": {}} for o in ("none", "medium")} for k in CONF}
    for r in range(rounds):
        for occ in ("none", "medium"):
            for name in ycb_objects():
                p = ycb_session(name, occ, seconds=2)
                for k, kw in CONF.items():
                    m = track_session(p, "", shape="slam", write=False, **dict(kw))
                    res[k][occ]["cpu"].append(m["cpu_ms_per_frame_mean"])
                    res[k][occ]["err"][name] = m["motion_err_mm"]
                    cpu, err = m["cpu_ms_per_frame_mean"], m["motion_err_mm"]
                    print(r, k, name, occ, round(cpu, 2), round(err, 3), flush=True)
    for k in CONF:
        for occ in ("none", "medium"):
            c, e = res[k][occ]["cpu"], list(res[k][occ]["err"].values())
            mc = sum(c) / len(c)
            print(k, occ, "cpu_ms", round(mc, 2), "poses/s", round(1000 / mc, 1), "err_mm", round(sum(e) / len(e), 3))


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 2)
