"""``vtrack bench speed``: offline tracking throughput on the machine's cores (issue #20: >= 30 poses/s, 2 cores).

Blind SLAM (the default options) over every shared YCB object (5 s sessions at medium occlusion,
``VTRACK_BENCH_SPEED_SECONDS`` / ``VTRACK_BENCH_SPEED_OCC``; seeds ``--seeds``), each session tracked twice in turn:
``in process`` (read, segmentation, tactile pipelines, colour tracks and the tracker step one after the other on one
core), ``prefetch`` (the frames built ahead of the tracker in child processes, the tactile pipelines in one,
segmentation and the rest in the other, :mod:`vtrack.frames.prefetch`; ``vtrack track --prefetch``) and ``prefetch,
one child`` (``--prefetch single``: both in one child, the layout before 2026-11-28; an ablation). This process runs
one thread either way, and so does each child.

Per run: ``poses_per_s`` (frames / wall time of the per-frame loop, the child's start included; ``wall_ms`` its
inverse), ``steady_poses_per_s``
(the same without the wait for the first frame, i.e. what a long session approaches), ``ms`` (CPU per frame of the
build and the step, both processes; reading excluded), ``wall_s`` (the whole call: set-up, loop, SLAM's offline second
pass), the motion error, and ``max_pose_diff`` (largest difference of a pose matrix entry from the in-process run:
the two must track the same). Objects: ``VTRACK_BENCH_SPEED_OBJECTS`` (comma-separated); quick mode: the default
object (the tomato soup can) only.
"""

from __future__ import annotations

import os
import time

from vtrack.bench.harness import BenchTable, add_seed_means, bench_seeds

VARIANTS = {"in process": "off", "prefetch": "on", "prefetch, one child": "single"}


def run(quick: bool = False) -> BenchTable:
    """Build the throughput table (see the module docstring)."""
    from vtrack.threads import limit_threads

    limit_threads(1)
    import numpy as np

    from vtrack.testing.sim import DEFAULT_OBJECT, ycb_objects, ycb_session
    from vtrack.threads import available_cpus
    from vtrack.tracking.run import track_session, warm_up

    warm_up("slam", write=False)  # imports before the first timed run (it would pay them alone)

    # x axis: wall time per frame (what the prefetch changes; the CPU per frame stays about the same)
    table = BenchTable(stage="speed", error_key="motion_err_mm", time_key="wall_ms", threads=1)
    seconds = float(os.environ.get("VTRACK_BENCH_SPEED_SECONDS", "5"))
    occ = os.environ.get("VTRACK_BENCH_SPEED_OCC", "medium")
    only = [o for o in os.environ.get("VTRACK_BENCH_SPEED_OBJECTS", "").split(",") if o]
    objects = only or ([DEFAULT_OBJECT] if quick else ycb_objects())
    seeds = bench_seeds()
    t_all = time.perf_counter()
    for k, (seed, obj) in enumerate((s, b) for s in seeds for b in objects):
        sess = ycb_session(obj, occ, seconds, seed=seed)
        order = list(VARIANTS.items())
        order = order[k % len(order) :] + order[: k % len(order)]  # rotate who goes first: the machine's speed drifts
        poses = {}
        for name, mode in order:
            t0 = time.perf_counter()
            m, (_, T) = track_session(sess, "", shape="slam", write=False, return_poses=True, prefetch=mode)
            wall = time.perf_counter() - t0
            poses[name] = T
            n, loop, first = m["frames"], m["frames_wall_s"], m["first_wait_s"]
            table.add(
                method=name,
                object=obj,
                occlusion=occ,
                seed=seed,
                poses_per_s=n / max(loop, 1e-9),
                wall_ms=1e3 * loop / max(n, 1),
                steady_poses_per_s=(n - 1) / max(loop - first, 1e-9),
                ms=m["cpu_ms_per_frame_mean"],
                first_wait_s=first,
                wall_s=wall,
                motion_err_mm=m["motion_err_mm"],
                frames=n,
            )
        diff = max(float(np.abs(poses[v] - poses["in process"]).max()) for v in VARIANTS)
        for row in table.rows[-len(VARIANTS) :]:
            row["max_pose_diff"] = diff
        if diff > 1e-9:
            table.notes.append(f"{obj} seed {seed}: prefetched poses differ from in-process ones by {diff:.3g}")
    add_seed_means(
        table,
        by=("method",),
        means=("poses_per_s", "wall_ms", "steady_poses_per_s", "ms", "first_wait_s", "wall_s", "motion_err_mm"),
        sums=("frames",),
    )
    final = "all" if len(seeds) > 1 else seeds[0]
    means = {r["method"]: r for r in table.rows if r.get("object") == "all" and r.get("seed") == final}
    if len(means) == len(VARIANTS):
        a = means["in process"]
        table.notes.append(
            f"mean over {a['n_objects']} objects: in process {a['poses_per_s']:.1f} poses/s; "
            + "; ".join(
                f"{v} {means[v]['poses_per_s']:.1f} poses/s ({means[v]['steady_poses_per_s']:.1f} without the "
                f"children's start, whole call {means[v]['wall_s']:.1f} s)"
                for v in VARIANTS
                if v != "in process"
            )
            + f"; in process whole call {a['wall_s']:.1f} s"
        )
    table.notes.append(
        f"blind SLAM, {seconds:g} s sessions at {occ} occlusion; {available_cpus()} CPUs; this process 1 thread, each "
        f"prefetch child 1 thread; ms: CPU per frame of build + step (all processes, reading excluded); "
        f"{time.perf_counter() - t_all:.0f} s wall."
    )
    return table
