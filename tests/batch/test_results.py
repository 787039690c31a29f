"""Result folders: a manifest written last, checksum validation, atomic commit without duplicates."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from vtrack.batch import results


def _job(tmp_path: Path, key: str = "s0") -> dict:
    return {
        "key": key,
        "target": "m:f",
        "params_digest": "p1",
        "session_fingerprint": "f1",
        "chunk": None,
        "session": "/data/s0",
        "params": {},
        "out_root": str(tmp_path),
    }


def _make_result(folder: Path, job: dict, payload: bytes = b"mesh-bytes") -> dict:
    folder.mkdir(parents=True)
    (folder / "mesh.ply").write_bytes(payload)
    (folder / "sub").mkdir()
    (folder / "sub" / "metrics.json").write_text('{"a": 1}')
    return results.write_manifest(folder, job, {"chamfer_mm": 1.5}, {"seconds": 0.1})


def test_valid_result_roundtrip_and_tamper_detection(tmp_path):
    job = _job(tmp_path)
    man = _make_result(tmp_path / "r", job)
    assert set(man["files"]) == {"mesh.ply", "sub/metrics.json"}
    assert results.read_valid_result(tmp_path / "r", job)["metrics"] == {"chamfer_mm": 1.5}
    # Same size, different content: only the checksum can tell.
    (tmp_path / "r" / "mesh.ply").write_bytes(b"mesh-bytez")
    assert results.read_valid_result(tmp_path / "r", job) is None
    assert results.read_valid_result(tmp_path / "r", job, check_hashes=False) is not None


def test_invalid_when_identity_or_manifest_differs(tmp_path):
    job = _job(tmp_path)
    _make_result(tmp_path / "r", job)
    for k, v in [("params_digest", "p2"), ("session_fingerprint", "f2"), ("target", "m:g")]:
        assert results.read_valid_result(tmp_path / "r", {**job, k: v}) is None
    assert results.read_valid_result(tmp_path / "r", {**job, "chunk": {"frames": [0, 5]}}) is None
    m = tmp_path / "r" / results.RESULT_MANIFEST
    m.write_text(m.read_text()[:40])  # truncated manifest
    assert results.read_valid_result(tmp_path / "r", job) is None
    (tmp_path / "r" / "mesh.ply").unlink()
    assert results.read_valid_result(tmp_path / "empty", job) is None


def test_commit_race_keeps_exactly_one_result(tmp_path):
    job = _job(tmp_path)
    _make_result(tmp_path / ".tmp-a", job, b"first")
    _make_result(tmp_path / ".tmp-b", job, b"second")
    assert results.commit(tmp_path / ".tmp-a", tmp_path / "s0", job) == "committed"
    assert results.commit(tmp_path / ".tmp-b", tmp_path / "s0", job) == "already_complete"
    assert (tmp_path / "s0" / "mesh.ply").read_bytes() == b"first"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s0"]


def test_commit_replaces_stale_result(tmp_path):
    job = _job(tmp_path)
    _make_result(tmp_path / "s0", {**job, "params_digest": "old"}, b"old")
    _make_result(tmp_path / ".tmp-new", job, b"new")
    assert results.commit(tmp_path / ".tmp-new", tmp_path / "s0", job) == "committed"
    assert (tmp_path / "s0" / "mesh.ply").read_bytes() == b"new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s0"]


def test_clean_leftovers_only_touches_temp_names(tmp_path):
    for name in [".tmp-s0-1234", ".trash-s1-99", "s2"]:
        (tmp_path / name).mkdir()
    assert results.clean_leftovers(tmp_path) == 2
    assert [p.name for p in tmp_path.iterdir()] == ["s2"]


def test_metrics_sanitised_and_summary_written(tmp_path):
    bad: list[str] = []
    from vtrack.io.jsonio import to_jsonable

    m = to_jsonable(
        {"a": np.float32(1.5), "b": float("nan"), "c": {"d": np.inf, "e": np.int64(3)}, "arr": np.array([1.0, 2.0])},
        bad,
    )
    assert m == {"a": 1.5, "b": None, "c": {"d": None, "e": 3}, "arr": [1.0, 2.0]}
    assert bad == ["b", "c.d"]
    recs = [
        {"key": "s0", "session": "/x", "chunk": None, "status": "ok", "attempts": 1, "seconds": 0.5, "metrics": m},
        {
            "key": "s1",
            "session": "/y",
            "chunk": {"frames": [0, 5]},
            "status": "failed",
            "attempts": 3,
            "error": "boom",
            "metrics": None,
        },
    ]
    paths = results.write_summary(tmp_path, recs, {"task": "t"})
    lines = paths["csv"].read_text().splitlines()
    assert lines[0].startswith("key,session,chunk,status,attempts,seconds,host,error,metric.a")
    assert "metric.c.e" in lines[0] and "metric.arr" not in lines[0]
    assert lines[2].startswith("s1,/y,0-5,failed,3,")
    assert json.loads(paths["json"].read_text())["results"][0]["metrics"]["b"] is None
