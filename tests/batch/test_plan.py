"""Planning: session discovery, result keys, chunking, fingerprints, task registry."""

from __future__ import annotations

import numpy as np
import pytest

from vtrack.batch.plan import chunk_ranges, discover_sessions, make_jobs, session_fingerprint, session_keys
from vtrack.batch.tasks import TASKS, chunk_params, is_available, resolve, target_of
from vtrack.errors import InputError


def test_discover_expands_folders_and_dedupes(synthetic_sessions, tmp_path):
    parent = synthetic_sessions[0].parent
    found = discover_sessions([parent, synthetic_sessions[1]])
    assert found == sorted(synthetic_sessions)  # the explicit duplicate is dropped
    with pytest.raises(InputError, match="no vtrack session"):
        discover_sessions([tmp_path])
    with pytest.raises(InputError, match="does not exist"):
        discover_sessions([tmp_path / "missing"])


def test_keys_disambiguate_same_names(tmp_path, synthetic_sessions):
    a = tmp_path / "a" / "run"
    b = tmp_path / "b" / "run"
    keys = session_keys([a, b, synthetic_sessions[0]])
    assert keys[synthetic_sessions[0]] == synthetic_sessions[0].name
    assert keys[a] != keys[b] and keys[a].startswith("run-") and keys[b].startswith("run-")
    assert session_keys([a, b])[a] == keys[a]


def test_chunks_cover_every_frame_once(synthetic_sessions):
    from vtrack.io.session import open_session

    s = synthetic_sessions[0]
    chunks = chunk_ranges(s, 5)
    assert [c["frames"] for c in chunks] == [[0, 5], [5, 10], [10, 12]]
    t = open_session(s)["camera/cam0"].t
    covered = np.concatenate([np.nonzero((t >= c["time_range"][0]) & (t < c["time_range"][1]))[0] for c in chunks])
    np.testing.assert_array_equal(covered, np.arange(len(t)))
    with pytest.raises(InputError):
        chunk_ranges(s, 0)


def test_chunk_jobs_need_a_chunkable_task(synthetic_sessions, tmp_path):
    jobs = make_jobs("stats", synthetic_sessions[:2], tmp_path, chunk_frames=5)
    assert [j["key"] for j in jobs[:3]] == [
        "session_0@f000000-000005",
        "session_0@f000005-000010",
        "session_0@f000010-000012",
    ]
    assert set(jobs[0]["chunk_args"]) == {"time_range", "frames"}
    with pytest.raises(InputError, match="cannot process part of a session"):
        make_jobs("json:dumps", synthetic_sessions[:1], tmp_path, chunk_frames=5)


def test_fingerprint_tracks_content(tmp_path):
    from vtrack.testing.sessions import write_synthetic_session

    s = write_synthetic_session(tmp_path / "s", seed=3, frames=4, width=16, height=12)
    f1 = session_fingerprint(s)
    assert f1 == session_fingerprint(s)
    write_synthetic_session(tmp_path / "s", seed=3, frames=5, width=16, height=12)
    assert session_fingerprint(s) != f1


def test_registry():
    assert target_of("stats") == TASKS["stats"]
    assert target_of("pkg.mod:fn") == "pkg.mod:fn"
    with pytest.raises(InputError, match="unknown batch task"):
        target_of("nope")
    assert is_available("stats")
    assert not is_available("no.such.module:fn")
    assert chunk_params(resolve(TASKS["stats"])) == ["time_range", "frames"]


@pytest.mark.parametrize(
    "task,params,expect",
    [
        (
            "reconstruct",
            {"method": "tsdf", "screenshot": False},
            {"open3d", "trimesh", "yourdfpy", "vtrack.fusion.tsdf"},
        ),
        ("track", {"shape": "known_shape"}, {"open3d", "vtrack.tracking.tracker", "vtrack.frames.session"}),
        ("bench", {"reconstruction": {"method": "tsdf"}}, {"open3d", "vtrack.fusion.tsdf", "vtrack.tracking.tracker"}),
    ],
)
def test_warm_up_imports_what_the_task_uses(task, params, expect):
    """Batch workers warm a task before timing: its module's ``warm_up(**params)`` hook must import the heavy
    dependencies the task loads lazily (else each worker's first task pays ~2 s of imports)."""
    import json
    import subprocess
    import sys

    code = (
        "import json, sys; from vtrack.batch.worker import warm_up; from vtrack.batch.tasks import target_of; "
        f"warm_up(target_of({task!r}), json.loads({json.dumps(json.dumps(params))})); "
        "print(json.dumps(sorted(sys.modules)))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    loaded = set(json.loads(out.stdout.strip().splitlines()[-1]))
    assert expect <= loaded, expect - loaded
    assert "torch" not in loaded  # TSDF / known-shape tracking must not pull in torch
