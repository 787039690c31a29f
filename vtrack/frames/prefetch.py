"""Frames of a session built in a child process, ahead of the tracker (offline, 2 cores).

Building a frame (disk read, segmentation, the four tactile pipelines, colour feature tracks) does not depend on
the tracker: it is a function of the recording alone. So offline, a child process builds frames ``0..n-1`` in
order and hands them over through a bounded queue while the parent tracks the previous ones; on two cores the
wall time per frame drops from ``build + track`` to about ``max(build, track)``. The frames are the same as the
parent's own :meth:`~vtrack.frames.session.SessionFrames.build` would give: the child's
:class:`~vtrack.frames.session.SessionFrames` is made with the same arguments and starts from its first frame, as a
freshly made (or :meth:`~vtrack.frames.session.SessionFrames.reset`) one does
(``tests/frames/test_prefetch.py`` checks identical tracker poses). With vision and touch, a second child computes
the tactile contacts and hands them to the frame builder (:class:`PrefetchedFrames`, ``touch_process``).

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


#: the frame prefetch modes (``track_session(prefetch=...)``, ``--prefetch``): ``single`` = on, with the tactile
#: pipelines in the frame builder's process (no touch process: the layout before 2026-11-28, an ablation)
PREFETCH_MODES = ("auto", "on", "off", "single")


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
        return mode in ("on", "single")
    from vtrack.threads import available_cpus, thread_limit

    single = thread_limit() == 1
    return (n_frames is None or n_frames >= MIN_FRAMES) and available_cpus() >= 2 and not single


def _timed_read(sf: Any, i: int, touch: bool = True) -> tuple[dict, float]:
    c0 = time.thread_time()
    raw = sf.read(i, touch=touch)
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


def _error_message(e: Exception) -> tuple[str, str, str]:
    """``("error", kind, message)`` for the parent to re-raise (kind: ``corrupt`` / ``input`` / ``other``)."""
    from vtrack.io.session import CorruptDataError

    kind = "corrupt" if isinstance(e, CorruptDataError) else "input" if isinstance(e, InputError) else "other"
    return ("error", kind, f"{type(e).__name__}: {e}" if kind == "other" else str(e))


def _child_setup() -> None:
    from vtrack.threads import limit_threads

    limit_threads(1)  # one stream of work: a BLAS pool would only spin beside the other processes
    _skip_open3d_plotly()


class _TouchFailed(Exception):
    """The touch process's ``("error", kind, message)``, for the frame builder to hand on as it is."""

    def __init__(self, msg: tuple) -> None:
        super().__init__(msg[2])
        self.msg = msg


def _get_touch(touch_q: Any, expect: str, timeout_s: float = START_TIMEOUT_S) -> tuple:
    """The touch process's next message, of kind ``expect`` (the frame builder's side): :class:`_TouchFailed` when
    it sent an error, a RuntimeError when none comes in time or it is of another kind."""
    import queue

    try:
        msg = touch_q.get(timeout=timeout_s)
    except queue.Empty:
        raise RuntimeError(f"touch process: no contacts in {timeout_s:.0f} s") from None
    if msg[0] == "error":
        raise _TouchFailed(msg)
    if msg[0] != expect:
        raise RuntimeError(f"touch process sent {msg[0]!r}, expected {expect!r}")
    return msg


def _touch_contacts(session: str, kwargs: dict, n: int, touch_q: Any) -> None:
    """Touch child process: a touch-only ``SessionFrames`` (the same frame times and sensor poses as the builder's:
    the cameras set the times either way), then per frame ``0..n-1`` its contacts into ``touch_q`` as
    ``("contacts", i, [(sensor, Contact)], read_cpu_ms, cpu_ms)``; ``("done", cpu_s)`` at the end; ``("error", kind,
    message)`` on any exception (the builder hands it on)."""
    try:
        _child_setup()
        from vtrack.frames.session import SessionFrames

        sf = SessionFrames(session, **{**kwargs, "modalities": ("touch",), "colour": False})
        n = min(n, len(sf)) if n > 0 else len(sf)
        c_start = time.process_time()
        for i in range(n):
            c0 = time.process_time()
            raw = sf.read_touch(i)
            c1 = time.process_time()
            got = sf.touch_contacts(raw, sf.frame_sensor_poses(i))
            touch_q.put(("contacts", i, got, (c1 - c0) * 1e3, (time.process_time() - c1) * 1e3))
        touch_q.put(("done", time.process_time() - c_start))
    except Exception as e:  # noqa: BLE001 - every failure goes on as one line
        touch_q.put(_error_message(e))


def _build_frames(session: str, kwargs: dict, n: int, queue: Any, touch_q: Any = None) -> None:
    """Child process: ``SessionFrames(session, **kwargs)``, then frames ``0..n-1`` into ``queue`` as
    ``("frame", i, Frame, read_cpu_ms, build_cpu_ms)``; ``("done", cpu_s)`` at the end; ``("error", kind, message)``
    on any exception (the parent re-raises it). With ``touch_q`` the contacts of each frame come from the touch
    process (:func:`_touch_contacts`; its read and CPU time are added to the frame's, its CPU to ``cpu_s``)."""
    try:
        _child_setup()
        from vtrack.frames.session import SessionFrames

        sf = SessionFrames(session, **kwargs)
        n = min(n, len(sf)) if n > 0 else len(sf)
        queue.put(("ready", n))  # the number of frames it will build
        c_start = time.process_time()
        touch = touch_q is None
        with ThreadPoolExecutor(1) as reader:
            # frame i + 1 is read (disk, decompression: mostly outside the GIL) while frame i is built
            nxt = reader.submit(_timed_read, sf, 0, touch) if n else None
            for i in range(n):
                raw, read_ms = nxt.result()
                nxt = reader.submit(_timed_read, sf, i + 1, touch) if i + 1 < n else None
                touch_ms = 0.0
                if touch_q is not None:
                    _, j, raw["touch"], touch_read_ms, touch_ms = _get_touch(touch_q, "contacts")
                    if j != i:
                        raise RuntimeError(f"touch process sent frame {j}, expected {i}")
                    read_ms += touch_read_ms
                c1 = time.thread_time()
                fr = sf.build(raw)
                queue.put(("frame", i, fr, read_ms, (time.thread_time() - c1) * 1e3 + touch_ms))
        cpu_s = time.process_time() - c_start
        if touch_q is not None:
            cpu_s += float(_get_touch(touch_q, "done")[1])
        queue.put(("done", cpu_s))
    except _TouchFailed as e:  # the touch process's own message (its kind and text)
        queue.put(e.msg)
    except Exception as e:  # noqa: BLE001 - every failure goes to the parent as one line
        queue.put(_error_message(e))


def _kill(procs: list) -> None:
    for proc in procs:
        if proc.is_alive():
            proc.kill()


def touch_apart(frames_kwargs: dict) -> bool:
    """Whether the frames of ``SessionFrames(**frames_kwargs)`` have a touch stage worth a process of its own: both
    modalities (touch alone: the touch stage is all the building there is)."""
    mods = tuple(frames_kwargs.get("modalities", ("vision", "touch")))
    return "touch" in mods and "vision" in mods


class PrefetchedFrames:
    """``(i, Frame, read_cpu_ms, build_cpu_ms)`` for ``i = 0..n-1`` of a session (:meth:`frames`), built in a child
    process that starts at once (so its start overlaps the caller's own set-up).

    With ``touch_process`` (and both modalities, :func:`touch_apart`) a second child reads the tactile images and runs
    the tactile pipelines, frame by frame in order (their state carries over as in one process), and hands each
    frame's contacts to the frame builder, which then reads and segments the camera images only: three streams of
    work (touch, frame building, tracking) on two cores instead of two, whose longer one, the frame builder, set the
    pace (docs/benchmarks/prefetch_touch_process.md). The frames are the same.

    Args:
        session: session directory.
        frames_kwargs: the keyword arguments of the parent's :class:`~vtrack.frames.session.SessionFrames` (picklable).
        n: frames to build (the first ``n``; 0 = all, as many as ``SessionFrames(session, **frames_kwargs)`` has).
        queue_frames: frames the child may build ahead.
        touch_process: the tactile pipelines in a process of their own (above); False: all in one child.

    ``cpu_s`` (after the iteration ends) is the children's CPU time over the frames. Use as a context manager (or
    call :meth:`close`): leaving early ends the children.
    """

    def __init__(
        self,
        session: str | Path,
        frames_kwargs: dict,
        n: int = 0,
        queue_frames: int = QUEUE_FRAMES,
        touch_process: bool = True,
    ) -> None:
        import multiprocessing as mp

        ctx = mp.get_context("spawn")
        self.session = str(session)
        self.cpu_s = 0.0
        self._q = ctx.Queue(maxsize=max(1, int(queue_frames)))
        apart = touch_process and touch_apart(frames_kwargs)
        self._touch_q = ctx.Queue(maxsize=max(1, int(queue_frames))) if apart else None
        self._procs: list = []
        if self._touch_q is not None:
            self._procs.append(
                ctx.Process(
                    target=_touch_contacts,
                    args=(self.session, dict(frames_kwargs), int(n), self._touch_q),
                    daemon=True,
                    name="vtrack-touch",
                )
            )
        self._proc = ctx.Process(
            target=_build_frames,
            args=(self.session, dict(frames_kwargs), int(n), self._q, self._touch_q),
            daemon=True,
            name="vtrack-frames",
        )
        self._procs.append(self._proc)
        for p in self._procs:
            p.start()
        # an exception between here and the iteration (the caller's initialisation) must not leave the children
        # blocked on a full queue for the rest of the process: they are killed when this object goes
        self._finalizer = weakref.finalize(self, _kill, self._procs)

    @property
    def processes(self) -> int:
        """Child processes started (1: the frame builder; 2: and the touch process)."""
        return len(self._procs)

    def _get(self) -> tuple:
        import queue

        deadline = time.monotonic() + START_TIMEOUT_S
        while True:
            try:
                msg = self._q.get(timeout=1.0)
                break
            except queue.Empty:
                for p in self._procs:
                    if not p.is_alive() and (p is self._proc or p.exitcode != 0):
                        self.close()
                        raise RuntimeError(
                            f"{p.name} process for {self.session} ended unexpectedly (exit code {p.exitcode})"
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
        """End the children (waits briefly, then kills them)."""
        for p in self._procs:
            if p.is_alive():
                p.join(0.5 if self.cpu_s else 0.0)
                if p.is_alive():
                    p.kill()
                    p.join(2.0)
        for q in (self._q, self._touch_q):
            if q is not None:
                q.close()
                q.cancel_join_thread()  # frames left in the queue are not wanted: do not block on them

    def __enter__(self) -> PrefetchedFrames:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
