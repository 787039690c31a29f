"""Atomic writers of vtrack.io.jsonio: the file appears whole or not at all, and no temporary file is left."""

import numpy as np
import pytest

from vtrack.io.jsonio import atomic_torch_save


def test_atomic_torch_save_round_trip_creates_parent_and_leaves_no_temporary(tmp_path):
    torch = pytest.importorskip("torch")
    path = tmp_path / "sub" / "w.pt"
    blob = {"a": torch.arange(5, dtype=torch.float16), "meta": {"k": 3}}
    assert atomic_torch_save(path, blob) == path
    back = torch.load(path, map_location="cpu", weights_only=False)
    assert torch.equal(back["a"], blob["a"]) and back["meta"] == {"k": 3}
    atomic_torch_save(path, {"a": torch.zeros(2)})  # overwrite in place
    assert np.array_equal(torch.load(path, weights_only=False)["a"].numpy(), np.zeros(2))
    assert sorted(p.name for p in path.parent.iterdir()) == ["w.pt"]


def test_atomic_torch_save_failure_keeps_the_old_file(tmp_path):
    torch = pytest.importorskip("torch")
    path = tmp_path / "w.pt"
    atomic_torch_save(path, {"a": torch.ones(3)})

    class Unpicklable:
        def __reduce__(self):
            raise RuntimeError("cannot pickle")

    with pytest.raises(RuntimeError, match="cannot pickle"):
        atomic_torch_save(path, {"bad": Unpicklable()})
    assert torch.equal(torch.load(path, weights_only=False)["a"], torch.ones(3))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["w.pt"]
