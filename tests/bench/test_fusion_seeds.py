"""``bench fusion``'s case options fail before any session runs when they cannot be honoured."""

from __future__ import annotations

from pathlib import Path

import pytest

from vtrack.bench.harness import BenchTable
from vtrack.errors import InputError


def test_bad_occlusion_and_given_session_with_seeds_are_input_errors(monkeypatch, shared_data: Path) -> None:
    from vtrack.bench.fusion import _full

    table = BenchTable("fusion", error_key="fscore_5mm", higher_is_better=True)
    monkeypatch.setenv("VTRACK_BENCH_FUSION_OCC", "medium,partial")
    with pytest.raises(InputError, match="VTRACK_BENCH_FUSION_OCC"):
        _full(table, 5.0)
    monkeypatch.delenv("VTRACK_BENCH_FUSION_OCC")
    # a recorded session has its own seed: its rows must not be labelled with the requested ones
    monkeypatch.setenv("VTRACK_BENCH_SEEDS", "1,2")
    monkeypatch.setenv("VTRACK_BENCH_FUSION_CASES", "025_mug|medium|/some/session")
    with pytest.raises(InputError, match="cannot be combined with --seeds"):
        _full(table, 5.0)
    assert table.rows == []  # nothing ran
