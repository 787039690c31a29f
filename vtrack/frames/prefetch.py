"""Frames of a session built in a child process, ahead of the tracker (offline, 2 cores).

Building a frame (disk read, segmentation, the four tactile pipelines, colour feature tracks) does not depend on
the tracker: it is a function of the recording alone. So offline, a child process builds frames ``0..n-1`` in
order and hands them over through a bounded queue while the parent tracks the previous ones; on two cores the
wall time per frame drops from ``build + track`` to about ``max(build, track)``. The frames are the same as the
parent's own :meth:`~vtrack.frames.session.SessionFrames.build` would give: the child's
:class:`~vtrack.frames.session.SessionFrames` is made with the same arguments and starts from its first frame, as a
freshly made (or :meth:`~vtrack.frames.session.SessionFrames.reset`) one does
(``tests/frames/test_prefetch.py`` checks identical tracker poses).

The child is spawned (not forked: the parent may already run threads, e.g. zarr's event loop) and capped at one
thread. Its start (imports, opening the session) costs ~1-3 s, so it pays only on sessions of more than a few
seconds (:func:`worth_prefetching`).
"""

from __future__ import annotations

import time
import weakref
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from vtrack.errors import InputError

#: frames the child may build ahead of the parent (bounds memory: a frame is ~0.1-0.5 MB)
QUEUE_FRAMES = 8

#: fewest frames for which the child process pays for its start (``auto``): ~1-3 s of start against ~20 ms
#: saved per frame on 2 cores (docs/benchmarks/prefetch_frames.md)
MIN_FRAMES = 120

#: seconds the parent waits for the child's first message (imports and opening the session) or a next frame
START_TIMEOUT_S = 180.0


#: the frame prefetch modes (``track_session(prefetch=...)``, ``--prefetch``)
PREFETCH_MODES = ("auto", "on", "off")


def check_prefetch_mode(mode: str, field: str = "prefetch") -> str:
    """``mode`` if it is one of :data:`PREFETCH_MODES`, else an InputError naming ``field`` (``--prefetch`` on the
    command line)."""
    if mode not in PREFETCH_MODES:
        raise InputError("unknown frame prefetch mode", field=field, expected=" | ".join(PREFETCH_MODES), got=mode)
    return mode


def worth_prefetching(mode: str | bool, n_frames: int | None) -> bool:
    """Whether to build frames in a child process: ``mode`` ``on`` / ``off`` / ``auto`` (or a bool); ``auto`` = at
    least :data:`MIN_FRAMES` frames (``n_frames``; None: not known yet), at least 2 CPUs available, and this process
    not capped at one thread (``vtrack --threads 1``, :func:`vtrack.threads.limit_threads`: a single-core figure)."""
    if isinstance(mode, bool):
        return mode
    if check_prefetch_mode(mode) != "auto":
        return mode == "on"
    from vtrack.threads import available_cpus, thread_limit

    single = thread_limit() == 1
    return (n_frames is None or n_frames >= MIN_FRAMES) and available_cpus() >= 2 and not single


def _timed_read(sf: Any, i: int) -> tuple[dict, float]:
    c0 = time.thread_time()
    raw = sf.read(i)
    return raw, (time.thread_time() - c0) * 1e3


def _skip_open3d_plotly() -> None:
    """In this process only (the frame builder, which draws nothing): let ``import open3d`` skip its Plotly/Dash
    viewer, which it imports unconditionally (0.5-0.6 s of the child's ~2.4 s start, measured). A stand-in module
    takes its place; calling it says why it is missing."""
    import sys
    import types

    name = "open3d.visualization.draw_plotly"
    if name in sys.modules or "open3d" in sys.modules:
        return

    def _missing(*_: Any, **__: Any) -> None:
        raise RuntimeError("open3d's Plotly viewer is not loaded in vtrack's frame-builder process")

    stub = types.ModuleType(name)
    stub.get_plotly_fig = stub.draw_plotly = stub.draw_plotly_server = _missing  # type: ignore[attr-defined]
    sys.modules[name] = stub


def _build_frames(session: str, kwargs: dict, n: int, queue: Any) -> None:
    """Child process: ``SessionFrames(session, **kwargs)``, then frames ``0..n-1`` into ``queue`` as
    ``("frame", i, Frame, read_cpu_ms, build_cpu_ms)``; ``("done", cpu_s)`` at the end; ``("error", kind, message)``
    on any exception (the parent re-raises it)."""
    try:
        from vtrack.threads import limit_threads

        limit_threads(1)  # one stream of work: a BLAS pool would only spin beside the parent's tracker
        _skip_open3d_plotly()
        from vtrack.frames.session import SessionFrames

        sf = SessionFrames(session, **kwargs)
        n = min(n, len(sf)) if n > 0 else len(sf)
        queue.put(("ready", n))  # the number of frames it will build
        c_start = time.process_time()
        with ThreadPoolExecutor(1) as reader:
            # frame i + 1 is read (disk, decompression: mostly outside the GIL) while frame i is built
            nxt = reader.submit(_timed_read, sf, 0) if n else None
            for i in range(n):
                raw, read_ms = nxt.result()
                nxt = reader.submit(_timed_read, sf, i + 1) if i + 1 < n else None
                c1 = time.thread_time()
                fr = sf.build(raw)
                queue.put(("frame", i, fr, read_ms, (time.thread_time() - c1) * 1e3))
        queue.put(("done", time.process_time() - c_start))
    except Exception as e:  # noqa: BLE001 - every failure goes to the parent as one line
        from vtrack.io.session import CorruptDataError

        kind = "corrupt" if isinstance(e, CorruptDataError) else "input" if isinstance(e, InputError) else "other"
        queue.put(("error", kind, f"{type(e).__name__}: {e}" if kind == "other" else str(e)))


def _kill(proc: Any) -> None:
    if proc.is_alive():
        proc.kill()


class PrefetchedFrames:
    """``(i, Frame, read_cpu_ms, build_cpu_ms)`` for ``i = 0..n-1`` of a session (:meth:`frames`), built in a child
    process that starts at once (so its start overlaps the caller's own set-up).

    Args:
        session: session directory.
        frames_kwargs: the keyword arguments of the parent's :class:`~vtrack.frames.session.SessionFrames` (picklable).
        n: frames to build (the first ``n``; 0 = all, as many as ``SessionFrames(session, **frames_kwargs)`` has).
        queue_frames: frames the child may build ahead.

    ``cpu_s`` (after the iteration ends) is the child's CPU time over the frames. Use as a context manager (or call
    :meth:`close`): leaving early ends the child.
    """

    def __init__(self, session: str | Path, frames_kwargs: dict, n: int = 0, queue_frames: int = QUEUE_FRAMES) -> None:
        import multiprocessing as mp

        ctx = mp.get_context("spawn")
        self.session = str(session)
        self.cpu_s = 0.0
        self._q = ctx.Queue(maxsize=max(1, int(queue_frames)))
        self._proc = ctx.Process(
            target=_build_frames,
            args=(self.session, dict(frames_kwargs), int(n), self._q),
            daemon=True,
            name="vtrack-frames",
        )
        self._proc.start()
        # an exception between here and the iteration (the caller's initialisation) must not leave the child
        # blocked on a full queue for the rest of the process: it is killed when this object goes
        self._finalizer = weakref.finalize(self, _kill, self._proc)

    def _get(self) -> tuple:
        import queue

        deadline = time.monotonic() + START_TIMEOUT_S
        while True:
            try:
                msg = self._q.get(timeout=1.0)
                break
            except queue.Empty:
                if not self._proc.is_alive():
                    raise RuntimeError(
                        f"frame builder process for {self.session} ended unexpectedly (exit code {self._proc.exitcode})"
                    ) from None
                if time.monotonic() > deadline:
                    raise RuntimeError(
                        f"frame builder process for {self.session}: no frame in {START_TIMEOUT_S:.0f} s"
                    ) from None
        if msg[0] == "error":
            self.close()
            _, kind, text = msg
            if kind == "corrupt":
                from vtrack.io.session import CorruptDataError

                raise CorruptDataError(text)
            if kind == "input":
                raise InputError(text)
            raise RuntimeError(f"frame builder process: {text}")
        return msg

    def frames(self, expected: int | None = None) -> Iterator[tuple[int, Any, float, float]]:
        """The built frames in order (see the class); ``expected``: the number of frames the caller's own
        :class:`~vtrack.frames.session.SessionFrames` has (the child's must agree: a RuntimeError otherwise)."""
        try:
            _, n_child = self._get()
            if expected is not None and n_child != expected:
                raise RuntimeError(f"frame builder process for {self.session}: {n_child} frames, expected {expected}")
            while True:
                msg = self._get()
                if msg[0] == "done":
                    self.cpu_s = float(msg[1])
                    return
                _, i, fr, read_ms, build_ms = msg
                yield i, fr, read_ms, build_ms
        finally:
            self.close()

    def close(self) -> None:
        """End the child (waits briefly, then kills it)."""
        if self._proc.is_alive():
            self._proc.join(0.5 if self.cpu_s else 0.0)
            if self._proc.is_alive():
                self._proc.kill()
                self._proc.join(2.0)
        self._q.close()
        self._q.cancel_join_thread()  # frames left in the queue are not wanted: do not block on them

    def __enter__(self) -> PrefetchedFrames:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
