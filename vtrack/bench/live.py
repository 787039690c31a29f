"""``vtrack bench live``: blind tracking live at sensor rate (real-time replay through ``vtrack.live``).

Each case replays a simulator session at real time (1 camera at 30 Hz, 4 DIGIT at 60 Hz, joints at 60 Hz)
into the ``track`` consumer (blind SLAM: segmentation by the FK-posed hand, touch from the tactile images
through each sensor's calibrated pipeline; the session's ``gt/`` is read only after the run, to score). Rows
(one per session x variant), with the definitions of :func:`vtrack.live.pipeline.live_summary`:

- ``real_time_factor`` (wall time; lowered by whatever else runs on the machine) and
  ``real_time_factor_cpu`` (each worker thread's CPU time: what it reaches with a core to itself);
- latency of a pose after its camera frame (mean / p95), dropped tactile / camera frames (%), poses/s;
- ``track_runq_ms``: ms per tracked frame the tracker's thread waited on the OS run queue for a core (Linux): how
  much of a step's wall time the machine's load added (wall = CPU + this + waits for the GIL or a helper);
- ``motion_err_mm``: object-motion error of the live poses (ADD; ADD-S for symmetric objects);
- ``ms``: CPU ms of one camera frame (segmentation + tracking; the tactile pipeline too in the ``touch in
  camera step`` variant), ``frames_cpu_ms``: its segmentation / frame-building part when that is a stage of its
  own (in the child process), ``touch_cpu_ms``: CPU ms per tactile image in the touch worker;
- ``cpu_s_per_session_s``: CPU seconds of all the pipeline's processes per second of recording;
- ``load1``: the machine's 1-minute load average at the start of the row (2 cores: above 2, every figure
  measured in wall time is inflated); ``speed_probe_ms``: :func:`vtrack.bench.harness.speed_probe_ms` just before
  the row (the cores' speed at the time: a shared machine's changes by up to ~1.8x within hours at a low load).

Variants: ``default`` (what ``vtrack live`` does: the tactile pipeline on every tactile image as it arrives in a
child process, segmentation with the colour term's feature tracks on the camera's RGB image a stage ahead of the
tracker in a second child, the replay decoding the session in a third process into a shared-memory ring that the
other processes read in place), ``inline frames`` (segmentation in the tracker's step: the default until
2026-11-28), ``frames in the touch process`` (segmentation a stage ahead of the tracker in the touch child),
``frames inline, reader thread``, ``touch thread`` (the tactile pipeline in a worker thread sharing the GIL with
the tracker), ``touch in camera step`` (the newest image of each sensor is processed inside the camera step, as
offline tracking does; tactile images in between are never read), ``pickled transport`` (the default without
the shared-memory ring: every frame pickled through the reader's queue, every tactile image again to the touch
child) and ``adaptive camera stride`` (the tracker skips camera frames, stride <= 2, while its steps take longer
than 0.9 camera periods; ``camera_strided_pct`` = camera frames it did not track) and ``no colour (depth only)``
(the tracker's frames without the colour term's feature tracks; the replay does not decode the camera's RGB)

and ``sticking contacts`` (SLAM's preset for fingers that drive the object, ``vtrack live --contacts stick``).

Cases: 3 shared YCB objects, 5 s sessions, occlusion none, or ``VTRACK_BENCH_LIVE_CASES`` =
``"object|occlusion|seconds[|contact mode[|seed]];..."`` (the simulator's ``sim.contact_mode``: ``slide``, the
default, or ``stick``: fingers that drive the object; its seed, default 0). Quick mode: one 2 s session, the default
variant.
"""

from __future__ import annotations

import itertools
import os
import time

import numpy as np

from vtrack.bench.harness import BenchTable, env_list, speed_probe_ms

VARIANTS = {
    "default (touch process, frames process, reader process)": {},
    # segmentation in the tracker's step: the default until 2026-11-28 (docs/benchmarks/live_frames_process.md)
    "inline frames": {"frames_worker": "inline", "reader": "process"},
    "frames in the touch process": {"frames_worker": "shared", "reader": "process"},
    "frames inline, reader thread": {"frames_worker": "inline", "reader": "thread"},
    "touch thread": {"touch_worker": "thread", "frames_worker": "inline", "reader": "thread"},
    "touch in camera step": {"touch_worker": "off", "frames_worker": "inline", "reader": "thread"},
    # the reader process pickles every frame through the queue and the touch worker each image to its helper
    # (no shared-memory ring): the transport before 2026-11-26 late morning
    "pickled transport": {"transport": "pipe"},
    # the tracker skips camera frames while its steps take longer than 0.9 camera periods (stride <= 2)
    "adaptive camera stride": {"max_camera_stride": 2},
    # depth only: frames without the colour term's feature tracks, the camera's RGB not decoded (before 2026-11-26
    # evening)
    "no colour (depth only)": {"colour": False},
    # SLAM's preset for fingers that drive the object (`vtrack live --contacts stick`; ids built where the frames are)
    "sticking contacts": {"preset": "SLAM_STICKING_CONTACTS"},
}
DEFAULT_VARIANT = "default (touch process, frames process, reader process)"
CASES = (("006_mustard_bottle", "none", 5.0), ("005_tomato_soup_can", "none", 5.0), ("025_mug", "none", 5.0))


def _cases(quick: bool) -> list[tuple[str, str, float, str, int]]:
    """(object, occlusion, seconds, the simulator's contact mode, its seed) per case."""
    env = os.environ.get("VTRACK_BENCH_LIVE_CASES")
    if env:
        out = []
        for item in env.split(";"):
            name, occ, sec, mode, seed = (item.split("|") + ["none", "5", "slide", "0"])[:5]
            out.append((name, occ or "none", float(sec or 5), mode or "slide", int(seed or 0)))
        return out
    return [("006_mustard_bottle", "none", 2.0, "slide", 0)] if quick else [(*c, "slide", 0) for c in CASES]


def _speeds() -> list[float]:
    """Replay speeds: ``VTRACK_BENCH_LIVE_SPEED``, one or a comma-separated list (default 1 = real time). Below 1
    (e.g. 0.25) every frame is processed on a loaded machine, so ``cpu_s_per_session_s`` is the full CPU demand of
    real time. Above 1 the recording plays faster than it was taken: for the pipeline's per-frame budget the same
    as cores that many times slower, so a sweep (``1,1.5,1.8,2.2``) measures the headroom of the live target: the
    slowdown of the machine it survives.

    Raises:
        InputError: not a list of distinct numbers in (0, 10].
    """
    return env_list(
        "VTRACK_BENCH_LIVE_SPEED",
        float,
        [1.0],
        lambda v: 0.0 < v <= 10.0,
        "bad live replay speed",
        field="VTRACK_BENCH_LIVE_SPEED",
        expected="distinct numbers in (0, 10], e.g. 1,1.5,2",
    )


def run_live(session, variant: dict, speed: float = 1.0) -> dict:
    """One replay of ``session`` (``speed`` x real time) into the ``track`` consumer (``variant``: its
    options, plus ``reader`` = the replay's decoder, process | thread, and ``transport`` = shm | pipe); the
    pipeline's result dict."""
    from vtrack.live.consumers import make_consumer, replay_fields, replay_streams
    from vtrack.live.pipeline import LivePipeline
    from vtrack.live.sources import SessionReplaySource

    variant = dict(variant)
    if "preset" in variant:  # a named dict of tracker options in vtrack.tracking.slam
        import vtrack.tracking.slam as slam

        variant = {**getattr(slam, variant.pop("preset")), **variant}
    reader = variant.pop("reader", "process")
    transport = variant.pop("transport", "shm")
    cons = [make_consumer("track", session, **variant)]
    src = SessionReplaySource(
        session,
        streams=replay_streams(session, cons),
        fields=replay_fields(cons),
        reader=reader,
        speed=speed,
        transport=transport,
    )
    return LivePipeline(src, cons).run()


def run(quick: bool = False) -> BenchTable:
    from vtrack.live.pipeline import source_stream
    from vtrack.testing.sim import ycb_session

    table = BenchTable(stage="live", error_key="motion_err_mm", time_key="ms")
    variants = {DEFAULT_VARIANT: VARIANTS[DEFAULT_VARIANT]} if quick else VARIANTS
    only = os.environ.get("VTRACK_BENCH_LIVE_VARIANTS")
    if only:
        variants = {k: v for k, v in variants.items() if any(o.strip() and o.strip() in k for o in only.split(";"))}
    speeds = _speeds()
    for name, occ, seconds, contacts, seed in _cases(quick):
        sess = ycb_session(name, occ, seconds, contact_mode=contacts, seed=seed)
        for (vname, v), speed in itertools.product(variants.items(), speeds):
            load1 = os.getloadavg()[0]
            probe = speed_probe_ms()
            t0 = time.perf_counter()
            res = run_live(sess, v, speed)
            sm = res["summary"]
            tr = res["consumers"]["track"]
            cam = next((s for k, s in tr["streams"].items() if source_stream(k).startswith("camera/")), {})
            fr = res["consumers"].get("track.frames", {}).get("streams", {})
            seg = next((s for k, s in fr.items() if k.startswith("camera/")), {})
            touch = res["consumers"].get("track.touch", {}).get("streams", {})
            touch_cpu = [s["cpu_ms_mean"] for s in touch.values() if s["processed"]]
            table.add(
                method=vname if speed == 1.0 else f"{vname} @ {speed:g}x",
                setting=f"{name} / {occ} / {seconds:g} s"
                + (f" / {contacts} fingers" if contacts != "slide" else "")
                + (f" / seed {seed}" if seed else ""),
                object=name,
                occlusion=occ,
                contacts=contacts,
                seed=seed,
                real_time_factor=sm.get("real_time_factor"),
                real_time_factor_cpu=sm.get("real_time_factor_cpu"),
                # what the CPU figure predicts at real time when the replay ran at `speed` (capacity scales)
                rtf_cpu_at_speed_1=None
                if sm.get("real_time_factor_cpu") is None
                else round(sm["real_time_factor_cpu"] * speed, 3),
                latency_ms_mean=sm.get("latency_ms_mean"),
                latency_ms_p95=sm.get("latency_ms_p95"),
                dropped_tactile_pct=sm.get("dropped_tactile_pct"),
                dropped_camera_pct=sm.get("dropped_camera_pct"),
                poses_per_s=sm.get("poses_per_s"),
                # ms per tracked frame the tracker's thread waited for a core (the machine's load, not the pipeline)
                track_runq_ms=sm.get("runq_ms_mean"),
                cpu_s_per_session_s=sm.get("cpu_s_per_session_s"),
                cpu_main_s_per_session_s=round(res["cpu"]["main_s"] / max(res["cpu"]["session_s"], 1e-9), 3),
                speed=speed,
                motion_err_mm=tr["result"].get("motion_err_mm", float("nan")),
                ms=cam.get("cpu_ms_mean", float("nan")) + seg.get("cpu_ms_mean", 0.0),
                frames_cpu_ms=seg.get("cpu_ms_mean", float("nan")),
                touch_cpu_ms=float(np.mean(touch_cpu)) if touch_cpu else float("nan"),
                steps=tr["result"].get("steps", 0),
                # camera frames the stride policy did not track, % of those the tracker took
                camera_strided_pct=round(
                    100.0
                    * tr["result"].get("camera_skipped", 0)
                    / max(tr["result"].get("camera_skipped", 0) + tr["result"].get("steps", 0), 1),
                    2,
                ),  # fmt: skip
                # per worker (stage): which one sets real_time_factor_cpu
                rtf_cpu_by_worker="; ".join(
                    f"{k} {v['real_time_factor_cpu']:g}"
                    for k, v in res["consumers"].items()
                    if v.get("real_time_factor_cpu") is not None
                ),
                load1=round(load1, 2),
                speed_probe_ms=probe,
                wall_s=round(time.perf_counter() - t0, 1),
                error=tr.get("first_error", ""),
            )
    table.notes.append(
        "Command: `vtrack --threads 1 bench live --out DIR`. Real-time replay (speed 1) of blind sessions; "
        "real_time_factor = capacity / demand of the busiest worker thread (wall time), real_time_factor_cpu = "
        "the same from thread CPU time (a core per worker); see vtrack/live/pipeline.py::live_summary."
    )
    table.notes.append(
        "cpu_s_per_session_s: CPU seconds of all the pipeline's processes (main, touch, reader) per second of "
        "recording, independent of the load; real time on 2 cores needs < 2 (with margin: the OS, the emitter's "
        "timing). `VTRACK_BENCH_LIVE_SPEED=0.25` replays at quarter speed so that no frame is dropped and it is "
        "the full demand; above 1 (a list: `1,1.5,1.8`) the replay is faster than the recording, as if the cores "
        "were that much slower (rows `@ 1.5x`): the headroom of the live target; "
        "`VTRACK_BENCH_LIVE_VARIANTS='default;reader thread'` selects rows."
    )
    table.notes.append(
        "Measured on a shared 2-core machine: `load1` is the load average when the row started; with a load "
        "above 2 the wall-time figures (real_time_factor, latency, drops) are inflated by the other processes."
    )
    return table
