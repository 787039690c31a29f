"""Benchmark harness: timing, machine info, and CSV + markdown + Pareto-plot output.

A stage builds a :class:`BenchTable` of rows (one per method x operating point), each with at
least ``method``, ``setting``, ``ms`` (median per unit of work) and an error column, then calls
:func:`write_results`. The harness records thread count, machine and git revision.
"""

from __future__ import annotations

import csv
import os
import platform
import subprocess
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.io.jsonio import write_json
from vtrack.paths import REPO_ROOT


def benchmarks_dir() -> Path:
    """Where benchmark results go: ``VTRACK_BENCH_DIR`` (set by ``vtrack bench --out``), else
    ``results/benchmarks`` under the current folder (an installed package has no docs/ to write into; the
    repository's committed tables are refreshed with ``--out docs/benchmarks``)."""
    d = Path(os.environ.get("VTRACK_BENCH_DIR", Path.cwd() / "results" / "benchmarks"))
    d.mkdir(parents=True, exist_ok=True)
    return d


def time_call(fn: Callable[[], Any], *, warmup: int = 1, repeat: int = 5, min_seconds: float = 0.0) -> dict[str, float]:
    """Time ``fn()``: warm-up calls, then at least ``repeat`` timed calls (and ``min_seconds`` total).

    Returns median, p95, mean and min in milliseconds plus the number of timed calls.
    """
    for _ in range(max(0, warmup)):
        fn()
    times = []
    t_start = time.perf_counter()
    while len(times) < max(1, repeat) or (time.perf_counter() - t_start) < min_seconds:
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
        if len(times) > 10_000:
            break
    a = np.asarray(times)
    return {
        "ms_median": float(np.median(a)),
        "ms_p95": float(np.percentile(a, 95)),
        "ms_mean": float(a.mean()),
        "ms_min": float(a.min()),
        "n_timed": len(a),
    }


def git_revision() -> str:
    try:
        return (
            subprocess.run(
                ["git", "rev-parse", "--short", "HEAD"], cwd=REPO_ROOT, capture_output=True, text=True, timeout=5
            ).stdout.strip()
            or "unknown"
        )
    except Exception:
        return "unknown"


def _probe_workload(scale: int = 1) -> float:
    """The fixed work of :func:`speed_probe_ms`: many small numpy calls (the per-frame pattern of the pipeline's
    stages) and plain interpreter work; returns a checksum so that nothing is optimised away."""
    a = np.random.default_rng(0).random(4096)
    acc = 0.0
    for _ in range(60 * scale):
        b = np.sqrt(a * a + 1.0)
        acc += float(np.sort(b)[100]) + float(b.sum())
    d: dict[int, int] = {}
    for i in range(20000 * scale):
        d[i & 1023] = d.get(i & 1023, 0) + i
    return acc + sum(d.values())


def speed_probe_ms(repeats: int = 5, scale: int = 1) -> float:
    """CPU ms of this thread for a fixed reference workload (best of ``repeats``): how fast this machine's cores
    are right now. The CPU speed of a shared machine changes within hours (up to ~1.8x seen here) while the load
    average stays low, so a benchmark figure in wall or CPU time is comparable with another only at a similar
    probe. Thread CPU time, so waiting for a core on a loaded machine does not count (``load1`` shows that).
    About 8 ms per repeat on a fast phase of the 2-core machine of 2026-11-29."""
    best = float("inf")
    for _ in range(max(1, repeats)):
        c0 = time.thread_time()
        _probe_workload(scale)
        best = min(best, (time.thread_time() - c0) * 1e3)
    return round(best, 3)


def machine_info() -> dict[str, Any]:
    info = {
        "machine": platform.machine(),
        "processor": platform.processor() or platform.machine(),
        "cpus": os.cpu_count(),
        "python": platform.python_version(),
        "git": git_revision(),
        "speed_probe_ms": speed_probe_ms(),
    }
    try:
        import torch  # noqa: F401  (only if already importable; records the thread setting)

        info["torch_threads"] = torch.get_num_threads()
    except Exception:
        pass
    return info


def bench_seeds() -> list[int]:
    """Simulator seeds of the session benchmarks (tracking, heavy, fusion): ``VTRACK_BENCH_SEEDS`` (``vtrack bench
    --seeds 0,1,2``), default ``[0]``, the seed every committed table used. Seed ``k`` is a new session of the same
    object, occlusion and object trajectory (``ycb_session(..., seed=k)``: other finger pressures, joints, contacts and
    sensor noise), so a mean over seeds shows what holds beyond one recording.

    Raises:
        InputError: the variable is not a comma-separated list of distinct non-negative integers.
    """
    return env_list(
        "VTRACK_BENCH_SEEDS",
        int,
        [0],
        lambda s: s >= 0,
        "bad benchmark seeds",
        field="VTRACK_BENCH_SEEDS / --seeds",
        expected="distinct integers >= 0, e.g. 0,1,2",
    )


def env_list(
    var: str,
    kind: Callable[[str], Any],
    default: list,
    valid: Callable[[Any], bool],
    message: str,
    field: str,
    expected: str,
) -> list:
    """A comma-separated list of distinct values from the environment variable ``var`` (``kind`` parses each item,
    ``valid`` checks it); ``default`` when unset or blank.

    Raises:
        InputError: an item does not parse or is not valid, or two are equal (``message``, ``field``, ``expected``).
    """
    from vtrack.errors import InputError

    raw = os.environ.get(var, "").strip()
    if not raw:
        return list(default)
    try:
        values = [kind(v) for v in raw.split(",")]
    except ValueError:
        values = []
    if not values or not all(valid(v) for v in values) or len(set(values)) != len(values):
        raise InputError(message, field=field, expected=expected, got=raw)
    return values


def add_seed_means(
    table: BenchTable,
    by: tuple[str, ...],
    means: tuple[str, ...],
    sums: tuple[str, ...] = (),
    where: Callable[[dict], bool] | None = None,
    extra: Callable[[list[dict]], dict[str, Any]] | None = None,
    min_objects: int = 1,
) -> None:
    """Per-object rows of several seeds -> mean over objects per seed (``object="all"``, ``seed=k``) and, with two or
    more seeds, the mean of those per-seed means with their standard deviation (``seed="all"``, columns
    ``<key>_sd_seeds``, sample sd over seeds). Rows must carry ``object`` and ``seed``; ``by`` are the other grouping
    columns (e.g. method, occlusion); ``where`` selects the per-object rows (default: all); ``extra(rows)`` adds
    columns to each per-seed row (e.g. a minimum over objects); groups of fewer than ``min_objects`` rows get no
    mean."""
    table.add_group_means(
        by=(*by, "seed"),
        means=means,
        sums=sums,
        min_rows=min_objects,
        where=lambda r: r.get("object") != "all" and (where is None or where(r)),
        label=lambda key, rows: {"object": "all", "n_objects": len(rows), **(extra(rows) if extra else {})},
    )
    table.add_group_means(
        by=by,
        means=means,
        sums=sums,
        min_rows=2,
        where=lambda r: r.get("object") == "all" and r.get("seed") != "all" and (where is None or where(r)),
        label=lambda key, rows: {
            "object": "all",
            "seed": "all",
            "n_objects": min(r["n_objects"] for r in rows),
            "n_seeds": len(rows),
            **{f"{k}_sd_seeds": float(np.std([float(r[k]) for r in rows], ddof=1)) for k in means},
        },
    )


@dataclass
class BenchTable:
    """Rows of one benchmark stage.

    Args:
        stage: name (file stem in docs/benchmarks).
        error_key: column plotted on the y axis (lower is better unless ``higher_is_better``).
        time_key: column plotted on the x axis (ms).
        higher_is_better: e.g. F-score.
    """

    stage: str
    error_key: str
    time_key: str = "ms"
    higher_is_better: bool = False
    rows: list[dict[str, Any]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    threads: int = 1

    def add(self, **row: Any) -> None:
        self.rows.append(row)

    def add_group_means(
        self,
        by: tuple[str, ...],
        means: tuple[str, ...],
        where: Callable[[dict], bool],
        label: Callable[[tuple, list[dict]], dict[str, Any]],
        sums: tuple[str, ...] = (),
        min_rows: int = 2,
    ) -> None:
        """Append one row per group of the rows selected by ``where`` (grouped by the ``by`` columns):
        NaN-ignoring means of ``means``, totals of ``sums``, plus what ``label(group, rows)`` returns
        (e.g. ``object="all"``, a min or max). Groups smaller than ``min_rows`` are skipped."""
        groups: dict[tuple, list[dict]] = {}
        for r in self.rows:
            if where(r):
                groups.setdefault(tuple(r[k] for k in by), []).append(r)
        for key, rows in groups.items():
            if len(rows) < min_rows:
                continue
            row: dict[str, Any] = dict(zip(by, key, strict=True))
            row.update({k: float(np.nanmean([float(r[k]) for r in rows])) for k in means})
            row.update({k: sum(r[k] for r in rows) for k in sums})
            row.update(label(key, rows))
            self.add(**row)

    def pareto_mask(self) -> np.ndarray:
        """Rows not dominated in (time, error): nothing else is both faster and better."""
        from vtrack.viz.plots import pareto_front

        if not self.rows:
            return np.zeros(0, dtype=bool)
        t = [float(r.get(self.time_key, np.nan)) for r in self.rows]
        e = [float(r.get(self.error_key, np.nan)) for r in self.rows]
        return pareto_front(t, e, self.higher_is_better)


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        if not np.isfinite(v):
            return str(v)
        return f"{v:.4g}"
    return str(v)


def write_results(table: BenchTable, out_dir: Path | None = None, columns: list[str] | None = None) -> dict[str, Path]:
    """Write ``<stage>.csv``, ``<stage>.md`` and ``<stage>.png`` (Pareto plot) and update the index."""
    out_dir = out_dir or benchmarks_dir()
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = table.rows
    pareto = table.pareto_mask()
    for r, p in zip(rows, pareto, strict=True):
        r["pareto"] = bool(p)
    cols = columns or list(dict.fromkeys(k for r in rows for k in r))
    csv_path = out_dir / f"{table.stage}.csv"
    with open(csv_path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=cols, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: r.get(k, "") for k in cols})
    info = machine_info()
    info["threads"] = table.threads
    md_path = out_dir / f"{table.stage}.md"
    lines = [
        f"# Benchmark: {table.stage}",
        "",
        f"Error column: `{table.error_key}` ({'higher' if table.higher_is_better else 'lower'} is better); "
        f"time column: `{table.time_key}`. Pareto-optimal rows are marked ★.",
        "",
        f"Machine: {info['cpus']} CPUs, {info['processor']}, Python {info['python']}, "
        f"threads {table.threads}, git `{info['git']}`, {time.strftime('%Y-%m-%d %H:%M')}, "
        f"speed probe {info['speed_probe_ms']:g} ms (`vtrack.bench.harness.speed_probe_ms`: CPU time of a fixed "
        "workload, lower = faster cores right now).",
        "",
    ]
    lines += ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        cells = [_fmt(r.get(c, "")) for c in cols]
        if r.get("pareto"):
            cells[0] = "★ " + cells[0]
        lines.append("| " + " | ".join(cells) + " |")
    if table.notes:
        lines += ["", *[f"- {n}" for n in table.notes]]
    lines += ["", f"![{table.stage}]({table.stage}.png)", ""]
    md_path.write_text("\n".join(lines))
    png_path = out_dir / f"{table.stage}.png"
    plot_pareto(table, png_path)
    write_json(out_dir / f"{table.stage}.json", {"machine": info, "rows": rows}, indent=1)
    _update_index(out_dir)
    return {"csv": csv_path, "md": md_path, "png": png_path}


def plot_pareto(table: BenchTable, path: Path) -> None:
    """Scatter of error against time per method, Pareto front highlighted (shared with the viewer's plots)."""
    from vtrack.viz.plots import plot_speed_vs_error

    if table.rows:
        plot_speed_vs_error(
            path,
            table.rows,
            time_key=table.time_key,
            error_key=table.error_key,
            higher_is_better=table.higher_is_better,
            title=f"{table.stage}: speed against error",
        )


def _update_index(out_dir: Path) -> None:
    stages = sorted(p.stem for p in out_dir.glob("*.md") if p.stem != "README")
    lines = [
        "# Benchmarks",
        "",
        "Produced by `vtrack bench <stage>` (see each page for the command, machine and",
        "git revision). Each stage: CSV, markdown table and Pareto plot (error against time).",
        "",
    ]
    index = out_dir / "README.md"
    old = index.read_text().splitlines() if index.is_file() else []
    for s in stages:
        # link only what is there: a hand-written page (a diagnosis) has no CSV or plot
        links = [
            f"[{kind}]({s}.{ext})"
            for kind, ext in (("csv", "csv"), ("plot", "png"))
            if (out_dir / f"{s}.{ext}").is_file()
        ]
        head = f"- [{s}]({s}.md)"
        line = head + (" — " + ", ".join(links) if links else "")
        # a hand-written entry (a description after the page link, a note after its links, more links) survives a
        # re-run as long as it still links every file the stage has
        targets = [link[link.index("(") :] for link in links]
        kept = next(
            (o for o in old if (o == head or o.startswith(head + " ")) and all(t in o for t in targets)),
            None,
        )
        lines.append(kept if kept is not None else line)
    index.write_text("\n".join(lines) + "\n")
