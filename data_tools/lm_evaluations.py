"""Window evaluations per LM solve of blind SLAM (``WindowTracker._total`` calls per ``_optimise``, online and second
pass) and the mean object-motion error (mm, scored against ``gt/`` by the eval code) of blind SLAM over the 6 YCB
objects, one thread, with the tracker options given as JSON (e.g. ``'{"small_step": "accept"}'``).

Usage: ``python data_tools/lm_evaluations.py [OPTS_JSON [SECONDS OCCLUSIONS SEEDS]]``; default ``{} 2 none,medium 0``
(the 12 2 s sessions of the speed figures), e.g. ``python data_tools/lm_evaluations.py '{}' 5 medium 0,1,2``.
"""

import json
import sys

from vtrack.threads import limit_threads


def main(opts: dict, seconds: float, occlusions: list[str], seeds: list[int]) -> None:
    limit_threads(1)
    import vtrack.tracking.window as win
    from vtrack.testing.sim import ycb_objects, ycb_session
    from vtrack.tracking.run import track_session

    count = {"solves": 0, "evals": 0}
    optimise, total = win.WindowTracker._optimise, win.WindowTracker._total

    def counted_total(self, *a, **k):
        count["evals"] += 1
        return total(self, *a, **k)

    def counted_optimise(self, *a, **k):
        count["solves"] += 1
        return optimise(self, *a, **k)

    win.WindowTracker._optimise, win.WindowTracker._total = counted_optimise, counted_total
    errs: dict[str, list[float]] = {occ: [] for occ in occlusions}
    cpu = []
    for occ in occlusions:
        for seed in seeds:
            for name in ycb_objects():
                p = ycb_session(name, occ, seconds=seconds, seed=seed)
                m = track_session(p, "", shape="slam", write=False, **opts)
                errs[occ].append(m["motion_err_mm"])
                cpu.append(m["cpu_ms_per_frame_mean"])
                print(occ, seed, name, round(m["motion_err_mm"], 3), flush=True)
    mean_err = ", ".join(f"{occ} {sum(e) / len(e):.3f}" for occ, e in errs.items())
    print(
        f"options {opts}, {seconds:g} s, seeds {seeds}: {count['evals']} evaluations in {count['solves']} solves = "
        f"{count['evals'] / max(count['solves'], 1):.2f} per solve; mean motion error {mean_err} mm; "
        f"CPU {sum(cpu) / len(cpu):.2f} ms per frame"
    )


if __name__ == "__main__":
    a = sys.argv[1:]
    main(
        json.loads(a[0]) if a else {},
        float(a[1]) if len(a) > 1 else 2.0,
        a[2].split(",") if len(a) > 2 else ["none", "medium"],
        [int(x) for x in a[3].split(",")] if len(a) > 3 else [0],
    )
