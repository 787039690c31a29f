"""Run consumers on a live stream, dropping frames rather than falling behind.

Each consumer has a worker thread and a *mailbox* with one slot per stream: a new frame replaces
an unprocessed one of the same stream (counted as dropped), so a slow consumer always works on the
newest data and its latency stays bounded by one processing step, whatever the input rate.
The worker takes the pending frame with the oldest timestamp first (so joints that precede a
camera frame are applied before it).

A consumer may keep up to ``max_pending`` frames of a stream (a short queue that absorbs a burst,
e.g. the tactile stage while the other core is taken by a tracker step; beyond it the oldest is
replaced, counted as dropped), and with ``batch = True`` it is handed every pending frame at once
(:meth:`Consumer.process_batch`: one round trip to a helper process for the four tactile images of
a time step instead of four).
"""

from __future__ import annotations

import os
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vtrack.live.shared import FrameOverwritten
from vtrack.live.sources import FrameEvent

#: Prefix of a stream a consumer stage derives from a source stream and hands to a later stage
#: (``frames/camera/cam0``: camera/cam0's tracking frames); its frames count as frames of the source stream.
DERIVED_PREFIX = "frames/"


def source_stream(stream: str) -> str:
    """The source stream a (possibly derived) stream's frames come from."""
    return stream[len(DERIVED_PREFIX) :] if stream.startswith(DERIVED_PREFIX) else stream


class Consumer:
    """Base class: ``wants(stream)`` selects streams; ``process(event)`` handles one frame;
    ``finish()`` returns a JSON-able result dict. A consumer whose work splits into stages that may run
    concurrently (e.g. tactile images through the tactile pipeline at 60 Hz beside the tracker at the camera
    rate) returns them from ``parts()``: each part gets its own worker thread and mailbox. A part that feeds a
    later one calls ``forward(event)`` (set by the pipeline) with a stream named ``DERIVED_PREFIX + source
    stream`` and the source frame's ``wall`` time; it goes to the mailboxes of the parts that want it."""

    name = "consumer"
    forward: Callable[[FrameEvent], None] | None = None
    #: unprocessed frames of one stream the mailbox keeps; a newer one then replaces the oldest (counted dropped)
    max_pending: int = 1
    #: hand the worker's pending frames to :meth:`process_batch` all at once (else one by one, oldest first)
    batch: bool = False

    def wants(self, stream: str) -> bool:
        return True

    def process(self, event: FrameEvent) -> None:
        raise NotImplementedError

    def process_batch(self, events: list[FrameEvent]) -> list[bool]:
        """Handle several frames (``batch = True``: every pending frame, oldest first). Returns per frame
        whether it was processed (False: lost, e.g. its shared-memory slot was overwritten: counted dropped)."""
        out = []
        for ev in events:
            try:
                self.process(ev)
                out.append(True)
            except FrameOverwritten:
                out.append(False)
        return out

    def finish(self) -> dict[str, Any]:
        return {}

    def parts(self) -> list[Consumer]:
        return [self]


@dataclass
class ConsumerStats:
    received: dict[str, int] = field(default_factory=dict)
    processed: dict[str, int] = field(default_factory=dict)
    dropped: dict[str, int] = field(default_factory=dict)
    latency_ms: list[float] = field(default_factory=list)
    busy_s: float = 0.0
    errors: int = 0
    busy_by_stream: dict[str, float] = field(default_factory=dict)
    cpu_by_stream: dict[str, float] = field(default_factory=dict)
    #: seconds the worker thread waited on the OS run queue for a core while processing (Linux; absent elsewhere)
    runq_by_stream: dict[str, float] = field(default_factory=dict)
    latency_by_stream: dict[str, list[float]] = field(default_factory=dict)

    def summary(self, wall_s: float) -> dict[str, Any]:
        lat = np.asarray(self.latency_ms) if self.latency_ms else np.zeros(1)
        streams = sorted(set(self.received) | set(self.processed))
        return {
            "streams": {
                s: {
                    "received": self.received.get(s, 0),
                    "processed": self.processed.get(s, 0),
                    "dropped": self.dropped.get(s, 0),
                    "rate_hz": round(self.processed.get(s, 0) / max(wall_s, 1e-9), 2),
                    "busy_ms_mean": round(1e3 * self.busy_by_stream.get(s, 0.0) / max(self.processed.get(s, 0), 1), 2),
                    "cpu_ms_mean": round(1e3 * self.cpu_by_stream.get(s, 0.0) / max(self.processed.get(s, 0), 1), 2),
                    "runq_ms_mean": round(1e3 * self.runq_by_stream[s] / max(self.processed.get(s, 0), 1), 2)
                    if s in self.runq_by_stream
                    else None,
                    "latency_ms_mean": _r(np.mean(self.latency_by_stream[s]))
                    if self.latency_by_stream.get(s)
                    else None,
                    "latency_ms_p95": _r(np.percentile(self.latency_by_stream[s], 95))
                    if self.latency_by_stream.get(s)
                    else None,
                }
                for s in streams
            },
            "dropped_total": int(sum(self.dropped.values())),
            "processed_total": int(sum(self.processed.values())),
            "latency_ms_mean": round(float(lat.mean()), 2),
            "latency_ms_p95": round(float(np.percentile(lat, 95)), 2),
            "busy_fraction": round(self.busy_s / max(wall_s, 1e-9), 3),
            "errors": self.errors,
        }


def _r(x: float) -> float:
    return round(float(x), 2)


def thread_sched_ns(fd: int | None = None) -> tuple[int, int] | None:
    """(ns on a CPU, ns waiting on the run queue for one) of the calling thread so far, from Linux's
    ``/proc/thread-self/schedstat``; None where the OS does not say. ``fd``: that file opened by this thread
    (:func:`open_thread_sched`), read again in place: ~2 instead of ~14 us a call, twice per frame a stage handles."""
    try:
        if fd is not None:
            raw = os.pread(fd, 128, 0)
        else:
            with open("/proc/thread-self/schedstat", "rb") as f:
                raw = f.read()
        on_cpu, waiting = raw.split()[:2]
        return int(on_cpu), int(waiting)
    except (OSError, ValueError):
        return None


def open_thread_sched() -> int | None:
    """The calling thread's ``/proc/thread-self/schedstat`` opened for :func:`thread_sched_ns` (None if absent)."""
    try:
        return os.open("/proc/thread-self/schedstat", os.O_RDONLY)
    except (OSError, AttributeError):
        return None


class _Worker(threading.Thread):
    def __init__(self, consumer: Consumer) -> None:
        super().__init__(daemon=True, name=f"live-{consumer.name}")
        self.consumer = consumer
        self.slots: dict[str, deque[FrameEvent]] = {}  # per stream, pending frames oldest first
        self.max_pending = max(1, int(getattr(consumer, "max_pending", 1)))
        self.cv = threading.Condition()
        self.closed = False
        self.stats = ConsumerStats()
        self.error: BaseException | None = None

    def put(self, ev: FrameEvent) -> None:
        with self.cv:
            st = self.stats
            st.received[ev.stream] = st.received.get(ev.stream, 0) + 1
            q = self.slots.setdefault(ev.stream, deque())
            if len(q) >= self.max_pending:  # full: the oldest unprocessed frame is replaced, never processed
                q.popleft()
                st.dropped[ev.stream] = st.dropped.get(ev.stream, 0) + 1
            q.append(ev)
            self.cv.notify()

    def close(self) -> None:
        with self.cv:
            self.closed = True
            self.cv.notify()

    def _take(self) -> list[FrameEvent]:
        """The next frames to process (under the lock): the oldest pending one, or all of them (batch)."""
        if self.consumer.batch:
            evs = sorted((ev for q in self.slots.values() for ev in q), key=lambda e: e.t)
            self.slots.clear()
            return evs
        key = min((k for k, q in self.slots.items() if q), key=lambda k: self.slots[k][0].t)
        q = self.slots[key]
        ev = q.popleft()
        if not q:
            del self.slots[key]
        return [ev]

    def run(self) -> None:
        sched = open_thread_sched()  # this thread's: opened here, in the thread it describes
        try:
            self._run(sched)
        finally:
            if sched is not None:
                os.close(sched)

    def _run(self, sched: int | None) -> None:
        while True:
            with self.cv:
                while not self.slots and not self.closed:
                    self.cv.wait(0.1)
                if not self.slots and self.closed:
                    return
                evs = self._take()
            t0, c0, q0 = time.perf_counter(), time.thread_time(), thread_sched_ns(sched)
            try:
                if len(evs) == 1 and not self.consumer.batch:
                    self.consumer.process(evs[0])
                    ok = [True]
                else:
                    ok = self.consumer.process_batch(evs)
            except FrameOverwritten:  # its shared slot was reused before it was read: a dropped frame
                ok = [False] * len(evs)
            except Exception as e:  # keep the pipeline alive; the first error is reported
                self.stats.errors += 1
                if self.error is None:
                    self.error = e
                ok = [True] * len(evs)  # processed (with an error), as before batching
            t1, q1 = time.perf_counter(), thread_sched_ns(sched)
            runq = None if q0 is None or q1 is None else (q1[1] - q0[1]) * 1e-9
            st = self.stats
            # + CPU the consumer spent in a helper process for these frames (its own thread only waited); read
            # once: a frame handled next (joints) must not count the previous frame's offloaded CPU again
            cpu = time.thread_time() - c0 + float(getattr(self.consumer, "offload_cpu_s", 0.0))
            if hasattr(self.consumer, "offload_cpu_s"):
                self.consumer.offload_cpu_s = 0.0
            n = max(sum(ok), 1)  # a batch's time and CPU are shared by the frames it processed
            with self.cv:
                for ev, done in zip(evs, ok, strict=True):
                    if not done:
                        st.dropped[ev.stream] = st.dropped.get(ev.stream, 0) + 1
            for ev, done in zip(evs, ok, strict=True):
                if not done:
                    continue
                st.busy_s += (t1 - t0) / n
                st.busy_by_stream[ev.stream] = st.busy_by_stream.get(ev.stream, 0.0) + (t1 - t0) / n
                st.cpu_by_stream[ev.stream] = st.cpu_by_stream.get(ev.stream, 0.0) + cpu / n
                if runq is not None:
                    st.runq_by_stream[ev.stream] = st.runq_by_stream.get(ev.stream, 0.0) + runq / n
                st.latency_ms.append((t1 - ev.wall) * 1e3)
                st.latency_by_stream.setdefault(ev.stream, []).append((t1 - ev.wall) * 1e3)
                st.processed[ev.stream] = st.processed.get(ev.stream, 0) + 1


class LivePipeline:
    """Connect a source to consumers and run until the source ends (or :meth:`stop`)."""

    def __init__(self, source: Any, consumers: list[Consumer], switch_interval_s: float = 0.001) -> None:
        self.source = source
        self.switch_interval_s = switch_interval_s
        self.consumers = consumers
        self.workers = [_Worker(p) for c in consumers for p in c.parts()]
        for w in self.workers:
            w.consumer.forward = self._emit

    def _emit(self, ev: FrameEvent) -> None:
        for w in self.workers:
            if w.consumer.wants(ev.stream):
                w.put(ev)

    def stop(self) -> None:
        self.source.stop()

    def run(self) -> dict[str, Any]:
        """Run to the end; returns per-consumer statistics and results plus the source's."""
        import sys

        # Short GIL slices: the replay reader and emitter make many short calls and must not wait
        # a full default 5 ms slice behind a consumer's Python-heavy step.
        old_switch = sys.getswitchinterval()
        sys.setswitchinterval(self.switch_interval_s)
        for w in self.workers:
            w.start()
        t0, cpu0 = time.perf_counter(), time.process_time()
        try:
            src_stats = self.source.run(self._emit)
        except KeyboardInterrupt:
            self.source.stop()
            src_stats = self.source.stats
        finally:
            sys.setswitchinterval(old_switch)
        t_src = time.perf_counter() - t0
        for w in self.workers:  # in stage order: a stage may still forward its last frame to a later one
            w.close()
            w.join()
        close = getattr(self.source, "close", None)
        if close is not None:  # e.g. a replay's shared-memory ring: every frame is done with now
            close()
        wall = time.perf_counter() - t0
        cpu_main = time.process_time() - cpu0  # all threads of this process (workers, emitter, a reader thread)
        active = src_stats.active_s or t_src
        out: dict[str, Any] = {
            "wall_s": round(wall, 3),
            "source_s": round(t_src, 3),
            "active_s": round(active, 3),
            "source": {
                "emitted": dict(src_stats.emitted),
                "skipped_late": dict(src_stats.skipped_late),
                "max_lag_ms": round(src_stats.max_lag_s * 1e3, 2),
                "emitted_rate_hz": src_stats.rates_hz(),
            },
            "consumers": {},
        }
        for w in self.workers:
            res = w.stats.summary(active)
            res["result"] = w.consumer.finish()
            if w.error is not None:
                res["first_error"] = f"{type(w.error).__name__}: {w.error}"
            out["consumers"][w.consumer.name] = res
        # child processes (a consumer's helper process, a reader process) report their own CPU time
        cpu_children = float(getattr(src_stats, "reader_cpu_s", 0.0)) + sum(
            float(getattr(w.consumer, "child_cpu_s", 0.0)) for w in self.workers
        )
        out["cpu"] = {
            "main_s": round(cpu_main, 3),
            "children_s": round(cpu_children, 3),
            "total_s": round(cpu_main + cpu_children, 3),
            # seconds of the recording replayed (the source's clock runs `speed` x the wall clock)
            "session_s": round(active * float(getattr(self.source, "speed", 1.0)), 3),
        }
        out["summary"] = live_summary(out, [c.name for c in self.consumers])
        return out


def live_summary(res: dict[str, Any], consumers: list[str] | None = None) -> dict[str, Any]:
    """The headline figures of a live run (``LivePipeline.run`` output), defined so they can be checked:

    - ``real_time_factor``: min over worker threads of capacity / demand = active replay seconds / the
      seconds that processing every frame the worker received would take (its mean busy time per frame of each
      stream x frames received). >= 1: the pipeline keeps up with the sensors; < 1: it must drop frames.
      ``real_time_factor_cpu``: the same from each worker thread's CPU time (what it would reach with a core
      to itself; on a shared, loaded machine the wall-time figure is lower by the load).
    - ``dropped_<kind>_pct`` (kind = tactile | camera | joints): frames of those streams never processed, %
      of the frames in the replayed schedule: skipped by the source (late) or replaced unprocessed in a
      worker's mailbox (the worst worker that takes the stream).
    - ``latency_ms_mean`` / ``latency_ms_p95``: from a camera frame's emission to the end of its processing
      (the pose), in the ``track`` consumer (else the first consumer).
    - ``runq_ms_mean``: per processed camera frame of the ``track`` consumer (else the first), ms its worker thread
      waited on the OS run queue for a core (Linux, ``/proc/thread-self/schedstat``; None elsewhere). A step's wall
      time is its CPU time + this + waits for the GIL or a helper process: a machine short of cores shows here.
    - ``poses_per_s``: tracker steps / active seconds (``track`` consumer).
    - ``cpu_s_per_session_s``: CPU seconds of every process of the pipeline (this one, a reader process, the
      consumers' helper processes) per second of replayed recording. Independent of the machine's load (to
      the extent CPU time is); real time on ``n`` cores needs it below ``n`` (frames dropped are not counted:
      replay with ``speed`` < 1 to measure the full demand).
    """
    src = res["source"]
    active = max(float(res.get("active_s") or 0.0), 1e-9)
    scheduled = {
        k: src["emitted"].get(k, 0) + src["skipped_late"].get(k, 0)
        for k in set(src["emitted"]) | set(src["skipped_late"])
    }
    cons = res["consumers"]
    out: dict[str, Any] = {}
    for c in cons.values():
        # demand: processing EVERY frame of the schedule (also those the source skipped or the mailbox replaced)
        # at the worker's mean time per processed frame of each stream
        for key, per in (("real_time_factor", "busy_ms_mean"), ("real_time_factor_cpu", "cpu_ms_mean")):
            demand = sum(
                v[per] * scheduled.get(source_stream(k), v["received"])
                for k, v in c["streams"].items()
                if v["processed"]
            )
            c[key] = round(1e3 * active / demand, 3) if demand > 0 else None
    for key in ("real_time_factor", "real_time_factor_cpu"):
        v = [c[key] for c in cons.values() if c.get(key) is not None]
        out[key] = min(v) if v else None
    # joints: only the newest state is used (a superseded one is not a loss), so they are not counted here
    for kind, prefix in (("tactile", "tactile/"), ("camera", "camera/")):
        names = [k for k in scheduled if k.startswith(prefix)]
        total = sum(scheduled[k] for k in names)
        if not total:
            continue
        lost = 0
        for k in names:
            # a consumer's stages in a chain each drop frames (camera/x, then frames/camera/x): they add up;
            # consumers side by side each see every frame: the worst one counts
            took: dict[str, int] = {}
            for name, c in cons.items():
                for kk in (k, DERIVED_PREFIX + k):
                    if kk in c["streams"]:
                        root = name.split(".", 1)[0]
                        took[root] = took.get(root, 0) + c["streams"][kk]["dropped"]
            lost += src["skipped_late"].get(k, 0) + (max(took.values()) if took else 0)
        out[f"dropped_{kind}_pct"] = round(100.0 * lost / total, 2)
    cpu = res.get("cpu")
    if cpu and cpu.get("session_s"):
        out["cpu_s_per_session_s"] = round(cpu["total_s"] / cpu["session_s"], 3)
    main = next((n for n in (consumers or []) if n == "track"), None) or next(iter(cons), None)
    if main is not None:
        cams = {
            k: v
            for k, v in cons[main]["streams"].items()
            if source_stream(k).startswith("camera/") and v["latency_ms_mean"]
        }
        if cams:
            s0 = next(iter(cams.values()))
            out["latency_ms_mean"], out["latency_ms_p95"] = s0["latency_ms_mean"], s0["latency_ms_p95"]
            out["runq_ms_mean"] = s0.get("runq_ms_mean")
        steps = cons[main].get("result", {}).get("steps")
        if steps is not None:
            out["poses_per_s"] = round(steps / active, 2)
    return out


def live_advice(res: dict[str, Any]) -> list[str]:
    """What a user should know when a live run did not keep up (``LivePipeline.run`` output with its ``summary``):
    one line each, empty when the run met real time (real-time factor >= 1 and < 5 % of the tactile frames dropped).

    It tells a machine short of cores (a worker that would keep up with a core to itself: ``real_time_factor_cpu``
    >= 1 > ``real_time_factor``) from work too heavy for this CPU (both below 1). Measured margins of the default
    pipeline: docs/benchmarks/live_headroom.md."""
    sm = res.get("summary") or {}
    cons = res.get("consumers") or {}
    out: list[str] = []
    rtf, rtf_cpu = sm.get("real_time_factor"), sm.get("real_time_factor_cpu")
    if rtf is not None and rtf < 1.0:
        slow = min(
            (n for n in cons if cons[n].get("real_time_factor") is not None),
            key=lambda n: cons[n]["real_time_factor"],
            default="?",
        )
        cam = sm.get("dropped_camera_pct")
        out.append(
            f"real-time factor {rtf:g} < 1: worker '{slow}' cannot keep up"
            + (f" ({cam:g} % of the camera frames dropped)" if cam is not None else "")
        )
        runq = sm.get("runq_ms_mean")
        if rtf_cpu is not None and rtf_cpu >= 1.0:
            out.append(
                f"it would keep up with a core of its own (CPU-time factor {rtf_cpu:g}): the machine is short of cores"
                + (f" (the tracker waited {runq:g} ms per step for one)" if runq else "")
                + "; the pipeline's processes and any other program share them"
            )
        else:
            out.append("it would not keep up with a core of its own either: this CPU is too slow for the configuration")
        if "track" in cons:
            # (a camera stride or depth-only tracking do not raise the factor, which counts every camera frame of the
            # recording: measured on the 5 s mug replayed at 2.2x, 0.774 default, 0.717 --no-colour, 0.759 stride <= 2)
            out.append("to track every camera frame: replay slower (--speed 0.5) or track offline (vtrack track)")
    tac = sm.get("dropped_tactile_pct")
    if tac is not None and tac >= 5.0:
        out.append(
            f"{tac:g} % of the tactile frames dropped (>= 5 %): the touch stage falls behind; the pipeline needs "
            "the machine's cores to itself"
        )
    return out
