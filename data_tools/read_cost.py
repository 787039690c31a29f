"""CPU of reading a session frame by frame, chunk files decoded directly (vtrack.io.chunks) against through Zarr,
alternated per round: one camera's depth and RGB, and each DIGIT's images at the camera rate (every second one).

Usage: ``python data_tools/read_cost.py [OBJECT [SECONDS [ROUNDS]]]`` (default 006_mustard_bottle, 5 s medium, 3).
Prints ms of process CPU (all threads, Zarr's included) per camera frame, per field and in total.
"""

import sys
import time


def read_ms(session, direct: bool) -> dict[str, float]:
    from vtrack.io.session import open_session

    r = open_session(session)
    cam = r["camera/cam0"]
    n = cam.n
    out = {}
    jobs = [("depth", cam["depth"], 1), ("rgb", cam["rgb"], 1)]
    jobs += [(name.split("/")[-1], r[name]["image"], 2) for name in sorted(r.streams) if name.startswith("tactile/")]
    for name, field, step in jobs:
        if not direct:
            field._files = None  # the Zarr path
        c0 = time.process_time()
        for j in range(0, len(field), step):
            field[j]
        out[name] = (time.process_time() - c0) * 1e3 / n
    out["total"] = sum(out.values())
    return out


def main(obj: str, seconds: float, rounds: int) -> None:
    from vtrack.threads import limit_threads

    limit_threads(1)
    from vtrack.testing.sim import ycb_session

    s = ycb_session(obj, "medium", seconds)
    res: dict[str, list[dict]] = {"zarr": [], "direct": []}
    for k in range(rounds):
        order = ["zarr", "direct"] if k % 2 == 0 else ["direct", "zarr"]
        for v in order:
            res[v].append(read_ms(s, v == "direct"))
            print(k, v, {f: round(x, 2) for f, x in res[v][-1].items()}, flush=True)
    for v, rows in res.items():
        print(v, {f: round(sum(r[f] for r in rows) / len(rows), 2) for f in rows[0]})


if __name__ == "__main__":
    a = sys.argv[1:]
    main(a[0] if a else "006_mustard_bottle", float(a[1]) if len(a) > 1 else 5.0, int(a[2]) if len(a) > 2 else 3)
