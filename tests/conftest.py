"""Shared pytest fixtures."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

# Small ops are faster single-threaded on 2 cores, and tests must not fight each other for cores.
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data`` beside the repository; tests needing it skip when it is absent."""
    from vtrack.paths import shared_data_dir

    d = shared_data_dir()
    if not (d / "README.md").exists():
        pytest.skip(f"shared data folder not found at {d} (expected beside the repository)")
    return d


@pytest.fixture(scope="session", autouse=True)
def _isolated_cache(tmp_path_factory) -> None:
    """Use a per-run cache unless VTRACK_CACHE is set (so CI never reads stale generated data)."""
    if "VTRACK_CACHE" not in os.environ:
        os.environ["VTRACK_CACHE"] = str(tmp_path_factory.mktemp("vtrack_cache"))


@pytest.fixture(scope="session")
def tiny_session(shared_data) -> Path:
    """A 1 s synthetic session of the default scene (occlusion none), generated once per test run."""
    from vtrack.testing.sim import tiny_session_path

    return tiny_session_path(occlusion="none", seconds=1.0)


@pytest.fixture(scope="session")
def blind_session(tiny_session, tmp_path_factory) -> Path:
    """``tiny_session`` with every trace of ground truth removed (``vtrack session strip-gt``)."""
    from vtrack.io.strip import strip_gt

    out = tmp_path_factory.mktemp("blind") / "session"
    strip_gt(tiny_session, out)
    return out
