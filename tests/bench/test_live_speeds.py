"""`vtrack bench live`'s replay speeds (``VTRACK_BENCH_LIVE_SPEED``): one or a list; above 1 the headroom sweep."""

from __future__ import annotations

import pytest

from vtrack.bench.live import _speeds
from vtrack.errors import InputError


def test_speed_list_parse_and_reject(monkeypatch) -> None:
    monkeypatch.delenv("VTRACK_BENCH_LIVE_SPEED", raising=False)
    assert _speeds() == [1.0]
    monkeypatch.setenv("VTRACK_BENCH_LIVE_SPEED", "0.25")
    assert _speeds() == [0.25]
    monkeypatch.setenv("VTRACK_BENCH_LIVE_SPEED", " 1,1.5,2.2 ")
    assert _speeds() == [1.0, 1.5, 2.2]
    for bad in ("fast", "1,,2", "0", "-1", "1,1", "11", "nan"):
        monkeypatch.setenv("VTRACK_BENCH_LIVE_SPEED", bad)
        with pytest.raises(InputError, match="VTRACK_BENCH_LIVE_SPEED"):
            _speeds()
