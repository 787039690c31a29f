"""Fixtures for the batch tests: small generated sessions and the task to run over them.

When the reconstruction is installed (``vtrack.fusion.reconstruct``) the local-vs-Ray test runs the
real batch reconstruction on three generated sessions; otherwise it uses the batch engine's own
deterministic ``stats`` task, which exercises exactly the same engine code paths.
"""

from __future__ import annotations

import importlib.util
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
    from vtrack.testing.sessions import write_synthetic_session

    return [
        write_synthetic_session(root / f"session_{i}", seed=i, frames=frames, width=96, height=72) for i in range(n)
    ]


@pytest.fixture(scope="session")
def synthetic_sessions(tmp_path_factory) -> list[Path]:
    """Six synthetic sessions (12 frames each), shared read-only by the tests."""
    return _synthetic_sessions(tmp_path_factory.mktemp("batch_sessions"), 6)


@pytest.fixture(scope="session")
def real_case(synthetic_sessions) -> BatchCase | None:
    """The real batch reconstruction (TSDF, vision; no screenshot) on three sessions, or None while
    ``vtrack.fusion.reconstruct`` is not installed. The sessions are the synthetic ones: the
    simulator's sessions take tens of seconds each to generate on 2 busy cores."""
    if not _have("vtrack.fusion.reconstruct"):
        return None
    return BatchCase(
        "reconstruct",
        synthetic_sessions[:3],
        {"method": "tsdf", "modalities": ["vision"], "screenshot": False, "poses": "gt", "segmentation": "gt"},
    )


@pytest.fixture(scope="session")
def three_case(real_case, synthetic_sessions) -> BatchCase:
    """Three sessions and the task for the local-vs-Ray equivalence test."""
    if real_case is not None:
        return real_case
    return BatchCase("stats", synthetic_sessions[:3], {})
