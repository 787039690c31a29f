"""Run consumers on a live stream, dropping frames rather than falling behind.

Each consumer has a worker thread and a *mailbox* with one slot per stream: a new frame replaces
an unprocessed one of the same stream (counted as dropped), so a slow consumer always works on the
newest data and its latency stays bounded by one processing step, whatever the input rate.
The worker takes the pending frame with the oldest timestamp first (so joints that precede a
camera frame are applied before it).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vtrack.live.sources import FrameEvent


class Consumer:
    """Base class: ``wants(stream)`` selects streams; ``process(event)`` handles one frame;
    ``finish()`` returns a JSON-able result dict."""

    name = "consumer"

    def wants(self, stream: str) -> bool:
        return True

    def process(self, event: FrameEvent) -> None:
        raise NotImplementedError

    def finish(self) -> dict[str, Any]:
        return {}


@dataclass
class ConsumerStats:
    received: dict[str, int] = field(default_factory=dict)
    processed: dict[str, int] = field(default_factory=dict)
    dropped: dict[str, int] = field(default_factory=dict)
    latency_ms: list[float] = field(default_factory=list)
    busy_s: float = 0.0
    errors: int = 0

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


class _Worker(threading.Thread):
    def __init__(self, consumer: Consumer) -> None:
        super().__init__(daemon=True, name=f"live-{consumer.name}")
        self.consumer = consumer
        self.slots: dict[str, FrameEvent] = {}
        self.cv = threading.Condition()
        self.closed = False
        self.stats = ConsumerStats()
        self.error: BaseException | None = None

    def put(self, ev: FrameEvent) -> None:
        with self.cv:
            st = self.stats
            st.received[ev.stream] = st.received.get(ev.stream, 0) + 1
            if ev.stream in self.slots:
                st.dropped[ev.stream] = st.dropped.get(ev.stream, 0) + 1
            self.slots[ev.stream] = ev
            self.cv.notify()

    def close(self) -> None:
        with self.cv:
            self.closed = True
            self.cv.notify()

    def run(self) -> None:
        while True:
            with self.cv:
                while not self.slots and not self.closed:
                    self.cv.wait(0.1)
                if not self.slots and self.closed:
                    return
                key = min(self.slots, key=lambda k: self.slots[k].t)
                ev = self.slots.pop(key)
            t0 = time.perf_counter()
            try:
                self.consumer.process(ev)
            except Exception as e:  # keep the pipeline alive; the first error is reported
                self.stats.errors += 1
                if self.error is None:
                    self.error = e
            t1 = time.perf_counter()
            self.stats.busy_s += t1 - t0
            self.stats.latency_ms.append((t1 - ev.wall) * 1e3)
            self.stats.processed[ev.stream] = self.stats.processed.get(ev.stream, 0) + 1


class LivePipeline:
    """Connect a source to consumers and run until the source ends (or :meth:`stop`)."""

    def __init__(self, source: Any, consumers: list[Consumer], switch_interval_s: float = 0.001) -> None:
        self.source = source
        self.switch_interval_s = switch_interval_s
        self.workers = [_Worker(c) for c in consumers]

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
        t0 = time.perf_counter()
        try:
            src_stats = self.source.run(self._emit)
        except KeyboardInterrupt:
            self.source.stop()
            src_stats = self.source.stats
        finally:
            sys.setswitchinterval(old_switch)
        t_src = time.perf_counter() - t0
        for w in self.workers:
            w.close()
        for w in self.workers:
            w.join()
        wall = time.perf_counter() - t0
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
        return out
