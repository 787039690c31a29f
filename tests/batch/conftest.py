"""Fixtures for the batch tests: three small sessions and the task to run over them.

When the simulator and the reconstruction are installed (``vtrack.sim.fixtures``,
``vtrack.fusion.reconstruct``) the tests run the real batch reconstruction on three generated
sessions; until then they use the batch engine's own deterministic ``stats`` task on synthetic
sessions, which exercises exactly the same engine code paths.
"""

from __future__ import annotations

import importlib.util
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest


def _have(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except ModuleNotFoundError:
        return False


@dataclass
class BatchCase:
    task: str
    sessions: list[Path]
    params: dict[str, Any] = field(default_factory=dict)


def _synthetic_sessions(root: Path, n: int, frames: int = 12) -> list[Path]:
    from vtrack.batch.synthetic import write_synthetic_session

    return [write_synthetic_session(root / f"session_{i}", seed=i, frames=frames, width=96, height=72)
            for i in range(n)]


@pytest.fixture(scope="session")
def synthetic_sessions(tmp_path_factory) -> list[Path]:
    """Six synthetic sessions (12 frames each), shared read-only by the tests."""
    return _synthetic_sessions(tmp_path_factory.mktemp("batch_sessions"), 6)


@pytest.fixture(scope="session")
def real_case(tmp_path_factory) -> BatchCase | None:
    """Three generated sessions + the real reconstruction, or None while they are not installed."""
    if not (_have("vtrack.sim.fixtures") and _have("vtrack.fusion.reconstruct")):
        return None
    try:
        from vtrack.sim.fixtures import tiny_session_path
    except ImportError:
        return None
    root = tmp_path_factory.mktemp("batch_real")
    sessions = []
    for seed in range(3):
        src = Path(tiny_session_path(seed=seed))
        dst = root / f"gen_{seed}"
        shutil.copytree(src, dst)
        sessions.append(dst)
    return BatchCase("reconstruct", sessions, {})


@pytest.fixture(scope="session")
def three_case(real_case, synthetic_sessions) -> BatchCase:
    """Three sessions and the task for the local-vs-Ray equivalence test."""
    if real_case is not None:
        return real_case
    return BatchCase("stats", synthetic_sessions[:3], {})

