"""Ray engine: same metrics as the local engine, crashed workers retried (one Ray start per module)."""

from __future__ import annotations

import json
import os

import pytest

ray = pytest.importorskip("ray")

from vtrack.batch import run_batch  # noqa: E402
from vtrack.batch.engines import RayEngine  # noqa: E402


def without_timing(metrics):
    """Metrics minus wall-clock fields (``*seconds``, ``ms_per_*``), which differ run to run."""
    if isinstance(metrics, dict):
        return {
            k: without_timing(v) for k, v in metrics.items() if not (k.endswith("seconds") or k.startswith("ms_per"))
        }
    return metrics


@pytest.fixture(scope="module")
def ray_cluster():
    """One local 2-CPU Ray cluster for the whole module (start-up costs a few seconds)."""
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    engine = RayEngine(workers=2)
    engine.start()
    yield engine
    engine._owns = True
    engine.close()


def _engine(ray_cluster) -> RayEngine:
    # Reuses the module's Ray connection (RayEngine does not shut down a connection it did not open).
    assert ray.is_initialized()
    return RayEngine(workers=2)


def test_ray_matches_local(ray_cluster, three_case, tmp_path):
    local = run_batch(
        three_case.task, three_case.sessions, tmp_path / "local", engine="local", workers=2, params=three_case.params
    )
    on_ray = run_batch(
        three_case.task, three_case.sessions, tmp_path / "ray", engine=_engine(ray_cluster), params=three_case.params
    )
    assert on_ray["run"]["engine"] == "ray" and on_ray["run"]["ok"] == 3
    assert local["run"]["ok"] == 3
    m_local = {r["key"]: without_timing(r["metrics"]) for r in local["results"]}
    m_ray = {r["key"]: without_timing(r["metrics"]) for r in on_ray["results"]}
    assert m_ray == m_local  # bit-identical metrics (wall-clock times aside)
    assert len({json.dumps(m, sort_keys=True) for m in m_local.values()}) == 3  # three different sessions
    # Result files are identical too (same checksums in the manifests).
    for key in m_local:
        a = json.loads((tmp_path / "local" / key / "batch_result.json").read_text())["files"]
        b = json.loads((tmp_path / "ray" / key / "batch_result.json").read_text())["files"]
        assert {k: v["sha256"] for k, v in a.items() if k.endswith(".ply")} == {
            k: v["sha256"] for k, v in b.items() if k.endswith(".ply")
        }


def test_ray_crash_retried_and_reported(ray_cluster, synthetic_sessions, tmp_path):
    plan = {"session_0": {"mode": "exit", "times": 1}, "session_1": {"mode": "kill", "times": 99}}
    rep = run_batch("stats", synthetic_sessions[:3], tmp_path, engine=_engine(ray_cluster), retries=1, fault_plan=plan)
    by = {r["key"]: r for r in rep["results"]}
    assert by["session_0"]["status"] == "ok" and by["session_0"]["attempts"] == 2
    assert "WorkerCrashedError" in by["session_0"]["attempt_errors"][0]
    assert by["session_1"]["status"] == "failed" and by["session_1"]["attempts"] == 2
    assert by["session_2"]["status"] == "ok" and by["session_2"]["attempts"] == 1
    assert sorted(p.name for p in tmp_path.iterdir() if p.is_dir()) == ["session_0", "session_2"]
