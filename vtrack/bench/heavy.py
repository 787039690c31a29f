"""``vtrack bench heavy``: touch where vision fails - the occlusion sweep for vision, touch and both (issue #20).

Blind tracking (segmentation and touch from the raw streams, SLAM's own frame / global registration of ``--mesh``;
ground truth for scoring only) of every shared YCB object at occlusion none / medium / heavy (2 s sessions,
``VTRACK_BENCH_HEAVY_SECONDS``; occlusions ``VTRACK_BENCH_HEAVY_OCC``, comma-separated), with vision only, touch only
and both: SLAM (object-motion error: ADD, ADD-S for symmetric objects, first-frame alignment) and known shape from
``--mesh`` without a pose (ADD-S in the mesh frame). Per occlusion and method the mean over objects, and the reduction
of visuo-tactile against vision-only (#20's target under heavy occlusion: >= 50 %). Seeds: ``vtrack bench heavy
--seeds 0,1,2`` (``VTRACK_BENCH_SEEDS``) runs every session of each seed, then reports the mean over objects per seed
and the mean and standard deviation of those over seeds (the comparison note reads the latter).
Sessions: the simulator's default sliding fingers, or ``VTRACK_BENCH_HEAVY_CONTACTS=stick`` for fingers that drive the
object (``sim.contact_mode: stick``; generated once and cached). The SLAM row "sticking-contacts preset"
(:data:`vtrack.tracking.slam.SLAM_STICKING_CONTACTS`, ``vtrack track --contacts stick``) is the setting for the latter;
on sliding sessions it shows what the preset costs when its assumption is wrong. The row "contacts auto"
(``--contacts auto``) runs both and keeps one blind (its ``ms`` includes the second run; ``contacts_chosen``).
Quick mode: the soup can under heavy occlusion, SLAM vision / both.
"""

from __future__ import annotations

import os
import time

from vtrack.bench.harness import BenchTable, add_seed_means, bench_seeds

MODES = {"vision": ("vision",), "touch": ("touch",), "vision+touch": ("vision", "touch")}
STICK_ROW = "slam/vision+touch sticking-contacts preset"
AUTO_ROW = "slam/vision+touch contacts auto"


def run(quick: bool = False) -> BenchTable:
    """Build the occlusion-sweep table (see the module docstring)."""
    from vtrack.threads import limit_threads

    limit_threads(1)
    from vtrack.errors import InputError
    from vtrack.paths import shared_data_dir
    from vtrack.testing.sim import DEFAULT_OBJECT, ycb_objects, ycb_session
    from vtrack.tracking.run import track_session
    from vtrack.tracking.slam import SLAM_STICKING_CONTACTS, SLAM_TOUCH_WEAK_VISION

    table = BenchTable(stage="heavy_occlusion", error_key="motion_err_mm", time_key="ms", threads=1)
    seconds = float(os.environ.get("VTRACK_BENCH_HEAVY_SECONDS", "2"))
    occs = os.environ.get("VTRACK_BENCH_HEAVY_OCC", "heavy" if quick else "none,medium,heavy").split(",")
    contacts = os.environ.get("VTRACK_BENCH_HEAVY_CONTACTS", "slide")
    if contacts not in ("slide", "stick"):
        raise InputError(
            "unknown contact mode", field="VTRACK_BENCH_HEAVY_CONTACTS", expected="slide|stick", got=contacts
        )
    objects = [DEFAULT_OBJECT] if quick else ycb_objects()
    runs = [(f"slam/{m}", dict(shape="slam", modalities=mods)) for m, mods in MODES.items()]
    # the SLAM heavy-occlusion preset (opt-in) beside the default, and the default without its contact budget (every
    # contact in frames that see little: SLAM's default before 2026-11-28, docs/benchmarks/few_touch.md)
    runs += [
        (
            "slam/vision+touch weak-vision preset",
            dict(shape="slam", modalities=MODES["vision+touch"], **SLAM_TOUCH_WEAK_VISION),
        ),
        (
            "slam/vision+touch all contacts (few_touch_points=0)",
            dict(shape="slam", modalities=MODES["vision+touch"], few_touch_points=0),
        ),
        (STICK_ROW, dict(shape="slam", modalities=MODES["vision+touch"], **SLAM_STICKING_CONTACTS)),
        # the blind choice between the default and the preset (`--contacts auto`): both runs, one kept
        (AUTO_ROW, dict(shape="slam", modalities=MODES["vision+touch"], select_contacts=True)),
    ]
    runs += [(f"known/{m}", dict(shape="known_shape", modalities=MODES[m])) for m in ("vision", "vision+touch")]
    if quick:
        runs = [r for r in runs if r[0] in ("slam/vision", "slam/vision+touch", "slam/vision+touch weak-vision preset")]
    seeds = bench_seeds()
    t0 = time.perf_counter()
    for occ, seed, obj in ((o, k, b) for o in occs for k in seeds for b in objects):
        sess = ycb_session(obj, occ, seconds, contact_mode=contacts, seed=seed)
        mesh = shared_data_dir() / "objects" / "ycb" / f"{obj}.ply"
        for name, kw in runs:
            if kw["shape"] == "known_shape":
                kw = {**kw, "mesh": mesh}
            try:
                m = track_session(sess, "", write=False, **kw)
            except InputError as e:  # e.g. no first pose by global registration: a result too
                table.notes.append(f"{name} {obj} {occ} seed {seed}: {e}")
                continue
            table.add(
                method=name,
                object=obj,
                occlusion=occ,
                seed=seed,
                motion_err_mm=m["motion_err_mm"],
                add_s_mm=m["add_s_mm"],
                # with a second run on the same frames (auto), its CPU too
                ms=m["cpu_ms_per_frame_mean"] + 1e3 * m.get("select_cpu_s", 0.0) / max(m["frames"], 1),
                frames=m["frames"],
                **({"contacts_chosen": m["contacts_choice"]["chosen"]} if "contacts_choice" in m else {}),
            )
    add_seed_means(table, by=("method", "occlusion"), means=("motion_err_mm", "add_s_mm", "ms"), sums=("frames",))
    # the headline comparison: over every seed when there are several, else the one seed's mean over objects
    final = "all" if len(seeds) > 1 else seeds[0]
    means = {
        (r["method"], r["occlusion"]): r for r in table.rows if r.get("object") == "all" and r.get("seed") == final
    }
    pairs = [("slam", row, "motion_err_mm") for row in ("slam/vision+touch", STICK_ROW, AUTO_ROW)]
    for shape, row, key in [*pairs, ("known", "known/vision+touch", "add_s_mm")]:
        for occ in occs:
            v, vt = means.get((f"{shape}/vision", occ)), means.get((row, occ))
            if v and vt and v["n_objects"] == vt["n_objects"] and v[key] > 0:
                table.notes.append(
                    f"{contacts} sessions, {occ}: {row} {vt[key]:.2f} mm vs {shape}/vision {v[key]:.2f} mm "
                    f"({key}, mean of {v['n_objects']} objects, seeds {','.join(map(str, seeds))}): "
                    f"{abs(pct := 100.0 * (1.0 - vt[key] / v[key])):.0f} % {'lower' if pct >= 0 else 'higher'}"
                )
    table.notes.append(
        f"blind; {seconds:g} s sessions, {contacts} fingers (sim.contact_mode); motion_err_mm: ADD of the object's "
        "motion since the first frame (ADD-S for symmetric objects), add_s_mm: absolute ADD-S in the mesh frame "
        "(known shape); ms: CPU per frame on 1 thread "
        f"incl. segmentation and the tactile pipeline; {time.perf_counter() - t0:.0f} s wall."
    )
    return table
