"""End to end: `vtrack view` in a subprocess, the page opened in real headless chromium, screenshot checked.

Uses Debian's chromium (installed by `./run test` via apt); no browser is downloaded. Skips (with
the reason) only when no chromium binary exists.
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from vtrack.viz.colors import TOUCH_RGB, VISION_RGB

pytestmark = pytest.mark.browser

_CANDIDATES = ("/usr/bin/chromium", shutil.which("chromium") or "", shutil.which("chromium-browser") or "")
CHROMIUM = next((p for p in _CANDIDATES if p and os.access(p, os.X_OK)), None)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class _Server:
    """`vtrack view PATH --port N` in a subprocess; stderr collected line by line."""

    def __init__(self, path: Path, port: int) -> None:
        vtrack = Path(sys.executable).parent / "vtrack"
        cmd = [str(vtrack)] if vtrack.exists() else [sys.executable, "-m", "vtrack_apps.cli"]
        env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
        self.proc = subprocess.Popen([*cmd, "view", str(path), "--port", str(port)], stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True, env=env)
        self.lines: list[str] = []
        self._t = threading.Thread(target=self._read, daemon=True)
        self._t.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.append(line.rstrip())

    def wait_for(self, text: str, timeout: float) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if any(text in ln for ln in self.lines):
                return True
            if self.proc.poll() is not None:
                time.sleep(0.2)
                return any(text in ln for ln in self.lines)
            time.sleep(0.05)
        return False

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)


def _screenshot(url: str, out: Path, tmp: Path, size=(1200, 800), budget_ms: int = 5000) -> subprocess.CompletedProcess:
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
           "--disable-background-networking", "--disable-component-update", "--disable-sync",
           "--disable-dev-shm-usage", f"--user-data-dir={tmp / 'chrome-profile'}", f"--screenshot={out}",
           f"--window-size={size[0]},{size[1]}", f"--virtual-time-budget={budget_ms}", url]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120)


def _near(img: np.ndarray, rgb, tol: int) -> int:
    return int((np.abs(img.astype(np.int32) - np.array(rgb)).max(-1) <= tol).sum())


@pytest.mark.skipif(CHROMIUM is None, reason="no chromium binary (apt-get install chromium; ./run test does it)")
def test_viewer_page_renders_scene_in_headless_chromium(view_fixture, tmp_path):
    import cv2

    port = _free_port()
    t0 = time.monotonic()
    srv = _Server(view_fixture["demo"], port)
    try:
        assert srv.wait_for("ready in", 60), "viewer did not start:\n" + "\n".join(srv.lines[-20:])
        startup = time.monotonic() - t0
        out = tmp_path / "page.png"
        res = _screenshot(f"http://127.0.0.1:{port}", out, tmp_path)
        assert out.exists(), f"chromium wrote no screenshot (rc {res.returncode}): {res.stderr[-800:]}"
        assert srv.wait_for("connected", 10), "server never logged the browser client:\n" + "\n".join(srv.lines)
    finally:
        srv.stop()
    img = cv2.imread(str(out))[..., ::-1]
    assert img.shape[:2] == (800, 1200)
    # 3D canvas = left part of the page (the GUI panel sits at the top right).
    canvas = img[:, :800]
    non_bg = (np.abs(canvas.astype(np.int32) - 255).max(-1) > 30).mean()
    assert non_bg > 0.01, f"3D view looks blank ({non_bg:.4f} non-background pixels)"
    assert len(np.unique(canvas.reshape(-1, 3), axis=0)) > 50
    # The fused cloud is drawn in modality colours (points are shaded, so allow a tolerance).
    # The viewer opens at the last frame, so the whole cloud (5000 vision + 1000 touch points) is shown.
    blue, orange = _near(canvas, VISION_RGB, 50), _near(canvas, TOUCH_RGB, 50)
    assert blue > 300, f"too few vision-coloured cloud pixels ({blue})"
    assert orange > 60, f"too few touch-coloured cloud pixels ({orange})"
    assert startup < 60
    connected = [ln for ln in srv.lines if "client" in ln and "connected" in ln]
    assert connected and "client 0 connected" in connected[0]
