"""``--contacts auto``'s choice again, with the current rigidity test, on sessions already measured by
``contact_mode_evidence.py``: per row of its CSVs, the session's frames are built again (one default SLAM run, for
its frames), the sticking-contact ids annotated, and :func:`vtrack.tracking.stick.contact_rigidity` (now on the ids'
gel points) recomputed; :func:`vtrack.tracking.stick.fingers_stick` then decides with the row's two consistency
scores. The two runs' poses, errors and scores do not depend on the rigidity test, so they are taken from the CSV.

Usage: ``python data_tools/contact_mode_rechoose.py OUT.csv EVIDENCE.csv...`` (2 processes, one thread each). OUT has
the evidence columns plus ``rigidity_gel``, ``pairs_gel``, ``auto_choice_gel`` and ``auto_err_gel_mm``.
"""

import csv
import sys
from multiprocessing import Pool


def _run(row: dict) -> dict:
    from vtrack.threads import limit_threads

    limit_threads(1)
    from vtrack.testing.sim import ycb_session
    from vtrack.tracking.run import track_session
    from vtrack.tracking.slam import SLAM_STICKING_CONTACTS
    from vtrack.tracking.stick import contact_rigidity, fingers_stick, sticking_contacts_for

    path = ycb_session(
        row["obj"], row["occlusion"], float(row["seconds"]), contact_mode=row["contacts"], seed=int(row["seed"])
    )
    kf: dict = {}
    track_session(path, "", shape="slam", write=False, keep_frames=kf)
    sticker = sticking_contacts_for(SLAM_STICKING_CONTACTS, ("touch",))
    tfs = [sticker.annotate(fr, fr.tracking_frame()) for _, fr in kf["built"]]
    rig, pairs = contact_rigidity(tfs)
    stick = fingers_stick(rig, float(row["default_consistency_mm"]), float(row["preset_consistency_mm"]))
    out = dict(row, rigidity_gel=rig, pairs_gel=pairs, auto_choice_gel="stick" if stick else "slide")
    out["auto_err_gel_mm"] = row["preset_err_mm" if stick else "default_err_mm"]
    print(out["obj"], out["occlusion"], out["seed"], out["contacts"], round(rig, 3), out["auto_choice_gel"], flush=True)
    return out


def main() -> None:
    out_csv, ins = sys.argv[1], sys.argv[2:]
    rows = [r for f in ins for r in csv.DictReader(open(f))]
    with Pool(2) as pool:
        res = pool.map(_run, rows, chunksize=1)
    with open(out_csv, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(res[0]))
        w.writeheader()
        w.writerows(res)


if __name__ == "__main__":
    main()
