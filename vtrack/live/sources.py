"""Live frame sources.

A source runs in its own thread and calls ``emit(event)`` for each frame, in time order, at the
pace of its clock. :class:`SessionReplaySource` replays a recorded session at real-time rate (or
``speed`` x); when it runs late by more than ``max_lag_s`` it skips frames (without reading them)
instead of drifting behind the wall clock.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError


@dataclass
class FrameEvent:
    """One frame of one stream: ``data`` holds the stream's fields; ``t`` is the stream time (s);
    ``wall`` is the wall-clock time (``time.perf_counter``) at which it was emitted."""

    stream: str
    t: float
    index: int
    data: dict[str, np.ndarray]
    wall: float = 0.0


@dataclass
class SourceStats:
    emitted: dict[str, int] = field(default_factory=dict)
    skipped_late: dict[str, int] = field(default_factory=dict)
    seconds: float = 0.0
    max_lag_s: float = 0.0
    first_wall: float | None = None
    last_wall: float | None = None

    @property
    def active_s(self) -> float:
        """Wall time from the first to the last emitted frame, s."""
        if self.first_wall is None or self.last_wall is None:
            return 0.0
        return self.last_wall - self.first_wall

    def rates_hz(self) -> dict[str, float]:
        """Emitted frames per second of active replay, per stream."""
        span = self.active_s
        return {k: round((v - 1) / span, 2) if span > 0 and v > 1 else 0.0 for k, v in self.emitted.items()}


class SessionReplaySource:
    """Replay a session's streams at real-time rate.

    Args:
        session: session directory or an open ``SessionReader``.
        streams: stream names to replay (default: cameras, tactile, joints).
        speed: playback speed (1 = real time).
        max_lag_s: frames due more than this long ago are skipped (source-side dropping).
        seconds: replay only the first seconds.
        loop: number of passes over the session (for longer runs of short sessions).
        prefetch: max frames decoded ahead of their due time.
    """

    def __init__(self, session: Any, streams: Sequence[str] | None = None, speed: float = 1.0,
                 max_lag_s: float = 0.05, seconds: float | None = None, loop: int = 1, prefetch: int = 64) -> None:
        from vtrack.io.session import SessionReader, open_session

        self.reader = session if isinstance(session, SessionReader) else open_session(Path(session))
        names = list(streams) if streams else [k for k in self.reader.streams
                                              if k.startswith(("camera/", "tactile/")) or k == "joints"]
        for n in names:
            if n not in self.reader:
                raise InputError("no such stream in the session", path=self.reader.path, field=n,
                                 expected=str(sorted(self.reader.streams)))
        names = [n for n in names if self.reader[n].n > 0]
        if not names:
            raise InputError("nothing to replay (no non-empty camera/tactile/joints stream)", path=self.reader.path)
        if speed <= 0 or not np.isfinite(speed):
            raise InputError("speed must be > 0", field="speed", got=speed)
        self.streams = names
        self.speed = float(speed)
        self.max_lag_s = float(max_lag_s)
        t0 = min(self.reader[n].t[0] for n in names)
        sched = []
        for k, n in enumerate(names):
            t = self.reader[n].t
            if seconds is not None:
                t = t[t <= t0 + seconds]
            sched.append(np.stack([t - t0, np.full(len(t), k), np.arange(len(t))], 1))
        one = np.concatenate(sched)
        one = one[np.lexsort((one[:, 1], one[:, 0]))]
        self.period = float(one[-1, 0]) + 1e-3 if len(one) else 0.0
        self.schedule = one
        self.loop = max(1, int(loop))
        self.prefetch = max(1, int(prefetch))
        self.preroll_s = 0.25
        self.stats = SourceStats()
        self._stop = threading.Event()

    @property
    def duration(self) -> float:
        return self.period * self.loop / self.speed

    def stop(self) -> None:
        self._stop.set()

    #: frames per block read, by stream kind (one zarr call per field per block: the per-call
    #: overhead, ~1 ms, would otherwise dominate small frames)
    BLOCK = {"camera": 2, "tactile": 8, "other": 64}

    def _reader_loop(self, items: list, out: Any, wall0: float) -> None:
        """Decode frames in schedule order into ``out`` (bounded queue); skip ones already too late."""
        cache: dict[str, tuple[int, dict[str, np.ndarray]]] = {}
        try:
            for item in items:
                if self._stop.is_set():
                    break
                rep, rel, k, i = item
                name = self.streams[k]
                due = wall0 + (rel + rep * self.period) / self.speed
                if time.perf_counter() - due > self.max_lag_s:
                    out.put((item, None))  # late before it was even read: skip without decoding
                    continue
                i0, block = cache.get(name, (-1, {}))
                s = self.reader[name]
                if not (0 <= i - i0 < len(next(iter(block.values()), ()))):
                    B = self.BLOCK.get(name.split("/", 1)[0], self.BLOCK["other"])
                    i0 = i
                    block = {f: s.fields[f][i:i + B] for f in s.fields}
                    cache[name] = (i0, block)
                out.put((item, {f: v[i - i0] for f, v in block.items()}))
        finally:
            out.put(None)

    def run(self, emit: Callable[[FrameEvent], None]) -> SourceStats:
        """Replay (blocking) until done or :meth:`stop`.

        A reader thread decodes frames ahead of their due time (block reads, bounded queue of
        ``prefetch`` frames); this thread emits each frame when due. A frame that is late by more
        than ``max_lag_s`` is skipped (not decoded if it is already late when its turn to be read
        comes) and counted in ``skipped_late``.
        """
        import queue

        st = self.stats
        # Pre-roll: the clock starts a little later so the reader has frames decoded in advance.
        wall0 = time.perf_counter() + self.preroll_s
        items = [(rep, float(rel), int(k), int(i)) for rep in range(self.loop) for rel, k, i in self.schedule]
        q: queue.Queue = queue.Queue(maxsize=self.prefetch)
        th = threading.Thread(target=self._reader_loop, args=(items, q, wall0), daemon=True, name="replay-read")
        th.start()
        try:
            while True:
                got = q.get()
                if got is None:
                    break
                (rep, rel, k, i), data = got
                name = self.streams[k]
                due = wall0 + (rel + rep * self.period) / self.speed
                now = time.perf_counter()
                if data is not None and due > now:
                    time.sleep(due - now)
                    now = time.perf_counter()
                lag = now - due
                if data is None or lag > self.max_lag_s:
                    st.skipped_late[name] = st.skipped_late.get(name, 0) + 1
                    continue
                st.max_lag_s = max(st.max_lag_s, lag)
                t = float(self.reader[name].t[i]) + rep * self.period
                emit(FrameEvent(name, t, i, data, now))
                st.emitted[name] = st.emitted.get(name, 0) + 1
                if st.first_wall is None:
                    st.first_wall = now
                st.last_wall = now
                if self._stop.is_set():
                    break
        finally:
            self._stop.set()
            while th.is_alive():  # unblock the reader if it waits on a full queue
                try:
                    q.get_nowait()
                except queue.Empty:
                    time.sleep(0.001)
        st.seconds = time.perf_counter() - wall0
        return st

    def start(self, emit: Callable[[FrameEvent], None]) -> threading.Thread:
        th = threading.Thread(target=self.run, args=(emit,), daemon=True, name="replay-source")
        th.start()
        return th


class QueueSource:
    """Frames pushed by a running recorder (``push`` from its ``on_frame`` hook), emitted as they
    arrive; the recorder is the clock. A full queue drops the new frame (counted in
    ``skipped_late``) so that the recorder is never slowed down by its live consumers.
    ``close()`` ends the stream after the queued frames."""

    def __init__(self, maxsize: int = 64) -> None:
        import queue

        self.q: queue.Queue = queue.Queue(maxsize=maxsize)
        self.stats = SourceStats()
        self._stop = threading.Event()

    def push(self, stream: str, t: float, data: dict[str, np.ndarray]) -> None:
        import queue

        try:
            self.q.put_nowait(FrameEvent(stream, float(t), -1, data, time.perf_counter()))
        except queue.Full:
            self.stats.skipped_late[stream] = self.stats.skipped_late.get(stream, 0) + 1

    def close(self) -> None:
        self.q.put(None)

    def stop(self) -> None:
        self._stop.set()
        self.close()

    def run(self, emit: Callable[[FrameEvent], None]) -> SourceStats:
        st = self.stats
        wall0 = time.perf_counter()
        while True:
            ev = self.q.get()
            if ev is None or self._stop.is_set():
                break
            ev.wall = time.perf_counter()
            emit(ev)
            st.emitted[ev.stream] = st.emitted.get(ev.stream, 0) + 1
            if st.first_wall is None:
                st.first_wall = ev.wall
            st.last_wall = ev.wall
        st.seconds = time.perf_counter() - wall0
        return st
