"""The live pipeline reports how long a stage's thread waited for a core (Linux schedstat): next to nothing when it
has a core, the time the other processes held its core when it has to share one."""

from __future__ import annotations

import multiprocessing as mp
import os
import sys
import threading
import time

import numpy as np
import pytest

from vtrack.live.pipeline import Consumer, LivePipeline, live_summary, thread_sched_ns
from vtrack.live.sources import QueueSource

pytestmark = pytest.mark.skipif(
    not sys.platform.startswith("linux") or thread_sched_ns() is None,
    reason="needs Linux's /proc/thread-self/schedstat",
)

SPIN_S = 0.03  # CPU per frame


class Spin(Consumer):
    """Burns SPIN_S of CPU per camera frame on CPU ``cpu`` (the worker thread pins itself there)."""

    name = "track"

    def __init__(self, cpu: int | None) -> None:
        self.cpu = cpu

    def process(self, ev) -> None:
        if self.cpu is not None:
            os.sched_setaffinity(0, {self.cpu})  # this thread only
        c0 = time.thread_time()
        while time.thread_time() - c0 < SPIN_S:
            pass


def _busy(cpu: int, started, stop) -> None:
    os.sched_setaffinity(0, {cpu})
    started.release()
    while not stop.is_set():
        pass


def _run(cpu: int | None) -> dict:
    src = QueueSource()
    cons = Spin(cpu)
    pipe = LivePipeline(src, [cons])

    def feed() -> None:
        for i in range(6):
            src.push("camera/cam0", i / 30, {"depth": np.zeros(2)})
            time.sleep(0.12)  # one frame at a time: nothing queued, nothing dropped
        src.close()

    threading.Thread(target=feed, daemon=True).start()
    return live_summary(pipe.run(), ["track"])


def test_run_queue_wait_is_the_time_another_process_held_the_core():
    cpu = sorted(os.sched_getaffinity(0))[0]
    alone = _run(None)
    assert alone["runq_ms_mean"] is not None and alone["runq_ms_mean"] >= 0.0
    ctx = mp.get_context("spawn")
    stop, started = ctx.Event(), ctx.Semaphore(0)
    hogs = [ctx.Process(target=_busy, args=(cpu, started, stop), daemon=True) for _ in range(2)]
    for h in hogs:
        h.start()
    try:
        for _ in hogs:  # both spin on that CPU before the stage runs (a spawned process takes ~1 s to start)
            assert started.acquire(timeout=60), "a busy process did not start"
        shared = _run(cpu)
    finally:
        stop.set()
        for h in hogs:
            h.join(5)
    # three runnable threads on one CPU: the stage's thread gets about a third of it, so it waits about twice
    # its 30 ms of CPU per frame (well above the idle case's)
    assert shared["runq_ms_mean"] > 0.8 * SPIN_S * 1e3, shared
    assert shared["runq_ms_mean"] > alone["runq_ms_mean"] + 0.5 * SPIN_S * 1e3, (alone, shared)
