"""The vtrack CLI: help, scene check, session info, clear errors (exit 2, no traceback)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

VTRACK = [sys.executable, "-m", "vtrack_apps.cli"]


def run(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([*VTRACK, *args], capture_output=True, text=True, timeout=300, cwd=cwd)


def test_help_lists_commands() -> None:
    out = run("--help")
    assert out.returncode == 0
    for cmd in ("demo", "bench", "scene", "session"):
        assert cmd in out.stdout


def test_scene_check_json(tmp_path: Path, shared_data: Path) -> None:
    from vtrack.paths import default_scene_path

    out = run("scene", "check", str(default_scene_path()), "--json", str(tmp_path / "s.json"))
    assert out.returncode == 0, out.stderr
    data = json.loads((tmp_path / "s.json").read_text())
    assert data["modalities"] == ["vision", "touch"]
    assert "kinematics" in data["components"] and "rgbd" in data["components"]


def test_bad_scene_is_one_clear_line(tmp_path: Path) -> None:
    p = tmp_path / "bad.yaml"
    p.write_text("name: x\ncameras:\n  - {name: c, fx: 0}\n")
    out = run("scene", "check", str(p))
    assert out.returncode == 2
    assert "bad.yaml" in out.stderr and "cameras.0.fx" in out.stderr
    assert "Traceback" not in out.stderr


def test_session_info(tmp_path: Path) -> None:
    from vtrack.io import streams
    from vtrack.io.session import SessionWriter

    with SessionWriter(tmp_path / "s", None) as w:
        w.add_stream("joints", streams.joints_stream(["a", "b"]))
        for i in range(30):
            w.append("joints", i / 60, q=np.zeros(2))
    out = run("session", "info", str(tmp_path / "s"), "--json", str(tmp_path / "i.json"))
    assert out.returncode == 0, out.stderr
    rows = json.loads((tmp_path / "i.json").read_text())
    assert rows[0]["stream"] == "joints" and rows[0]["frames"] == 30
    assert abs(rows[0]["rate_hz_measured"] - 60.0) < 1e-6
    out = run("session", "info", str(tmp_path / "nope"))
    assert out.returncode == 2 and "does not exist" in out.stderr and "Traceback" not in out.stderr


def test_bench_bad_seeds_is_one_clear_line(tmp_path: Path) -> None:
    out = run("bench", "heavy", "--seeds", "0,zero", "--out", str(tmp_path))
    assert out.returncode == 2
    assert "--seeds" in out.stderr and "0,zero" in out.stderr
    assert "Traceback" not in out.stderr and not list(tmp_path.iterdir())  # nothing ran, nothing written
