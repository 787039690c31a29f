"""End to end: `vtrack view` in a subprocess, the page opened in real headless chromium, screenshot checked.

Chromium is driven over the DevTools protocol (``websockets``): it navigates to the viewer, takes a
screenshot every 0.5 s until the fused cloud shows up in modality colours (or 60 s pass), and records
every request the page makes (all must go to the local viewer: it works offline). Uses Debian's
chromium (installed by `./run test` via apt); no browser is downloaded. Skips (with the reason) only
when no chromium binary exists.
"""

from __future__ import annotations

import asyncio
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


def _terminate(proc: subprocess.Popen) -> None:
    """Stop a child process: terminate, then kill if it does not exit within 10 s."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)


class _Server:
    """`vtrack view PATH --port N` in a subprocess; stderr collected line by line."""

    def __init__(self, path: Path, port: int) -> None:
        vtrack = Path(sys.executable).parent / "vtrack"
        cmd = [str(vtrack)] if vtrack.exists() else [sys.executable, "-m", "vtrack_apps.cli"]
        env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
        self.proc = subprocess.Popen(
            [*cmd, "view", str(path), "--port", str(port)],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env=env,
        )
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
        _terminate(self.proc)


class _DevTools:
    """Headless chromium driven over the DevTools protocol (``websockets``): navigate, watch network
    requests, take screenshots until the scene shows up."""

    def __init__(self, tmp: Path, size=(1200, 800)) -> None:
        cmd = [
            CHROMIUM,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--disable-dev-shm-usage",
            "--remote-debugging-port=0",
            f"--user-data-dir={tmp / 'chrome-profile'}",
            f"--window-size={size[0]},{size[1]}",
            "about:blank",
        ]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        self.browser_ws = None
        end = time.monotonic() + 60
        while time.monotonic() < end:
            line = self.proc.stderr.readline()
            if "DevTools listening on" in line:
                self.browser_ws = line.split("listening on", 1)[1].strip()
                break
            if not line and self.proc.poll() is not None:
                break
        threading.Thread(target=lambda: [None for _ in self.proc.stderr], daemon=True).start()
        if self.browser_ws is None:
            self.close()
            raise RuntimeError("chromium did not start its DevTools endpoint")
        self.size = size
        self.requests: list[str] = []
        self.exceptions: list[str] = []
        self._id = 0

    def page_ws(self) -> str:
        import json
        import urllib.request

        port = self.browser_ws.split("//", 1)[1].split("/", 1)[0]
        with urllib.request.urlopen(f"http://{port}/json/list", timeout=10) as r:
            pages = [t for t in json.load(r) if t.get("type") == "page"]
        return pages[0]["webSocketDebuggerUrl"]

    async def _call(self, ws, method: str, **params):
        import json

        self._id += 1
        my = self._id
        await ws.send(json.dumps({"id": my, "method": method, "params": params}))
        while True:
            msg = json.loads(await ws.recv())
            if msg.get("id") == my:
                if "error" in msg:
                    raise RuntimeError(f"{method}: {msg['error']}")
                return msg.get("result", {})
            if msg.get("method") == "Network.requestWillBeSent":
                self.requests.append(msg["params"]["request"]["url"])
            elif msg.get("method") == "Runtime.exceptionThrown":
                self.exceptions.append(str(msg["params"]["exceptionDetails"].get("text")))

    async def run(self, url: str, ready, timeout: float) -> tuple[np.ndarray | None, float]:
        """Open ``url``; screenshot every 0.5 s until ``ready(img)``; returns (last image, seconds)."""
        import base64

        import cv2
        import websockets

        async with websockets.connect(self.page_ws(), max_size=64 << 20) as ws:
            for m in ("Network.enable", "Page.enable", "Runtime.enable"):
                await self._call(ws, m)
            await self._call(
                ws,
                "Emulation.setDeviceMetricsOverride",
                width=self.size[0],
                height=self.size[1],
                deviceScaleFactor=1,
                mobile=False,
            )
            t0 = time.monotonic()
            await self._call(ws, "Page.navigate", url=url)
            img = None
            while time.monotonic() - t0 < timeout:
                await asyncio.sleep(0.5)
                shot = await self._call(ws, "Page.captureScreenshot", format="png")
                buf = np.frombuffer(base64.b64decode(shot["data"]), np.uint8)
                img = cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1]
                if ready(img):
                    return img, time.monotonic() - t0
            return img, time.monotonic() - t0

    def close(self) -> None:
        _terminate(self.proc)


def _near(img: np.ndarray, rgb, tol: int) -> int:
    return int((np.abs(img.astype(np.int32) - np.array(rgb)).max(-1) <= tol).sum())


def _scene_stats(img: np.ndarray) -> dict[str, float]:
    # 3D canvas without the GUI panel (top right) and viser's "software WebGL" notice (top left, with an
    # orange bar that would pass for touch points).
    canvas = img[170:, :800]
    return {
        "non_bg": float((np.abs(canvas.astype(np.int32) - 255).max(-1) > 30).mean()),
        "colours": float(len(np.unique(canvas.reshape(-1, 3), axis=0))),
        "vision": float(_near(canvas, VISION_RGB, 50)),
        "touch": float(_near(canvas, TOUCH_RGB, 50)),
    }


def _scene_ready(img: np.ndarray) -> bool:
    # The viewer opens at the last frame, so the whole fused cloud (5000 vision + 1000 touch points)
    # is drawn in modality colours (points are shaded, hence the tolerance).
    s = _scene_stats(img)
    return s["non_bg"] > 0.01 and s["colours"] > 50 and s["vision"] > 300 and s["touch"] > 60


@pytest.mark.skipif(CHROMIUM is None, reason="no chromium binary (apt-get install chromium; ./run test does it)")
def test_viewer_page_renders_scene_in_headless_chromium(view_fixture, tmp_path):
    import cv2

    port = _free_port()
    srv = _Server(view_fixture["demo"], port)
    browser = None
    try:
        assert srv.wait_for("ready in", 90), "viewer did not start:\n" + "\n".join(srv.lines[-20:])
        browser = _DevTools(tmp_path)
        img, seconds = asyncio.run(browser.run(f"http://127.0.0.1:{port}", _scene_ready, timeout=60))
        assert srv.wait_for("connected", 10), "server never logged the browser client:\n" + "\n".join(srv.lines)
    finally:
        if browser is not None:
            browser.close()
        srv.stop()
    assert img is not None, "no screenshot taken"
    cv2.imwrite(str(tmp_path / "page.png"), img[..., ::-1])
    print(f"scene shown {seconds:.1f} s after navigation: {_scene_stats(img)}")
    assert img.shape[:2] == (800, 1200)
    stats = _scene_stats(img)
    assert _scene_ready(img), f"scene not rendered within {seconds:.1f} s: {stats} (screenshot {tmp_path / 'page.png'})"
    connected = [ln for ln in srv.lines if "client" in ln and "connected" in ln]
    assert connected and "client 0 connected" in connected[0]
    # Offline: every request the page made went to the viewer itself (or inline data/blob URLs).
    external = [
        u
        for u in browser.requests
        if not u.startswith((f"http://127.0.0.1:{port}", f"ws://127.0.0.1:{port}", "data:", "blob:"))
    ]
    assert browser.requests and not external, external
