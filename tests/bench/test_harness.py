"""Benchmark harness: timing, Pareto front, CSV/MD/PNG output."""

from __future__ import annotations

import csv
import re
import time
from pathlib import Path

import numpy as np

from vtrack.bench.harness import BenchTable, speed_probe_ms, time_call, write_results


def test_time_call_measures_sleep() -> None:
    r = time_call(lambda: time.sleep(0.01), warmup=1, repeat=5)
    assert r["n_timed"] == 5
    assert 9.0 <= r["ms_median"] < 60.0 and r["ms_p95"] >= r["ms_median"] and r["ms_min"] <= r["ms_median"]


def test_speed_probe_measures_its_work() -> None:
    """The probe times work, not overhead: three times the workload takes about three times the CPU (interleaved
    so that a change of the machine's speed during the test hits both arms)."""
    one, three = [], []
    for _ in range(3):
        one.append(speed_probe_ms(repeats=1))
        three.append(speed_probe_ms(repeats=1, scale=3))
    assert 0.05 < min(one) < 1000.0
    assert 2.0 < min(three) / min(one) < 4.5


def test_pareto_front_lower_and_higher_is_better() -> None:
    t = BenchTable("x", error_key="err")
    for ms, err in [(1, 5.0), (2, 3.0), (3, 4.0), (4, 1.0), (5, 1.0), (0.5, float("nan"))]:
        t.add(method="m", ms=ms, err=err)
    assert t.pareto_mask().tolist() == [True, True, False, True, False, False]
    f = BenchTable("y", error_key="f", higher_is_better=True)
    for ms, s in [(1, 0.5), (2, 0.4), (3, 0.9)]:
        f.add(method="m", ms=ms, f=s)
    assert f.pareto_mask().tolist() == [True, False, True]


def test_write_results_files(tmp_path: Path) -> None:
    t = BenchTable("demo_stage", error_key="err", notes=["a note"])
    rng = np.random.default_rng(0)
    for m in ("a", "b"):
        for s in (1, 2, 4):
            t.add(method=m, setting=f"res{s}", ms=float(s * (1 + (m == "b"))), err=float(rng.random()))
    paths = write_results(t, out_dir=tmp_path)
    rows = list(csv.DictReader(open(paths["csv"])))
    assert len(rows) == 6 and {"method", "setting", "ms", "err", "pareto"} <= set(rows[0])
    md = paths["md"].read_text()
    assert "★" in md and "a note" in md and "demo_stage.png" in md
    assert re.search(r"speed probe \d+(\.\d+)? ms", md)  # the cores' speed at the time, on the Machine line
    from PIL import Image

    im = np.asarray(Image.open(paths["png"]).convert("L"))
    assert im.shape[0] > 200 and im.std() > 5  # a real plot, not a blank image
    index = tmp_path / "README.md"
    assert "demo_stage" in index.read_text()
    # a hand-written note after a stage's links survives the next run of any stage
    index.write_text(index.read_text().replace("[plot](demo_stage.png)", "[plot](demo_stage.png) (the 20 s run)"))
    write_results(BenchTable("other", error_key="err", rows=[dict(method="m", setting="s", ms=1.0, err=0.5)]), tmp_path)
    text = index.read_text()
    assert "[plot](demo_stage.png) (the 20 s run)" in text and "[other](other.md)" in text
    # ... and so does a description between the page link and its links (it was dropped: the entry did not start
    # with the generated line any more)
    index.write_text(text.replace("- [other](other.md) —", "- [other](other.md) (what it measures) —"))
    write_results(BenchTable("third", error_key="err", rows=[dict(method="m", setting="s", ms=1.0, err=0.5)]), tmp_path)
    text = index.read_text()
    assert "- [other](other.md) (what it measures) — [csv](other.csv), [plot](other.png)" in text
    assert "[plot](demo_stage.png) (the 20 s run)" in text and "[third](third.md)" in text


def test_add_group_means():
    t = BenchTable(stage="x", error_key="err")
    for obj, occ, err, frames in (
        ("a", "none", 1.0, 10),
        ("b", "none", 3.0, 20),
        ("a", "heavy", 9.0, 5),
        ("c", "none", float("nan"), 1),
        ("a", "medium", 2.0, 7),
    ):
        t.add(method="m", object=obj, occlusion=occ, err=err, frames=frames)
    t.add_group_means(
        by=("method", "occlusion"),
        means=("err",),
        sums=("frames",),
        where=lambda r: r["occlusion"] != "heavy",
        label=lambda key, rows: {"object": "all", "worst": max(r["err"] for r in rows[:2])},
    )
    added = t.rows[5:]
    # one group of three (NaN ignored in the mean); the single-row "medium" group is below min_rows=2
    assert len(added) == 1
    assert added[0] == {"method": "m", "occlusion": "none", "err": 2.0, "frames": 31, "object": "all", "worst": 3.0}


def test_bench_seeds_parse_and_reject(monkeypatch) -> None:
    import pytest

    from vtrack.bench.harness import bench_seeds
    from vtrack.errors import InputError

    monkeypatch.delenv("VTRACK_BENCH_SEEDS", raising=False)
    assert bench_seeds() == [0]  # the committed tables' seed
    monkeypatch.setenv("VTRACK_BENCH_SEEDS", " 0,2,1 ")
    assert bench_seeds() == [0, 2, 1]
    for bad in ("0,x", "-1", "1,1", ","):
        monkeypatch.setenv("VTRACK_BENCH_SEEDS", bad)
        with pytest.raises(InputError, match="VTRACK_BENCH_SEEDS"):
            bench_seeds()


def test_seed_means_average_objects_per_seed_then_seeds() -> None:
    from vtrack.bench.harness import add_seed_means

    t = BenchTable("s", error_key="err")
    # two methods, 3 objects, 3 seeds; err = object index + seed (+ 10 for method b); one NaN cell
    for m, off in (("a", 0.0), ("b", 10.0)):
        for seed in (0, 1, 2):
            for i, obj in enumerate(("o1", "o2", "o3")):
                err = float("nan") if (m, seed, obj) == ("b", 2, "o3") else i + seed + off
                t.add(method=m, object=obj, seed=seed, err=err, frames=10)
    add_seed_means(t, by=("method",), means=("err",), sums=("frames",))
    per_seed = {(r["method"], r["seed"]): r for r in t.rows if r["object"] == "all" and r["seed"] != "all"}
    assert len(per_seed) == 6
    assert per_seed[("a", 1)]["err"] == 2.0 and per_seed[("a", 1)]["frames"] == 30
    assert per_seed[("b", 2)]["err"] == 12.5 and per_seed[("b", 2)]["n_objects"] == 3  # NaN ignored in the mean
    over = {r["method"]: r for r in t.rows if r["seed"] == "all"}
    assert over["a"]["err"] == 2.0 and over["a"]["n_seeds"] == 3
    assert np.isclose(over["a"]["err_sd_seeds"], 1.0)  # per-seed means 1, 2, 3
    assert np.isclose(over["b"]["err"], (11 + 12 + 12.5) / 3)
    one = BenchTable("one", error_key="err")
    for obj in ("o1", "o2"):
        one.add(method="a", object=obj, seed=0, err=1.0)
    add_seed_means(one, by=("method",), means=("err",))
    assert [r["seed"] for r in one.rows if r["object"] == "all"] == [0]  # one seed: no over-seeds row


def test_tracking_bench_aggregate_over_objects_and_seeds() -> None:
    from vtrack.bench.tracking import add_object_means

    t = BenchTable("tracking", error_key="drift_mm")
    keys = ("ms", "wall_ms", "drift_mm", "add_s_mm", "motion_err_mm", "rot_drift_deg", "poses_per_s")
    for seed in (0, 1):
        for i, obj in enumerate(("a", "b", "c")):
            for occ in ("none", "medium", "heavy"):
                row = {k: float(i + 10 * seed) for k in keys}
                t.add(method="slam", data="sim", object=obj, occlusion=occ, noise=1.0, seed=seed, frames=60, **row)
    t.add(method="slam", data="synthetic", object="a", occlusion="none", noise=1.0, seed=0, frames=5, **row)
    add_object_means(t)
    agg = {r["setting"]: r for r in t.rows if r["object"] == "all"}
    assert set(agg) == {
        "all 3 objects none seed 0",
        "all 3 objects none seed 1",
        "all 3 objects medium seed 0",
        "all 3 objects medium seed 1",
        "all 3 objects none, 2 seeds",
        "all 3 objects medium, 2 seeds",
    }  # heavy occlusion and the synthetic row stay out
    assert (
        agg["all 3 objects medium seed 1"]["motion_err_mm"] == 11.0
        and agg["all 3 objects none seed 0"]["frames"] == 180
    )
    over = agg["all 3 objects none, 2 seeds"]
    assert over["motion_err_mm"] == 6.0 and np.isclose(over["motion_err_mm_sd_seeds"], np.std([1.0, 11.0], ddof=1))
    one = BenchTable("tracking", error_key="drift_mm")
    for obj in ("a", "b"):
        one.add(method="slam", data="sim", object=obj, occlusion="none", noise=1.0, seed=0, frames=60, **row)
    add_object_means(one)
    assert [r["setting"] for r in one.rows if r["object"] == "all"] == ["all 2 objects none"]  # one seed: as before
