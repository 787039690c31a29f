"""Measure batch throughput (tasks/min) against the number of workers (``vtrack batch scaling``).

Each repetition runs the whole batch again from scratch (``force=True``) into a fresh folder, with
workers warmed up (task module imported) before the clock starts, so the numbers are steady-state
throughput of the engine, not cluster start-up. For Ray, a local cluster is started per run (its
start-up time is reported separately as ``engine_start_seconds``).
"""

from __future__ import annotations

import os
import shutil
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from vtrack.batch.runner import run_batch


def measure_scaling(
    task: str,
    sessions: list[str | Path],
    *,
    engine: str = "ray",
    workers: list[int] = (1, 2),
    repeats: int = 3,
    params: dict[str, Any] | None = None,
    threads: int = 1,
    work_dir: str | Path | None = None,
    pin_cpus: bool | None = None,
) -> dict[str, Any]:
    """Run the batch ``repeats`` times per worker count; interleaved (1, 2, 1, 2, ...) so that
    background load changes hit every setting alike.

    Returns:
        ``{"runs": [...], "summary": {workers: {"tasks_per_min_median", ...}}, "speedup_median"}``.
    """
    root = Path(work_dir or tempfile.mkdtemp(prefix="vtrack-scaling-"))
    runs = []
    for rep in range(repeats):
        for n in workers:
            out = root / f"{engine}-w{n}-r{rep}"
            shutil.rmtree(out, ignore_errors=True)
            load0 = os.getloadavg()[0]
            t0 = time.perf_counter()
            report = run_batch(
                task,
                sessions,
                out,
                engine=engine,
                workers=n,
                params=params,
                force=True,
                threads=threads,
                pin_cpus=pin_cpus,
            )
            run = report["run"]
            runs.append(
                {
                    "engine": engine,
                    "workers": n,
                    "repeat": rep,
                    "pin_cpus": run.get("pin_cpus"),
                    "tasks": run["ok"],
                    "failed": run["failed"],
                    "wall_seconds": run["wall_seconds"],
                    "engine_start_seconds": run["engine_start_seconds"],
                    "tasks_per_min": run["tasks_per_min"],
                    "total_seconds": time.perf_counter() - t0,
                    "task_cpu_seconds": run.get("task_cpu_seconds"),
                    "cpu_utilisation": run.get("cpu_utilisation"),
                    "loadavg_1min_before": load0,
                    "loadavg_1min_after": os.getloadavg()[0],
                }
            )
    summary = {}
    for n in workers:
        tpm = [r["tasks_per_min"] for r in runs if r["workers"] == n and r["tasks_per_min"]]
        summary[n] = {
            "tasks_per_min_median": statistics.median(tpm) if tpm else None,
            "tasks_per_min_max": max(tpm) if tpm else None,
            "runs": len(tpm),
        }
    base = summary[workers[0]]["tasks_per_min_median"]
    speedup = {
        n: (summary[n]["tasks_per_min_median"] / base if base and summary[n]["tasks_per_min_median"] else None)
        for n in workers
    }
    return {
        "task": task,
        "engine": engine,
        "sessions": [str(s) for s in sessions],
        "params": params or {},
        "cpus": os.cpu_count(),
        "runs": runs,
        "summary": summary,
        "speedup_median": speedup,
    }
