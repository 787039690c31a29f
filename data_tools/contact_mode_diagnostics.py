"""Why ``--contacts auto`` misses some sessions with sticking fingers: other blind measures of whether the contacts
stick, per YCB session, beside the one it uses (docs/benchmarks/contacts_auto_heldout.md).

Per session (the simulator's ``sim.contact_mode`` given by ``--contacts``), from the sticking-contact ids of the frames
(:class:`vtrack.tracking.stick.StickingContacts`, ids alive >= 5 frames), on their patch centres
(``stick_patch_points``) unless said otherwise:
- ``rig_end``: :func:`vtrack.tracking.stick.contact_rigidity` of the ids' patch centres (|change of a pair's
  distance| / its mean displacement, between the first and last frame the pair shares; median over pairs: what
  ``--contacts auto`` tested until 2026-11-28 14:00 UTC);
- ``rig_gel``: the same on the ids' gel points (``stick_points``; what it tests since; column added after the CSVs
  of docs/benchmarks/contacts_auto_heldout.md were written);
- ``rig_slope``: the least-squares slope of a pair's distance against its mean displacement from the first shared
  frame, over every shared frame (median over pairs);
- ``rig_allpairs``: the ``rig_end`` ratio over every pair of shared frames that moved more than 2 mm (median);
- ``drift_est``: per id, its drift in the object frame between its first and last frame over how far the object point
  under it moved, with the default run's blind poses (median over ids; 0 for a contact fixed on the object);
- ``drift_gt``: the same with the ground-truth poses (DIAGNOSIS ONLY: read by this script's scoring, never by the
  pipeline);
- ``slip_pass``: the share of the anchored contact ids that pass the tracker's own slip test in the sticking run
  (``SLAM_STICKING_CONTACTS``; ``WindowTracker._stick_pairs``), and both runs' object-motion errors (mm, scored
  against gt/). The CSVs of docs/benchmarks/contacts_auto_heldout.md were written when the sticking run anchored the
  patch centres (before 2026-11-28 14:00 UTC); it anchors the gel points since, so ``slip_pass`` and
  ``preset_err_mm`` differ now.

Usage: ``python data_tools/contact_mode_diagnostics.py SECONDS OCCLUSION SEEDS [OBJECTS] --contacts slide|stick
[--out PREFIX]`` (2 processes, one thread each; PREFIX.csv, one row per session).
"""

import numpy as np


def rigidity_variants(tracks: dict) -> dict:
    """``rig_slope`` and ``rig_allpairs`` of the id tracks ``tracks`` (see the module doc)."""
    from vtrack.tracking.stick import contact_pairs

    slope, allp = [], []
    for A, B in contact_pairs(tracks):
        d = np.linalg.norm(A - B, axis=1)
        s = 0.5 * (np.linalg.norm(A - A[0], axis=1) + np.linalg.norm(B - B[0], axis=1))
        sc = s - s.mean()
        if s[-1] > 1e-4 and (sc * sc).sum() > 0:
            slope.append(abs((sc * (d - d.mean())).sum() / (sc * sc).sum()))
        for i in range(len(d)):
            mv = 0.5 * (np.linalg.norm(A[i + 1 :] - A[i], axis=1) + np.linalg.norm(B[i + 1 :] - B[i], axis=1))
            ok = mv > 2e-3
            allp.extend((np.abs(d[i + 1 :] - d[i])[ok] / mv[ok]).tolist())
    med = lambda x: float(np.median(x)) if x else float("nan")  # noqa: E731
    return {"rig_slope": med(slope), "rig_allpairs": med(allp)}


def drift_index(frames, poses: np.ndarray, min_life: int = 5, key: str = "stick_patch_points") -> float:
    """Median over ids (alive >= ``min_life`` frames) of their object-frame drift / the world move of the object point
    under them at their first frame, with object poses ``poses`` (N, 4, 4, T_world_object) of ``frames``."""
    tracks: dict[int, list] = {}
    for tf, T in zip(frames, poses, strict=True):
        Ti = np.linalg.inv(T)
        for cid, P in zip(tf.info.get("stick_ids", ()), tf.info.get(key, ()), strict=True):
            tracks.setdefault(int(cid), []).append((T, Ti[:3, :3] @ P + Ti[:3, 3]))
    vals = []
    for tr in tracks.values():
        if len(tr) < min_life:
            continue
        (T0, o0), (T1, o1) = tr[0], tr[-1]
        moved = np.linalg.norm((T1[:3, :3] @ o0 + T1[:3, 3]) - (T0[:3, :3] @ o0 + T0[:3, 3]))
        if moved > 1e-3:
            vals.append(np.linalg.norm(o1 - o0) / moved)
    return float(np.median(vals)) if vals else float("nan")


def _run(args: tuple) -> dict:
    obj, occ, secs, seed, contacts = args
    from vtrack.threads import limit_threads

    limit_threads(1)
    from vtrack.eval.session_gt import SessionGroundTruth
    from vtrack.testing.sim import ycb_session
    from vtrack.tracking import window
    from vtrack.tracking.run import track_session
    from vtrack.tracking.slam import SLAM_STICKING_CONTACTS
    from vtrack.tracking.stick import contact_rigidity, contact_tracks, sticking_contacts_for

    path = ycb_session(obj, occ, secs, contact_mode=contacts, seed=seed)
    row: dict = dict(obj=obj, occlusion=occ, seconds=secs, seed=seed, contacts=contacts)
    kf: dict = {}
    m, (_, est) = track_session(path, "", shape="slam", write=False, return_poses=True, keep_frames=kf)
    row["default_err_mm"] = float(m["motion_err_mm"])
    tfs = [fr.tracking_frame() for _, fr in kf["built"]]
    sticker = sticking_contacts_for(SLAM_STICKING_CONTACTS, ("touch",))
    for (_, fr), tf in zip(kf["built"], tfs, strict=True):
        sticker.annotate(fr, tf)
    row["rig_end"] = contact_rigidity(tfs, key="stick_patch_points")[0]
    row["rig_gel"] = contact_rigidity(tfs)[0]
    row.update(rigidity_variants(contact_tracks(tfs, "stick_patch_points")))
    row["drift_est"] = drift_index(tfs, est)
    gt = SessionGroundTruth.load(path)  # diagnosis only (see the module doc)
    row["drift_gt"] = drift_index(tfs, gt.poses_at(np.array([tf.t for tf in tfs])))
    # the sticking run, counting the anchored ids its slip test passes
    counts = [0, 0]
    orig = window.WindowTracker._stick_pairs

    def counted(self, fr, T_pred):
        out = orig(self, fr, T_pred)
        ids = fr.info.get("stick_ids")
        if ids is not None and len(ids):
            counts[0] += sum(1 for i in np.asarray(ids).tolist() if i in self._stick_anchors and i in self._stick_last)
            counts[1] += 0 if out is None else len(out[0])
        return out

    window.WindowTracker._stick_pairs = counted
    try:
        ms = track_session(path, "", shape="slam", write=False, **dict(SLAM_STICKING_CONTACTS))
    finally:
        window.WindowTracker._stick_pairs = orig
    row["preset_err_mm"] = float(ms["motion_err_mm"])
    row["slip_pass"] = counts[1] / counts[0] if counts[0] else float("nan")
    print(row, flush=True)
    return row


def main() -> None:
    from sweep_cli import run_contact_mode_sweep

    run_contact_mode_sweep("Other blind measures of sticking contacts, per session.", _run)


if __name__ == "__main__":
    main()
