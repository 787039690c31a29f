"""``vtrack batch`` CLI and the optional-Ray contract."""

from __future__ import annotations

import subprocess
import sys

import pytest
from typer.testing import CliRunner

from vtrack.batch import run_batch
from vtrack.errors import VtrackError


def test_core_import_does_not_need_ray():
    code = (
        "import sys, vtrack, vtrack.batch, vtrack.batch.engines, vtrack_apps.commands.batch; "
        "print(sorted(m for m in ('ray', 'torch', 'open3d') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_ray_engine_without_ray_says_how_to_install(monkeypatch, synthetic_sessions, tmp_path):
    monkeypatch.setitem(sys.modules, "ray", None)  # makes `import ray` raise ImportError
    with pytest.raises(VtrackError, match=r"pip install 'vtrack\[distributed\]'"):
        run_batch("stats", synthetic_sessions[:1], tmp_path, engine="ray", workers=1)
    # Nothing was half-written.
    assert not [p for p in tmp_path.iterdir() if p.is_dir()]


def test_cli_runs_reports_and_fails_with_status(synthetic_sessions, tmp_path):
    from vtrack_apps.cli import app

    runner = CliRunner()
    res = runner.invoke(
        app,
        [
            "batch",
            "stats",
            str(synthetic_sessions[0]),
            "--out",
            str(tmp_path / "ok"),
            "--workers",
            "1",
            "-o",
            "voxel_m=0.01",
        ],
    )
    assert res.exit_code == 0, res.output
    assert "1 ran, 0 skipped (complete), 0 failed" in res.output
    assert (tmp_path / "ok" / "summary.csv").read_text().count("\n") == 2
    res = runner.invoke(
        app,
        [
            "batch",
            "stats",
            str(synthetic_sessions[0]),
            "--out",
            str(tmp_path / "bad"),
            "--workers",
            "1",
            "-o",
            "voxel_m=-1",
        ],
    )
    assert res.exit_code == 1
    assert "0 ran, 0 skipped (complete), 1 failed" in res.output
