"""Accuracy and CPU cost of the live tracker's camera stride (issue #20), without the machine's load in it.

Feeds a session's frames to the live ``track`` consumer synchronously, in the replay's schedule order (joints,
every tactile image through the touch stage, each camera frame through segmentation + tracking), i.e. what
``vtrack live`` computes when no frame is dropped, and scores the live poses against the session's ground
truth (after the run). Per session and stride: object-motion error, tracked frames, CPU ms per tracked frame
and CPU per second of recording of the camera path.

    python data_tools/live_stride_eval.py [--strides 1,2,3] [--objects a,b] [--seconds 5] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np


def sync_replay(session, **opts) -> dict:
    """One synchronous replay of ``session`` into a ``track`` consumer (touch in the worker's thread)."""
    from vtrack.io.session import open_session
    from vtrack.live.consumers import make_consumer, replay_fields, replay_streams
    from vtrack.live.sources import FrameEvent, SessionReplaySource

    tc = make_consumer("track", session, touch_worker="thread", frames_worker="inline", **opts)
    parts = tc.parts()
    src = SessionReplaySource(session, streams=replay_streams(session, [tc]), fields=replay_fields([tc]))
    r = open_session(session)
    data = {n: {f: np.asarray(r[n].fields[f][:]) for f in fs} for n, fs in src.fields.items()}
    cam_cpu = 0.0
    for _rel, k, i in src.schedule:
        name, i = src.streams[int(k)], int(i)
        ev = FrameEvent(name, float(r[name].t[i]), i, {f: v[i] for f, v in data[name].items()}, time.perf_counter())
        c0 = time.process_time()
        for p in parts:
            if p.wants(name):
                p.process(ev)
        if name.startswith("camera/"):
            cam_cpu += time.process_time() - c0
    res = {}
    for p in parts:
        res.update(p.finish())
    seconds = float(src.period)
    res["cam_cpu_ms_per_tracked"] = round(1e3 * cam_cpu / max(res["steps"], 1), 2)
    res["cam_cpu_s_per_session_s"] = round(cam_cpu / seconds, 3)
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--strides", default="1,2,3")
    ap.add_argument("--objects", default="006_mustard_bottle,005_tomato_soup_can,025_mug")
    ap.add_argument("--occlusion", default="none")
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--opts", default="{}", help="more track-consumer options, JSON")
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    from vtrack.testing.sim import ycb_session
    from vtrack.threads import limit_threads

    limit_threads(1)
    rows = []
    for obj in a.objects.split(","):
        sess = ycb_session(obj, a.occlusion, a.seconds)
        for k in (int(x) for x in a.strides.split(",")):
            res = sync_replay(sess, camera_stride=k, **json.loads(a.opts))
            keys = ("motion_err_mm", "steps", "camera_skipped", "cam_cpu_ms_per_tracked", "cam_cpu_s_per_session_s")
            row = {"object": obj, "stride": k, **{key: res.get(key) for key in keys}}
            rows.append(row)
            print(json.dumps(row), flush=True)
    if a.json:
        from vtrack.io.jsonio import write_json

        write_json(a.json, {"command": "python data_tools/live_stride_eval.py", "args": vars(a), "rows": rows})


if __name__ == "__main__":
    main()
