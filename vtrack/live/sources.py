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
    ``wall`` is the wall-clock time (``time.perf_counter``) at which it was emitted. ``shared``: the fields
    of ``data`` that are views into a shared-memory ring (:mod:`vtrack.live.shared`; a replay with a reader
    process), by field: read them with :meth:`read` (checked against being overwritten) or hand the slot to
    another process."""

    stream: str
    t: float
    index: int
    data: dict[str, np.ndarray]
    wall: float = 0.0
    shared: dict[str, Any] | None = None

    def read(self, field: str, fn: Callable[[np.ndarray], Any] = np.array) -> Any:
        """``fn(data[field])`` (default: a copy); for a shared field checked afterwards, so that the result
        is this frame's (raises :class:`vtrack.live.shared.FrameOverwritten` if the slot was reused)."""
        if self.shared and field in self.shared:
            return self.shared[field].read(fn)
        return fn(self.data[field])


@dataclass
class SourceStats:
    emitted: dict[str, int] = field(default_factory=dict)
    skipped_late: dict[str, int] = field(default_factory=dict)
    seconds: float = 0.0
    max_lag_s: float = 0.0
    reader_cpu_s: float = 0.0  #: CPU s of a reader child process (a reader thread counts in this process)
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


#: bytes per block read: small frames are read several at a time (one zarr call per field per block:
#: the per-call overhead, ~1 ms, would otherwise dominate), large ones one by one (a big block read
#: would stall the emitter and make every other stream late)
BLOCK_BYTES = 1 << 20


#: block size of a reader process: it does not share the emitter's GIL, so larger blocks (fewer zarr calls, each
#: ~1 ms of overhead) cost no emitter latency; the prefetch queue covers a block's read
PROCESS_BLOCK_BYTES = 4 << 20


def _block_frames(stream: Any, fields: Sequence[str] | None = None, block_bytes: int | None = None) -> int:
    fs = [stream.fields[f] for f in (fields if fields is not None else stream.fields)]
    per = sum(int(np.prod(f.shape[1:], dtype=np.int64)) * f.dtype.itemsize for f in fs)
    return int(max(1, min(64, (block_bytes or BLOCK_BYTES) // max(per, 1))))


def _decode_loop(
    reader: Any,
    streams: list[str],
    items: list,
    put: Callable,
    wall0: Callable[[], float],
    cfg: tuple[float, float, float],
    stop: Any,
    fields: dict[str, list[str]] | None = None,
    block_bytes: int | None = None,
) -> None:
    """Decode frames in schedule order and ``put`` them; skip (put ``data=None``) frames already too
    late when reached. ``fields``: per stream, the fields to decode (default all); ``block_bytes``: bytes per
    block read (default :data:`BLOCK_BYTES`). Ends with ``put(None)``."""
    period, speed, max_lag_s = cfg
    cache: dict[str, tuple[int, dict[str, np.ndarray]]] = {}
    try:
        for item in items:
            if stop.is_set():
                break
            rep, rel, k, i = item
            name = streams[k]
            due = wall0() + (rel + rep * period) / speed
            if time.monotonic() - due > max_lag_s:
                put((item, None))
                continue
            i0, block = cache.get(name, (-1, {}))
            s = reader[name]
            if not (0 <= i - i0 < len(next(iter(block.values()), ()))):
                names = (fields or {}).get(name) or list(s.fields)
                B = _block_frames(s, names, block_bytes)
                i0 = i
                block = {f: s.fields[f][i : i + B] for f in names}
                cache[name] = (i0, block)
            put((item, {f: np.ascontiguousarray(v[i - i0]) for f, v in block.items()}))
    finally:
        put(None)


def _reader_process(
    path: str,
    streams: list[str],
    items: list,
    q: Any,
    stop: Any,
    wall0_v: Any,
    cfg: tuple[float, float, float],
    fields: dict[str, list[str]] | None = None,
    layout: Any = None,
) -> None:
    """Child-process reader: decoding runs outside the consumers' process (no GIL contention). Before its
    end marker it reports its CPU seconds since it was ready (``("__cpu__", s)``). With a ring ``layout``
    (:class:`vtrack.live.shared.RingLayout`) large fields are decoded into shared memory and only their
    slot's sequence number is sent (``(item, ("__ring__", seq, small fields))``)."""
    try:
        from vtrack.io.session import open_session
        from vtrack.threads import limit_threads

        limit_threads(1)  # decoding is one stream of work; a BLAS pool here would only spin beside the consumers
        reader = open_session(path)
        ring = None
        if layout is not None:
            from vtrack.live.shared import FrameRing

            ring = FrameRing(layout)  # mapped (its pages too) before the clock starts
    except Exception as e:
        q.put(f"{type(e).__name__}: {e}")
        return
    q.put("ready")
    block_bytes = PROCESS_BLOCK_BYTES
    c0 = time.process_time()
    while wall0_v.value == 0.0 and not stop.is_set():
        time.sleep(0.001)

    # the frames due at the same time (4 tactile images, a joint state, a camera frame) go through the queue as
    # one message: a fifth of the queue's pickling, pipe writes and wake-ups here and in the emitter
    last_of_group = {it for n, it in enumerate(items) if n + 1 == len(items) or items[n + 1][:2] != it[:2]}
    group: list = []

    def put(x: Any) -> None:
        if x is None:
            if group:
                q.put(list(group))
            q.put(("__cpu__", time.process_time() - c0))
            q.put(None)
            return
        if ring is not None and x[1] is not None and streams[x[0][2]] in layout.fields:
            seq, rest = ring.write(streams[x[0][2]], x[1])
            x = (x[0], ("__ring__", seq, rest))
        group.append(x)
        if x[0] in last_of_group:
            q.put(list(group))
            group.clear()

    _decode_loop(reader, streams, items, put, lambda: wall0_v.value, cfg, stop, fields, block_bytes)


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
        reader: ``thread`` (decode in a thread) or ``process`` (decode in a child process: no GIL
            contention with heavy consumers; costs a process start and a copy per frame).
        fields: per stream, the fields to decode and emit (default: all; e.g. a tracker needs a camera's
            ``depth`` only, and decoding the unused 640x480 colour image doubled the replay's cost).
        transport: how a reader process hands frames over: ``shm`` (large fields are decoded into a
            shared-memory ring, :mod:`vtrack.live.shared`; events carry views and ``shared`` slots that a
            consumer can pass on to its own helper process) or ``pipe`` (pickled through a queue).
    """

    def __init__(
        self,
        session: Any,
        streams: Sequence[str] | None = None,
        speed: float = 1.0,
        max_lag_s: float = 0.05,
        seconds: float | None = None,
        loop: int = 1,
        prefetch: int = 64,
        reader: str = "thread",
        fields: dict[str, Sequence[str]] | None = None,
        transport: str = "shm",
    ) -> None:
        from vtrack.io.session import SessionReader, open_session

        self.reader = session if isinstance(session, SessionReader) else open_session(Path(session))
        names = (
            list(streams)
            if streams
            else [k for k in self.reader.streams if k.startswith(("camera/", "tactile/")) or k == "joints"]
        )
        for n in names:
            if n not in self.reader:
                raise InputError(
                    "no such stream in the session",
                    path=self.reader.path,
                    field=n,
                    expected=str(sorted(self.reader.streams)),
                )
        names = [n for n in names if self.reader[n].n > 0]
        if not names:
            raise InputError("nothing to replay (no non-empty camera/tactile/joints stream)", path=self.reader.path)
        if speed <= 0 or not np.isfinite(speed):
            raise InputError("speed must be > 0", field="speed", got=speed)
        self.streams = names
        self.fields: dict[str, list[str]] = {}
        for n, fs in (fields or {}).items():
            if n not in names or fs is None:
                continue
            bad = [f for f in fs if f not in self.reader[n].fields]
            if bad:
                raise InputError(
                    "no such field in the stream", path=self.reader.path, field=f"{n}/{bad[0]}",
                    expected=str(sorted(self.reader[n].fields)),
                )  # fmt: skip
            self.fields[n] = list(fs)
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
        # at equal times the camera frame comes last: its step then sees the joint state (and, when the touch stage
        # is quick enough, the contacts) of its own time, as offline tracking does, not those one period older
        cam_last = np.array([n.startswith("camera/") for n in names])[one[:, 1].astype(int)]
        one = one[np.lexsort((one[:, 1], cam_last, one[:, 0]))]
        self.period = float(one[-1, 0]) + 1e-3 if len(one) else 0.0
        self.schedule = one
        self.loop = max(1, int(loop))
        self.prefetch = max(1, int(prefetch))
        self.preroll_s = 0.25
        if reader not in ("thread", "process"):
            raise InputError("unknown replay reader", field="reader", expected="thread|process", got=reader)
        self.reader_kind = reader
        if transport not in ("shm", "pipe"):
            raise InputError("unknown replay transport", field="transport", expected="shm|pipe", got=transport)
        self.transport = transport
        self.ring: Any = None  # the shared-memory ring of the running replay (reader process + shm)
        self.stats = SourceStats()
        self._stop = threading.Event()

    def close(self) -> None:
        """Remove the shared-memory ring of the last run (after its consumers are done with its frames;
        :class:`vtrack.live.pipeline.LivePipeline` calls it after joining its workers; else it goes when the
        source is garbage-collected or at exit)."""
        if self.ring is not None:
            self.ring.close()
            self.ring = None

    @property
    def duration(self) -> float:
        return self.period * self.loop / self.speed

    def stop(self) -> None:
        self._stop.set()

    def run(self, emit: Callable[[FrameEvent], None]) -> SourceStats:
        """Replay (blocking) until done or :meth:`stop`.

        A reader (thread, or a child process with ``reader="process"``) decodes frames ahead of
        their due time (block reads, bounded queue of ``prefetch`` frames); this thread emits each
        frame when due. A frame late by more than ``max_lag_s`` is skipped (not even decoded if it is
        already late when the reader reaches it) and counted in ``skipped_late``.
        """
        import queue

        st = self.stats
        items = [(rep, float(rel), int(k), int(i)) for rep in range(self.loop) for rel, k, i in self.schedule]
        cfg = (self.period, self.speed, self.max_lag_s)
        proc = None
        if self.reader_kind == "process":
            import multiprocessing as mp

            ctx = mp.get_context("spawn")  # no fork: the parent has threads (zarr's event loop)
            layout = None
            if self.transport == "shm":
                from vtrack.live.shared import FrameRing, ring_shapes

                shapes = ring_shapes(self.reader, self.streams, self.fields)
                if shapes:
                    # a slot is reused `slots` frames of its stream later: the reader runs at most `prefetch`
                    # frames ahead of the emitter, so a consumer has >= 64 of the stream's frame periods
                    # (~1 s at 60 Hz) to read an emitted frame
                    try:
                        self.ring = FrameRing.create(shapes, self.prefetch + 64)
                        layout = self.ring.layout
                    except OSError as e:  # no room for the ring: frames go pickled through the queue
                        import warnings

                        warnings.warn(f"live replay: {e}; falling back to the pipe transport", stacklevel=2)
            q: Any = ctx.Queue(maxsize=self.prefetch)
            stop_evt: Any = ctx.Event()
            wall0_v = ctx.Value("d", 0.0)
            proc = ctx.Process(
                target=_reader_process,
                args=(str(self.reader.path), self.streams, items, q, stop_evt, wall0_v, cfg, self.fields, layout),
                daemon=True,
                name="replay-read",
            )
            proc.start()
            first = q.get(timeout=120)
            if first != "ready":
                raise InputError(f"replay reader process failed: {first}", path=self.reader.path)
            wall0 = time.monotonic() + self.preroll_s
            wall0_v.value = wall0
        else:
            q = queue.Queue(maxsize=self.prefetch)
            stop_evt = self._stop
            wall0 = time.monotonic() + self.preroll_s  # pre-roll: let the reader get ahead
            th = threading.Thread(
                target=_decode_loop,
                daemon=True,
                name="replay-read",
                args=(self.reader, self.streams, items, q.put, lambda: wall0, cfg, stop_evt, self.fields),
            )
            th.start()
        try:
            while True:
                got = q.get()
                if got is None:
                    break
                if isinstance(got, str):  # error text from the reader process
                    raise InputError(f"replay reader failed: {got}", path=self.reader.path)
                if got[0] == "__cpu__":  # the reader process's CPU time, sent just before its end marker
                    st.reader_cpu_s = float(got[1])
                    continue
                for (rep, rel, k, i), data in got if isinstance(got, list) else [got]:  # a group of equal time
                    name = self.streams[k]
                    shared = None
                    if isinstance(data, tuple):  # ("__ring__", seq, small fields): large fields in the ring
                        shared = self.ring.slots(name, data[1])
                        data = {**data[2], **{f: v.view() for f, v in shared.items()}}
                    due = wall0 + (rel + rep * self.period) / self.speed
                    now = time.monotonic()
                    if data is not None and due > now:
                        time.sleep(due - now)
                        now = time.monotonic()
                    lag = now - due
                    if data is None or lag > self.max_lag_s:
                        st.skipped_late[name] = st.skipped_late.get(name, 0) + 1
                        continue
                    st.max_lag_s = max(st.max_lag_s, lag)
                    t = float(self.reader[name].t[i]) + rep * self.period
                    wall = time.perf_counter()
                    emit(FrameEvent(name, t, i, data, wall, shared))
                    st.emitted[name] = st.emitted.get(name, 0) + 1
                    if st.first_wall is None:
                        st.first_wall = wall
                    st.last_wall = wall
                    if self._stop.is_set():
                        break
                if self._stop.is_set():
                    break
        finally:
            self._stop.set()
            stop_evt.set()
            deadline = time.monotonic() + 5.0
            alive = (lambda: proc.is_alive()) if proc is not None else (lambda: th.is_alive())
            while alive() and time.monotonic() < deadline:  # unblock a reader waiting on a full queue
                try:
                    q.get(timeout=0.01)
                except Exception:
                    pass
            if proc is not None:
                if proc.is_alive():
                    proc.kill()
                proc.join(1.0)

        st.seconds = time.monotonic() - wall0 + self.preroll_s
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
