"""Component micro A/B of the colour term's cost, interleaved in ONE process: an older code snapshot vs this tree.

Under load a whole-pipeline A/B of a few-percent change drowns in noise (the same code's 12-session mean moved
by +-15 % between consecutive runs at load 10-16); alternating the changed components on the same inputs in one
process does not. Compares, old vs new: the frames layer's colour tracks (grey conversion + mask upsampling +
``FeatureTracks.update`` over the camera frames of the blind 2 s mustard (none) and mug (medium) sessions), the
colour residuals of a window (2-3 slots of 30-60 tracks, per evaluation) and the Huber weights (300 residuals).
Prints the median over rounds of each (ms per frame, ms per evaluation, us per call).

Usage: ``python data_tools/slam_colour_micro_ab.py OLD_DIR [ROUNDS]`` with OLD_DIR a snapshot holding
``vtrack/`` (e.g. ``git archive 75cedb8 vtrack | tar -x -C OLD_DIR``).
"""

from __future__ import annotations

import sys
import time

import numpy as np
from snapshot_module import load as _load


def _camera_frames() -> list[list[tuple[np.ndarray, np.ndarray]]]:
    """(RGB, strided object mask) of every frame of two sessions, through the frames layer (blind segmentation)."""
    from vtrack.frames.session import SessionFrames
    from vtrack.testing.sim import ycb_session

    out = []
    for name, occ in (("006_mustard_bottle", "none"), ("025_mug", "medium")):
        sf = SessionFrames(ycb_session(name, occ, 2), modalities=("vision", "touch"), colour=True)
        seq = []
        for k in range(len(sf)):
            raw = sf.read(k)
            fr = sf.build(raw)
            c = sf.cams[0]
            seq.append((raw["rgb"][c.name], fr.vision_mask[c.name]))
        out.append(seq)
    return out


def main() -> None:
    from vtrack.threads import limit_threads

    limit_threads(1)
    import vtrack.frames.session as new_session
    import vtrack.tracking.colour as new_colour
    import vtrack.tracking.window as new_window
    from vtrack.tracking.frame import TrackingFrame

    old_dir, rounds = sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 5
    old_colour = _load(f"{old_dir}/vtrack/tracking/colour.py", "old_colour")
    old_window = _load(f"{old_dir}/vtrack/tracking/window.py", "old_window")
    old_session = _load(f"{old_dir}/vtrack/frames/session.py", "old_session")
    data = _camera_frames()
    res: dict[str, list[float]] = {}
    rng = np.random.default_rng(0)

    def slot(n: int):
        T = new_window._exp(np.concatenate([rng.normal(0, 0.05, 3), rng.normal(0, 0.4, 3)]))
        Q = rng.normal(0, 0.03, (n, 3))
        P = Q @ T[:3, :3].T + T[:3, 3] + rng.normal(0, 0.002, (n, 3))
        C = np.tile([0.05, -0.1, -0.4], (n, 1))
        return new_window._Slot(T=T, t=0.0, frame=TrackingFrame(t=0.0), T_prior=T.copy(), colour=(P, Q, C))

    class _Plane:
        def query(self, p, with_grad=True):
            return p[:, 2], np.tile([0.0, 0.0, 1.0], (len(p), 1))

    wins = [[slot(int(rng.integers(30, 60))) for _ in range(int(rng.integers(2, 4)))] for _ in range(200)]
    tr_new = new_window.WindowTracker(_Plane(), np.eye(4), {"sigma_colour": 0.001})
    tr_old = old_window.WindowTracker(_Plane(), np.eye(4), {"sigma_colour": 0.001})
    r = rng.normal(0, 2, 300)
    for _ in range(rounds):
        for tag, col, ses in (("old", old_colour, old_session), ("new", new_colour, new_session)):
            n, n_tracks, c0 = 0, 0, time.process_time()
            for seq in data:
                ft = col.FeatureTracks()
                for rgb, m in seq:
                    full = ses.upsample_mask(m, rgb.shape[:2])
                    ids, _ = ft.update(col.to_grey(rgb) if tag == "old" else rgb, full)
                    n, n_tracks = n + 1, n_tracks + len(ids)
            res.setdefault(f"colour tracks {tag}, ms per frame", []).append((time.process_time() - c0) / n * 1e3)
            res.setdefault(f"track observations {tag}", []).append(n_tracks)
        c0 = time.process_time()
        for w in wins:
            for s in w:
                tr_old._colour_terms(s)
        res.setdefault("colour residuals old, ms per evaluation", []).append(
            (time.process_time() - c0) / len(wins) * 1e3
        )
        c0 = time.process_time()
        for w in wins:
            tr_new._window_colour_terms(w)
        res.setdefault("colour residuals new, ms per evaluation", []).append(
            (time.process_time() - c0) / len(wins) * 1e3
        )
        for tag, f in (("old", old_window._robust_weights), ("new", new_window._robust_weights)):
            c0 = time.process_time()
            for _ in range(3000):
                f(r, "huber", 1.5)
            res.setdefault(f"Huber weights {tag}, us per call", []).append((time.process_time() - c0) / 3000 * 1e6)
    for k, v in res.items():
        print(f"{k:42s} median {np.median(v):.4f}  ({', '.join(f'{x:.3f}' for x in v)})")


if __name__ == "__main__":
    main()
