"""Local process-pool engine: results, resume, retries after worker crashes, timeouts, chunks."""

from __future__ import annotations

import json
import os

import pytest

from vtrack.batch import run_batch
from vtrack.batch.results import RESULT_MANIFEST
from vtrack.batch.stats import session_stats
from vtrack.errors import InputError


def metrics_of(report: dict) -> dict[str, dict]:
    return {r["key"]: r["metrics"] for r in report["results"]}


def _dirs(out):
    return sorted(p.name for p in out.iterdir() if p.is_dir())


def test_local_run_then_resume_skips_complete(synthetic_sessions, tmp_path):
    sessions = synthetic_sessions[:3]
    rep = run_batch("stats", sessions, tmp_path, engine="local", workers=2)
    assert rep["run"]["ok"] == 3 and rep["run"]["failed"] == 0
    assert _dirs(tmp_path) == [s.name for s in sessions]
    m = metrics_of(rep)
    assert m["session_0"]["camera/cam0.frames"] == 12
    assert 0.9 < m["session_0"]["camera/cam0.valid_depth_fraction"] < 1.0
    # Different seeds -> different data -> different metrics.
    assert m["session_0"]["camera/cam0.points"] != m["session_1"]["camera/cam0.points"]
    mtimes = {s.name: (tmp_path / s.name / RESULT_MANIFEST).stat().st_mtime_ns for s in sessions}

    rep2 = run_batch("stats", sessions, tmp_path, engine="local", workers=2)
    assert [r["status"] for r in rep2["results"]] == ["cached"] * 3
    assert metrics_of(rep2) == m
    assert {s.name: (tmp_path / s.name / RESULT_MANIFEST).stat().st_mtime_ns for s in sessions} == mtimes

    # Other task options make the old results stale: they are recomputed, not reused.
    rep3 = run_batch("stats", sessions, tmp_path, engine="local", workers=2, params={"voxel_m": 0.01})
    assert rep3["run"]["ok"] == 3
    assert all(metrics_of(rep3)[k]["camera/cam0.occupied_voxels"] < m[k]["camera/cam0.occupied_voxels"] for k in m)
    rows = (tmp_path / "summary.csv").read_text().splitlines()
    assert len(rows) == 4 and rows[1].startswith("session_0,")


def test_crashing_worker_is_retried_and_reported(synthetic_sessions, tmp_path):
    sessions = synthetic_sessions[:4]
    plan = {
        "session_1": {"mode": "exit", "times": 1},  # crashes once, then succeeds
        "session_2": {"mode": "kill", "times": 99},  # SIGKILLs its worker every time
        "session_3": {"mode": "exit_before_commit", "times": 1},
    }  # dies with its result unrenamed
    out = tmp_path / "out"
    rep = run_batch("stats", sessions, out, engine="local", workers=2, retries=2, fault_plan=plan)
    by = {r["key"]: r for r in rep["results"]}
    assert by["session_0"]["status"] == "ok" and by["session_0"]["attempts"] == 1
    assert by["session_1"]["status"] == "ok" and by["session_1"]["attempts"] == 2
    assert "exit code 17" in by["session_1"]["attempt_errors"][0]
    assert by["session_3"]["status"] == "ok" and by["session_3"]["attempts"] == 2
    assert by["session_2"]["status"] == "failed" and by["session_2"]["attempts"] == 3
    assert "SIGKILL" in by["session_2"]["error"] and len(by["session_2"]["attempt_errors"]) == 3
    assert rep["run"]["crashes"] == 5 and rep["run"]["failed"] == 1
    # Exactly one result per successful session; the failed one has none; no temp leftovers.
    assert _dirs(out) == ["session_0", "session_1", "session_3"]
    # Results after a crash equal clean results.
    (tmp_path / "ref").mkdir()
    assert session_stats(str(sessions[1]), str(tmp_path / "ref")) == by["session_1"]["metrics"]
    # The failed session is picked up by the next run; the others are skipped.
    rep2 = run_batch("stats", sessions, out, engine="local", workers=2)
    assert [r["status"] for r in rep2["results"]] == ["cached", "cached", "ok", "cached"]


def test_bad_input_is_not_retried(synthetic_sessions, tmp_path):
    rep = run_batch("stats", synthetic_sessions[:1], tmp_path, workers=1, retries=3, params={"voxel_m": -1})
    r = rep["results"][0]
    assert r["status"] == "failed" and r["attempts"] == 1
    assert "voxel size must be positive" in r["error"]
    assert rep["run"]["failed"] == 1


def test_timeout_kills_and_retries(synthetic_sessions, tmp_path):
    rep = run_batch(
        "stats",
        synthetic_sessions[:2],
        tmp_path,
        workers=2,
        retries=1,
        timeout_s=4.0,
        fault_plan={"session_0": {"mode": "hang", "times": 1}},
    )
    by = {r["key"]: r for r in rep["results"]}
    assert by["session_0"]["status"] == "ok" and by["session_0"]["attempts"] == 2
    assert "timed out after 4 s" in by["session_0"]["attempt_errors"][0]
    assert by["session_1"]["status"] == "ok" and by["session_1"]["attempts"] == 1


def test_chunks_are_separate_tasks(synthetic_sessions, tmp_path):
    rep = run_batch("stats", synthetic_sessions[:1], tmp_path, workers=2, chunk_frames=5)
    keys = [r["key"] for r in rep["results"]]
    assert keys == ["session_0@f000000-000005", "session_0@f000005-000010", "session_0@f000010-000012"]
    frames = [r["metrics"]["camera/cam0.frames"] for r in rep["results"]]
    assert frames == [5, 5, 2]
    (tmp_path / "whole").mkdir()
    whole = session_stats(str(synthetic_sessions[0]), str(tmp_path / "whole"))
    assert sum(r["metrics"]["camera/cam0.points"] for r in rep["results"]) == whole["camera/cam0.points"]
    stats = json.loads((tmp_path / keys[1] / "stats.json").read_text())
    assert stats["frames"] == [5, 10]


def test_one_driver_per_output_folder(synthetic_sessions, tmp_path):
    import fcntl

    fd = os.open(tmp_path / ".batch.lock", os.O_RDWR | os.O_CREAT)
    fcntl.flock(fd, fcntl.LOCK_EX)
    try:
        with pytest.raises(InputError, match="another batch"):
            run_batch("stats", synthetic_sessions[:1], tmp_path, workers=1)
    finally:
        os.close(fd)


def test_unreadable_fault_plan_is_a_clear_error(tmp_path):
    from vtrack.batch.runner import load_fault_plan
    from vtrack.errors import InputError

    with pytest.raises(InputError, match="fault plan"):
        load_fault_plan(tmp_path / "missing.json")
    (tmp_path / "list.json").write_text("[1, 2]")
    with pytest.raises(InputError, match="JSON object"):
        load_fault_plan(tmp_path / "list.json")
    (tmp_path / "ok.json").write_text('{"*": {"mode": "raise", "times": 1}}')
    assert load_fault_plan(tmp_path / "ok.json") == {"*": {"mode": "raise", "times": 1}}
