"""Micro A/B of helper ``speed2``'s two frames-layer changes, interleaved in ONE process on the same inputs.

1. The hand render of the segmenter (``HandAwareSegmenter.render_hand_depth``: splat + exact-silhouette ray casts)
   of an older code snapshot vs this tree, on the link poses of every camera frame of the blind 2 s mustard (none)
   and mug (medium) sessions; also counts the pixels that differ (expected 0).
2. The touch part of ``SessionFrames.build``: the four tactile images of a time step one by one
   (``TouchSource.contact`` per sensor, the old path) vs together (``TouchSource.contacts`` ->
   ``contact_only_many``), on the same decoded frames; also checks the contacts are identical.

Prints CPU time (``time.process_time``) medians over rounds. Under load only the ratios mean something.

Usage: ``python data_tools/frames_touch_seg_micro_ab.py OLD_DIR [ROUNDS]`` with OLD_DIR a snapshot holding
``vtrack/`` (e.g. ``git archive 083a3c6 vtrack | tar -x -C OLD_DIR``).
"""

from __future__ import annotations

import sys
import time

import numpy as np
from snapshot_module import load as _load


def main() -> None:
    from vtrack.threads import limit_threads

    limit_threads(1)
    import vtrack.frames.segmentation as new_seg
    from vtrack.frames.session import SessionFrames
    from vtrack.testing.sim import ycb_session

    old_dir, rounds = sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 5
    old_seg = _load(f"{old_dir}/vtrack/frames/segmentation.py", "old_segmentation")

    renders, touch = [], []  # (segmenter, link poses); (TouchSource, [(sensor, raw)])
    for name, occ in (("006_mustard_bottle", "none"), ("025_mug", "medium")):
        sf = SessionFrames(ycb_session(name, occ, 2), modalities=("vision", "touch"), colour=False)
        for k in range(len(sf)):
            raw = sf.read(k)
            q = sf.q[k]
            for c in sf.cams:
                if c.segmenter is not None and q is not None and np.all(np.isfinite(q)):
                    renders.append((c.segmenter, c.segmenter.kin.link_poses(q)))
            touch.append((sf.touch, raw["touch"]))

    def render(cls) -> tuple[list, float]:
        for seg, _ in renders:
            seg.__class__ = cls  # the snapshot's methods on the same instances (same samples, same ray casters)
        out, c0 = [], time.process_time()
        for seg, poses in renders:
            out.append(seg.render_hand_depth(poses, with_core=True))
        return out, (time.process_time() - c0) / len(renders) * 1e3

    def contacts(batched: bool) -> tuple[list, float]:
        out, c0 = [], time.process_time()
        for src, frames in touch:
            out.append(src.contacts(frames) if batched else [src.contact(s, r) for s, r in frames])
        return out, (time.process_time() - c0) / len(touch) * 1e3

    res: dict[str, list[float]] = {k: [] for k in ("render_old", "render_new", "touch_single", "touch_batched")}
    for r in range(rounds):
        a, t_old = render(old_seg.HandAwareSegmenter)
        b, t_new = render(new_seg.HandAwareSegmenter)
        diff = sum(int((x[0] != y[0]).sum() + (x[1] != y[1]).sum()) for x, y in zip(a, b, strict=True))
        c, t_single = contacts(False)
        d, t_batched = contacts(True)
        same = all(
            np.array_equal(u.points, v.points) and np.array_equal(u.normals, v.normals) and u.valid == v.valid
            for x, y in zip(c, d, strict=True)
            for u, v in zip(x, y, strict=True)
        )
        for k, v in zip(res, (t_old, t_new, t_single, t_batched), strict=True):
            res[k].append(v)
        print(
            f"round {r}: hand render old {t_old:.3f} new {t_new:.3f} ms/frame (differing pixels {diff}); "
            f"touch one by one {t_single:.3f} together {t_batched:.3f} ms per time step (identical {same})",
            flush=True,
        )
    med = {k: float(np.median(v)) for k, v in res.items()}
    print(
        f"median: hand render {med['render_old']:.3f} -> {med['render_new']:.3f} ms per camera frame "
        f"(x{med['render_new'] / med['render_old']:.3f}); touch {med['touch_single']:.3f} -> "
        f"{med['touch_batched']:.3f} ms per time step (x{med['touch_batched'] / med['touch_single']:.3f}); "
        f"{len(renders)} camera frames, {len(touch)} time steps"
    )


if __name__ == "__main__":
    main()
