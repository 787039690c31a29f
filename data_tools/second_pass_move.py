"""How far SLAM's second pass moves the map's surface off itself, per percentile, on chosen 5 s sessions (the statistic
of the plausibility gate ``second_pass_max_move``), with the motion error before / after the pass (GT for scoring
only). Both gates are switched off here, so every pass is kept and measured.

Usage: python data_tools/second_pass_move.py obj:seed:mode [...]
  mode: ``track`` (the `vtrack track` settings) or ``rec`` (the contact settings of `vtrack reconstruct`)
  e.g. python data_tools/second_pass_move.py 011_banana:0:rec 011_banana:1:track 006_mustard_bottle:0:track"""

import sys
from dataclasses import replace

from vtrack.threads import limit_threads

limit_threads(1)
from scipy.spatial import cKDTree  # noqa: E402

from vtrack.eval.session_gt import SessionGroundTruth, score_trajectory  # noqa: E402
from vtrack.fusion.reconstruct import TOUCH_DOWNSAMPLE, TOUCH_STRIDE  # noqa: E402
from vtrack.geometry import se3  # noqa: E402
from vtrack.testing.sim import ycb_session  # noqa: E402
from vtrack.tracking.run import track_session  # noqa: E402
from vtrack.tracking.slam import surface_move  # noqa: E402

PCTS = (50, 75, 90)
for spec in sys.argv[1:]:
    o, seed, mode = spec.split(":")
    path = ycb_session(o, "medium", 5.0, seed=int(seed))
    kw = dict(touch_stride=TOUCH_STRIDE, touch_downsample=TOUCH_DOWNSAMPLE) if mode == "rec" else {}
    kept: dict = {}
    track_session(path, "", shape="slam", write=False, keep_frames=kept, **kw)
    tr, P1, times = kept["tracker"], kept["poses_first_pass"], kept["frames"].times
    tr.slam_opts = replace(tr.slam_opts, second_pass_max_degenerate_rise=10.0, second_pass_max_move=0.0)
    T = tr.retrack_start(kept["second_pass_frames"], P1)
    Sall = tr.map.surfels()[0]
    tree, S = cKDTree(Sall), Sall[:: max(1, len(Sall) // 2000)]
    worst = {p: max(surface_move(se3.invert(P1[k]) @ T[k], S, tree, p) for k in range(len(T))) for p in PCTS}
    gt = SessionGroundTruth.load(path)
    e1, e2 = (score_trajectory(gt, times, E)[0]["motion_err_mm"] for E in (P1, T))
    print(
        spec,
        f"motion error {e1:.3f} -> {e2:.3f} mm;",
        "largest per-frame move, percentile: mm",
        {p: round(1e3 * v, 2) for p, v in worst.items()},
        f"degenerate rise {tr.second_pass_report['degenerate_rise']:.3f}",
        flush=True,
    )
