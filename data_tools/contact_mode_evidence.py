"""Can a session tell blind whether its fingers slide or stick? Per YCB session (the simulator's ``sim.contact_mode``
given by ``--contacts``), blind SLAM with the default settings and with the sticking-contact preset
(``SLAM_STICKING_CONTACTS``), and for each run its object-motion error (scored against gt/ by eval code) and its map
consistency (:func:`vtrack.tracking.slam.map_consistency_mm`: how well the run's own depth points sit on its final
map, the blind score of ``--select-run``); and, from the frames alone (no pose), the sticking-contact ids'
statistics: their median life (frames), the median world speed of their patch centres (mm/s) and the rigidity index
of pairs of ids alive together (change of their distance / their mean displacement: 0 for contacts fixed to one rigid
body).

Usage: ``python data_tools/contact_mode_evidence.py SECONDS OCCLUSION SEEDS [OBJECTS] --contacts slide|stick
[--out PREFIX]`` (2 processes, one thread each; PREFIX.csv, one row per session).
"""

import csv
from multiprocessing import Pool

import numpy as np


def contact_id_stats(frames) -> dict:
    """Life, world speed and pair rigidity of the sticking-contact ids of ``frames`` (tracking frames annotated by
    :class:`vtrack.tracking.stick.StickingContacts`, with ``info["t"]``); ids alive >= 5 frames."""
    tracks: dict[int, dict[float, np.ndarray]] = {}
    for tf in frames:
        for cid, P in zip(tf.info["stick_ids"], tf.info["stick_points"], strict=True):
            tracks.setdefault(int(cid), {})[tf.info["t"]] = P
    long = {c: tr for c, tr in tracks.items() if len(tr) >= 5}
    lives = [len(tr) for tr in long.values()]
    speeds = []
    for tr in long.values():
        ts = sorted(tr)
        speeds.append(np.linalg.norm(tr[ts[-1]] - tr[ts[0]]) / (ts[-1] - ts[0]) * 1e3)
    rig = []
    ids = list(long)
    for a in range(len(ids)):
        for b in range(a + 1, len(ids)):
            A, B = long[ids[a]], long[ids[b]]
            ts = sorted(set(A) & set(B))
            if len(ts) < 5:
                continue
            d0, d1 = np.linalg.norm(A[ts[0]] - B[ts[0]]), np.linalg.norm(A[ts[-1]] - B[ts[-1]])
            disp = 0.5 * (np.linalg.norm(A[ts[-1]] - A[ts[0]]) + np.linalg.norm(B[ts[-1]] - B[ts[0]]))
            if disp > 1e-4:  # a pair that does not move says nothing about rigidity
                rig.append(abs(d1 - d0) / disp)
    med = lambda x: float(np.median(x)) if x else float("nan")  # noqa: E731
    return {
        "ids": len(tracks),
        "life_med": med(lives),
        "speed_mm_s_med": med(speeds),
        "rigidity_med": med(rig),
        "pairs": len(rig),
    }


def _run(args: tuple) -> dict:
    obj, occ, secs, seed, contacts = args
    from vtrack.threads import limit_threads

    limit_threads(1)
    from vtrack.testing.sim import ycb_session
    from vtrack.tracking.run import track_session
    from vtrack.tracking.slam import SLAM_STICKING_CONTACTS, map_consistency_mm
    from vtrack.tracking.stick import sticking_contacts_for

    path = ycb_session(obj, occ, secs, contact_mode=contacts, seed=seed)
    row: dict = dict(obj=obj, occlusion=occ, seconds=secs, seed=seed, contacts=contacts)
    for name, opts in (("default", {}), ("preset", dict(SLAM_STICKING_CONTACTS))):
        kf: dict = {}
        m, (times, est) = track_session(path, "", shape="slam", write=False, return_poses=True, keep_frames=kf, **opts)
        tfs = [fr.tracking_frame() for _, fr in kf["built"]]
        row[f"{name}_err_mm"] = float(m["motion_err_mm"])
        row[f"{name}_consistency_mm"] = map_consistency_mm(kf["tracker"], tfs, est)
        if name == "default":  # the ids from the frames alone (the same for both runs)
            sticker = sticking_contacts_for(SLAM_STICKING_CONTACTS, ("touch",))
            for (_, fr), tf, t in zip(kf["built"], tfs, times, strict=True):
                sticker.annotate(fr, tf)
                tf.info["t"] = float(t)
            row.update(contact_id_stats(tfs))
    row["consistency_ratio"] = row["preset_consistency_mm"] / row["default_consistency_mm"]
    print(row, flush=True)
    return row


def main() -> None:
    from sweep_cli import parse_sweep, sweep_parser

    ap = sweep_parser("Blind evidence for the contact mode, per session.")
    ap.add_argument("--contacts", default="slide", choices=("slide", "stick"), help="the sessions' sim.contact_mode")
    sw, a = parse_sweep(ap)
    jobs = [(o, sw.occlusion, sw.seconds, s, a.contacts) for s in sw.seeds for o in sw.objects]
    with Pool(2) as pool:
        rows = pool.map(_run, jobs, chunksize=1)
    if sw.out:
        with open(f"{sw.out}.csv", "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)


if __name__ == "__main__":
    main()
