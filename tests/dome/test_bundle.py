"""Dome model bundle format (vtrack.dome.bundle): explicit versions, no code from a data file."""

from __future__ import annotations

import sys

import pytest

from vtrack.errors import InputError


class _Payload:  # a pickled object in a "bundle": loading it must not run anything
    def __reduce__(self):
        return (exec, ("import pathlib; pathlib.Path(__import__('os').environ['VT_PWNED']).write_text('x')",))


def test_shipped_bundles_are_version_3_and_inference_never_imports_training():
    import subprocess

    from vtrack.dome.bundle import BUNDLE_VERSION, read_bundle, weights_dir

    for kind in ("gnn", "cnn"):
        assert read_bundle(weights_dir() / f"{kind}.pt")["version"] == BUNDLE_VERSION == 3
    code = (
        "import sys, numpy as np; from vtrack.dome.reconstruct import DomeReconstructor; "
        "DomeReconstructor(); print('TRAIN' if 'vtrack.dome.train' in sys.modules else 'CLEAN')"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().endswith("CLEAN")


def test_bundle_with_code_newer_version_or_missing_parts_is_refused(tmp_path, monkeypatch):
    import torch

    from vtrack.dome.bundle import read_bundle, weights_dir

    flag = tmp_path / "pwned"
    monkeypatch.setenv("VT_PWNED", str(flag))
    evil = tmp_path / "evil.pt"
    torch.save({"kind": "gnn", "cfg": {}, "train": {}, "recon": {}, "info": _Payload()}, evil)
    with pytest.raises(InputError, match="not a dome model bundle"):
        read_bundle(evil)
    assert not flag.exists()
    b = read_bundle(weights_dir() / "gnn.pt")
    newer = tmp_path / "newer.pt"
    torch.save({**b, "version": 4}, newer)
    with pytest.raises(InputError, match="newer vtrack"):
        read_bundle(newer)
    part = tmp_path / "part.pt"
    torch.save({k: v for k, v in b.items() if k != "recon"}, part)
    with pytest.raises(InputError, match="incomplete.*recon|recon.*incomplete"):
        read_bundle(part)
    with pytest.raises(InputError, match="not found"):
        read_bundle(tmp_path / "missing.pt")


def test_version_1_bundle_takes_the_old_behaviour_for_missing_keys(tmp_path):
    import torch

    from vtrack.dome.bundle import bundle_dome_config, bundle_train_config, load_bundle, read_bundle, weights_dir

    b = read_bundle(weights_dir() / "cnn.pt")  # the CNN bundle keeps the decoder-feature heads (legacy_*)
    # an old bundle: no version, no force_arch, the decoder-feature heads as force_p / force_nop
    new_keys = ("version", "force_arch", "force_archs", "force_p", "force_nop", "force_plain_p", "force_plain_nop")
    new_keys += ("force_legacy_p", "force_legacy_nop")
    v1 = {k: v for k, v in b.items() if k not in new_keys}
    v1.update(force_p=b["force_legacy_p"], force_nop=b["force_legacy_nop"])
    v1["train"] = {k: v for k, v in b["train"].items() if k not in ("still_l1",)}
    v1["cfg"] = {k: v for k, v in b["cfg"].items() if k != "reference_at_pressure"}
    assert bundle_train_config(v1).still_l1 == 0.0 and bundle_dome_config(v1).reference_at_pressure is False
    # version 2 guesses nothing: the same missing key is an error, not a silent default
    with pytest.raises(InputError, match="sensor config does not match"):
        bundle_dome_config({**v1, "version": 2, "cfg": {"nonsense": 1}})
    p = tmp_path / "v1.pt"
    torch.save(v1, p)
    model, heads, cfg, _ = load_bundle(p)
    assert cfg.reference_at_pressure is False and set(heads) == {"p", "nop"}
    assert all(h.arch == "decoder_film" for h in heads.values())
    bad = tmp_path / "arch.pt"
    torch.save({**b, "force_archs": {**b["force_archs"], "p": "transformer"}}, bad)
    with pytest.raises(InputError, match="force architecture"):
        load_bundle(bad)


def test_shipped_bundles_are_the_confined_inflation_sensor_and_merge_keeps_every_head(tmp_path):
    """The shipped nets are for today's default sensor (inflation confined, issue #26); bundles whose force heads
    were trained in separate processes merge into one, and only bundles sharing the reconstruction net may."""
    import torch

    from vtrack.dome.bundle import load_bundle, read_bundle, weights_dir
    from vtrack.dome.model import DomeConfig
    from vtrack.dome.train import merge_bundles, retarget_bundle

    src = weights_dir() / "gnn.pt"
    b = read_bundle(src)
    assert b["cfg"] == DomeConfig().to_dict() and b["cfg"]["inflation_mm_per_kpa"] == 0.0
    assert read_bundle(weights_dir() / "cnn.pt")["cfg"] == b["cfg"]
    heads = [k for k in b["force_archs"]]
    assert {"p", "nop"} <= set(heads)
    parts = []
    for i, keep in enumerate((["p"], [k for k in heads if k != "p"])):
        part = {k: v for k, v in b.items() if not k.startswith("force_")}
        part["force_archs"] = {k: b["force_archs"][k] for k in keep}
        part.update({f"force_{k}": b[f"force_{k}"] for k in keep})
        parts.append(tmp_path / f"part{i}.pt")
        torch.save(part, parts[-1])
    merge_bundles(parts, tmp_path / "merged.pt", evaluate_test=False)
    _, merged, _, _ = load_bundle(tmp_path / "merged.pt")
    assert set(merged) == set(heads)
    other = read_bundle(parts[1])
    first = next(k for k, v in other["recon"].items() if v.is_floating_point())
    other["recon"][first] = other["recon"][first] + 1
    torch.save(other, parts[1])
    with pytest.raises(InputError, match="reconstruction weights"):
        merge_bundles(parts, tmp_path / "bad.pt", evaluate_test=False)
    # the reconstruction net transfers only across the inflation (it sees the frame relative to its reference)
    with pytest.raises(InputError, match="do not transfer"):
        retarget_bundle(src, tmp_path / "x.pt", DomeConfig(radius_mm=25.0))
