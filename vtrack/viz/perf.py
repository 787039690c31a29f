"""Measure the viewer's load time and per-frame update (scrubbing) cost on a session / result.

Run: ``python -m vtrack.viz.perf PATH [--points N]``. With ``--points N`` a synthetic fused cloud of N
points (spread over the session's time span) is written next to a copy of the result metadata in a
temporary folder, so the scrubbing cost can be measured at a chosen display size (N > 200 k is
decimated to 200 k). Reports medians / p95 in ms of :meth:`Viewer.update_frame` (server side: data
access, FK, cloud bin updates, image encoding, message queueing) for

- ``cold``: frames whose images are not cached yet (zarr reads + decode),
- ``warm``: after the background cache fill (what playback and repeated scrubbing see),
- ``full-cloud``: warm, with "cloud up to current time" off.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np


def _synthetic_result(session: Path, n: int, out: Path) -> Path:
    from vtrack.io.export import write_ply_points
    from vtrack.io.session import open_session

    r = open_session(session)
    ts = np.concatenate([s.t for s in r.streams.values() if s.n]) if r.streams else np.zeros(1)
    rng = np.random.default_rng(0)
    P = rng.normal(size=(n, 3))
    P *= 0.03 / np.linalg.norm(P, axis=1, keepdims=True)
    mod = (rng.random(n) < 0.05).astype(np.int32)
    out.mkdir(parents=True, exist_ok=True)
    write_ply_points(
        out / "cloud.ply",
        P,
        scalars={
            "modality": mod,
            "t": rng.uniform(ts.min(), ts.max(), n),
            "sensor_id": np.zeros(n, np.int32),
            "confidence": rng.random(n).astype(np.float32),
            "tactile_value": rng.random(n).astype(np.float32),
        },
    )
    (out / "result.json").write_text(json.dumps({"kind": "reconstruction", "session": str(session)}))
    return out


def measure(path: str | Path, points: int = 0, frames: int = 60, seed: int = 0) -> dict:
    """Load ``path`` in a :class:`~vtrack.viz.viewer.Viewer` (port 0) and time frame updates (ms).

    ``open_s`` is wall time from loading to a served scene (imports excluded), ``open_cpu_s`` the CPU time
    of this process over the same span (close to the wall time on an idle machine; on a shared one
    the wall time also holds waiting for a core)."""
    from vtrack.viz.data import ViewData, resolve_sources
    from vtrack.viz.viewer import Viewer

    tmp = None
    if points:
        src = resolve_sources(path)
        if src.session is None:
            raise SystemExit("--points needs a session (directly or through a result's 'session')")
        tmp = tempfile.TemporaryDirectory(prefix="vtrack-viewperf-")
        path = _synthetic_result(src.session, points, Path(tmp.name) / "rec")
    c0, t0 = time.process_time(), time.perf_counter()
    data = ViewData(path)
    t1 = time.perf_counter()
    v = Viewer(data, port=0, log=lambda m: None)
    t2, c2 = time.perf_counter(), time.process_time()
    v.frame_ms.clear()
    rng = np.random.default_rng(seed)
    n = data.n_frames
    # Stop the background filler from helping the "cold" measurement.
    idx = [int(i) for i in rng.choice(n, size=min(frames, n), replace=False)]
    cold = [v.update_frame(i) for i in idx if not data.is_cached(i)]
    end = time.monotonic() + 120
    while not all(data.is_cached(i) for i in range(n)) and not data.image_cache_full and time.monotonic() < end:
        for i in range(n):
            data.images(i)
    warm = [v.update_frame(int(i)) for i in rng.integers(0, n, frames)]
    v.accumulate.value = False
    v.wait_idle(30)
    full = [v.update_frame(int(i)) for i in rng.integers(0, n, frames)]
    v.stop()
    if tmp is not None:
        tmp.cleanup()

    def stats(a: list[float]) -> dict:
        x = np.asarray(a, np.float64)
        return {
            "n": len(x),
            "median_ms": float(np.median(x)) if len(x) else None,
            "p95_ms": float(np.percentile(x, 95)) if len(x) else None,
        }

    return {
        "load_s": t1 - t0,
        "viewer_s": t2 - t1,
        "open_s": t2 - t0,
        "open_cpu_s": c2 - c0,
        "frames": n,
        "cloud_shown": len(data.cloud) if data.cloud is not None else 0,
        "cloud_total": data.cloud.n_total if data.cloud is not None else 0,
        "cold": stats(cold),
        "warm": stats(warm),
        "full_cloud": stats(full),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("path")
    ap.add_argument("--points", type=int, default=0, help="synthetic cloud size (0 = use the result's cloud)")
    ap.add_argument("--frames", type=int, default=60)
    a = ap.parse_args()
    print(json.dumps(measure(a.path, a.points, a.frames), indent=1))


if __name__ == "__main__":
    main()
