"""A batch whose driver is SIGKILLed mid-way resumes without lost or duplicated results."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from vtrack.batch import run_batch
from vtrack.batch.results import RESULT_MANIFEST
from vtrack.batch.stats import session_stats


def _descendants(pid: int) -> list[int]:
    """Children, grandchildren, ... (pool workers may hang below a fork server)."""
    parent = {}
    for p in Path("/proc").iterdir():
        if p.name.isdigit():
            try:
                parent[int(p.name)] = int((p / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
    out, frontier = [], [pid]
    while frontier:
        kids = [c for c, pp in parent.items() if pp in frontier]
        out += kids
        frontier = kids
    return out


def _alive(pid: int) -> bool:
    try:
        state = (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def _committed(out: Path) -> list[str]:
    return sorted(p.name for p in out.iterdir() if p.is_dir() and not p.name.startswith("."))


def test_killed_driver_resumes_without_loss_or_duplicates(synthetic_sessions, tmp_path):
    out = tmp_path / "out"
    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps({"*": {"delay_s": 0.6}}))  # slow tasks down so the kill lands mid-batch
    env = {**os.environ, "VTRACK_BATCH_FAULT_PLAN": str(plan)}
    cmd = [
        sys.executable,
        "-m",
        "vtrack_apps.cli",
        "batch",
        "stats",
        *map(str, synthetic_sessions),
        "--out",
        str(out),
        "--workers",
        "2",
    ]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    t0 = time.monotonic()
    workers: set[int] = set()
    while time.monotonic() - t0 < 60:
        workers.update(_descendants(proc.pid))
        if out.exists() and len(_committed(out)) >= 2:
            break
        assert proc.poll() is None, proc.stderr.read().decode()
        time.sleep(0.05)
    workers.update(_descendants(proc.pid))
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    done_before = _committed(out)
    assert 2 <= len(done_before) < len(synthetic_sessions), "the kill must land mid-batch"
    # The pool workers die with the driver (PR_SET_PDEATHSIG, fork server exit): nothing keeps writing.
    deadline = time.monotonic() + 10
    while any(_alive(w) for w in workers) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert workers and not any(_alive(w) for w in workers)
    done_after = _committed(out)
    assert done_after == done_before
    mtimes = {k: (out / k / RESULT_MANIFEST).stat().st_mtime_ns for k in done_before}

    rep = run_batch("stats", synthetic_sessions, out, workers=2)
    status = {r["key"]: r["status"] for r in rep["results"]}
    assert sorted(k for k, s in status.items() if s == "cached") == done_before  # nothing redone
    assert all(s in ("cached", "ok") for s in status.values())
    assert _committed(out) == sorted(s.name for s in synthetic_sessions)  # nothing lost
    assert not [p for p in out.iterdir() if p.name.startswith((".tmp-", ".trash-"))]
    assert {k: (out / k / RESULT_MANIFEST).stat().st_mtime_ns for k in done_before} == mtimes
    rows = (out / "summary.csv").read_text().splitlines()[1:]
    keys = [r.split(",")[0] for r in rows]
    assert sorted(keys) == sorted(s.name for s in synthetic_sessions)  # each exactly once
    # The resumed results equal those of an uninterrupted, in-process computation.
    for s in synthetic_sessions:
        (tmp_path / "ref" / s.name).mkdir(parents=True)
        assert session_stats(str(s), str(tmp_path / "ref" / s.name)) == next(
            r["metrics"] for r in rep["results"] if r["key"] == s.name
        )
