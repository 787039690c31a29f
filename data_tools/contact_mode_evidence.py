"""Can a session tell blind whether its fingers slide or stick? Per YCB session (the simulator's ``sim.contact_mode``
given by ``--contacts``), blind SLAM with the default settings and with the sticking-contact preset
(``SLAM_STICKING_CONTACTS``), and for each run its object-motion error (scored against gt/ by eval code) and its map
consistency (:func:`vtrack.tracking.slam.map_consistency_mm`: how well the run's own depth points sit on its final
map, the blind score of ``--select-run``); and, from the frames alone (no pose), the sticking-contact ids'
statistics: their median life (frames), the median world speed of their patch centres (mm/s) and the rigidity index
of pairs of ids alive together (change of their distance / their mean displacement: 0 for contacts fixed to one rigid
body), on the ids' gel points as ``--contacts auto`` tests it (the CSVs written before 2026-11-28 14:00 UTC,
docs/benchmarks/contacts_auto_*.csv, have the index of the patch centres, the test then, and the preset's errors with
the patch centres anchored; docs/benchmarks/contacts_gel_*.csv are the current ones).

The CSV also has ``--contacts auto``'s choice (:func:`vtrack.tracking.stick.fingers_stick` on these two runs) and the
error of the run it keeps.

Usage: ``python data_tools/contact_mode_evidence.py SECONDS OCCLUSION SEEDS [OBJECTS] --contacts slide|stick
[--out PREFIX]`` (2 processes, one thread each; PREFIX.csv, one row per session);
``python data_tools/contact_mode_evidence.py plot OUT.png CSV...``: the sessions on the two tests' plane.
"""

import csv

import numpy as np


def contact_id_stats(frames) -> dict:
    """Life (frames) and world speed (mm/s) of the sticking-contact ids of ``frames`` (tracking frames annotated by
    :class:`vtrack.tracking.stick.StickingContacts`; ids alive >= 5 frames) and their rigidity index
    (:func:`vtrack.tracking.stick.contact_rigidity`, what ``--contacts auto`` tests)."""
    from vtrack.tracking.stick import contact_rigidity, contact_tracks

    tracks = contact_tracks(frames, "stick_patch_points")
    long = [tr for tr in tracks.values() if len(tr) >= 5]
    speeds = []
    for tr in long:
        ts = sorted(tr)
        speeds.append(np.linalg.norm(tr[ts[-1]] - tr[ts[0]]) / (ts[-1] - ts[0]) * 1e3)
    rigidity, pairs = contact_rigidity(frames)
    return {
        "ids": len(tracks),
        "life_med": float(np.median([len(tr) for tr in long])) if long else float("nan"),
        "speed_mm_s_med": float(np.median(speeds)) if speeds else float("nan"),
        "rigidity_med": rigidity,
        "pairs": pairs,
    }


def _run(args: tuple) -> dict:
    obj, occ, secs, seed, contacts = args
    from vtrack.threads import limit_threads

    limit_threads(1)
    from vtrack.testing.sim import ycb_session
    from vtrack.tracking.run import track_session
    from vtrack.tracking.slam import SLAM_STICKING_CONTACTS, map_consistency_mm
    from vtrack.tracking.stick import fingers_stick, sticking_contacts_for

    path = ycb_session(obj, occ, secs, contact_mode=contacts, seed=seed)
    row: dict = dict(obj=obj, occlusion=occ, seconds=secs, seed=seed, contacts=contacts)
    for name, opts in (("default", {}), ("preset", dict(SLAM_STICKING_CONTACTS))):
        kf: dict = {}
        m, (_, est) = track_session(path, "", shape="slam", write=False, return_poses=True, keep_frames=kf, **opts)
        tfs = [fr.tracking_frame() for _, fr in kf["built"]]
        row[f"{name}_err_mm"] = float(m["motion_err_mm"])
        row[f"{name}_consistency_mm"] = map_consistency_mm(kf["tracker"], tfs, est)
        if name == "default":  # the ids from the frames alone (the same for both runs)
            sticker = sticking_contacts_for(SLAM_STICKING_CONTACTS, ("touch",))
            for (_, fr), tf in zip(kf["built"], tfs, strict=True):
                sticker.annotate(fr, tf)
            row.update(contact_id_stats(tfs))
    row["consistency_ratio"] = row["preset_consistency_mm"] / row["default_consistency_mm"]
    # --contacts auto's choice on these two runs (track_session(select_contacts=True) makes the same one from the same
    # frames and runs: tests/tracking/test_stick.py checks it keeps the chosen run's poses)
    stick = fingers_stick(row["rigidity_med"], row["default_consistency_mm"], row["preset_consistency_mm"])
    row["auto_choice"] = "stick" if stick else "slide"
    row["auto_err_mm"] = row["preset_err_mm" if stick else "default_err_mm"]
    print(row, flush=True)
    return row


def plot(csvs: list[str], out_png: str) -> None:
    """Rigidity index against the consistency ratio of every session in ``csvs`` (colour: the simulator's contact
    mode; marker: the occlusion), with ``--contacts auto``'s box (the sticking run kept inside it)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from vtrack.tracking.stick import STICK_CONSISTENCY_RATIO_MAX, STICK_RIGIDITY_MAX

    rows = [r for f in csvs for r in csv.DictReader(open(f))]
    fig, ax = plt.subplots(figsize=(7, 5))
    marks = {"none": "o", "medium": "s", "heavy": "^"}
    for mode, colour in (("stick", "tab:blue"), ("slide", "tab:red")):
        for occ, mk in marks.items():
            sel = [r for r in rows if r["contacts"] == mode and r["occlusion"] == occ]
            if sel:
                x = [float(r["rigidity_med"]) for r in sel]
                y = [float(r["consistency_ratio"]) for r in sel]
                ax.scatter(x, y, c=colour, marker=mk, s=22, alpha=0.7, label=f"{mode} fingers, {occ}")
    ax.axvline(STICK_RIGIDITY_MAX, color="k", lw=0.8, ls="--")
    ax.axhline(STICK_CONSISTENCY_RATIO_MAX, color="k", lw=0.8, ls="--")
    ax.set_xlabel("contact rigidity index (0: contacts move as one body)")
    ax.set_ylabel("map consistency, sticking run / default run")
    ax.set_title("--contacts auto keeps the sticking run in the lower left box")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out_png, dpi=120)


def main() -> None:
    import sys

    if sys.argv[1:2] == ["plot"]:  # plot OUT.png CSV...
        plot(sys.argv[3:], sys.argv[2])
        return
    from sweep_cli import run_contact_mode_sweep

    run_contact_mode_sweep("Blind evidence for the contact mode, per session.", _run)


if __name__ == "__main__":
    main()
