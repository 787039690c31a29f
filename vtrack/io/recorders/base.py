"""Shared recorder machinery: a stop flag driven by Ctrl-C, a one-line status display, and the session
writer every recorder opens."""

from __future__ import annotations

import signal
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO


class StopFlag:
    """Set by the first Ctrl-C (SIGINT) or SIGTERM so the recorder can flush and close cleanly;
    a second Ctrl-C raises KeyboardInterrupt (the writer's context manager still keeps the
    committed frames).

    Use as a context manager around the recording loop; handlers are installed only in the main
    thread and restored on exit.
    """

    def __init__(self, max_seconds: float | None = None) -> None:
        self._event = threading.Event()
        self._old: dict[int, Any] = {}
        self.reason = ""
        self.deadline = None if max_seconds is None else time.monotonic() + max_seconds

    def set(self, reason: str = "stopped") -> None:
        if not self._event.is_set():
            self.reason = reason
        self._event.set()

    def is_set(self) -> bool:
        if self.deadline is not None and time.monotonic() >= self.deadline:
            self.set("duration reached")
        return self._event.is_set()

    def _handler(self, signum, frame) -> None:
        if self._event.is_set() and signum == signal.SIGINT:
            raise KeyboardInterrupt
        self.set("Ctrl-C" if signum == signal.SIGINT else "SIGTERM")

    def __enter__(self) -> StopFlag:
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._old[sig] = signal.signal(sig, self._handler)
        return self

    def __exit__(self, *exc: Any) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)
        self._old.clear()


@dataclass
class RecordingStats:
    """Per-stream counts of a recording (frames written / dropped) and its wall time."""

    written: dict[str, int] = field(default_factory=dict)
    dropped: dict[str, int] = field(default_factory=dict)
    committed: dict[str, int] = field(default_factory=dict)
    started: float = field(default_factory=time.monotonic)

    def add(self, stream: str, n: int = 1) -> None:
        self.written[stream] = self.written.get(stream, 0) + n

    def drop(self, stream: str, n: int = 1) -> None:
        self.dropped[stream] = self.dropped.get(stream, 0) + n

    @property
    def elapsed(self) -> float:
        return time.monotonic() - self.started

    def to_dict(self) -> dict[str, Any]:
        el = max(self.elapsed, 1e-9)
        return {
            "seconds": round(self.elapsed, 3),
            "written": dict(self.written),
            "dropped": dict(self.dropped),
            "rate_hz": {k: round(v / el, 2) for k, v in self.written.items()},
        }


class StatusLine:
    """A single, rewritten status line on a terminal (``\\r``); plain lines every ``period`` s otherwise.

    The line shows elapsed time, frames and rate per stream, committed frames and drops, e.g.
    ``rec 12.3s | camera/oak 369 (30.0 Hz) | committed 352 | dropped 0``.
    """

    def __init__(self, stream: TextIO | None = None, period: float = 0.5, enabled: bool = True) -> None:
        self.out = stream or sys.stderr
        self.tty = bool(getattr(self.out, "isatty", lambda: False)())
        self.period = period if self.tty else max(period, 1.0)
        self.enabled = enabled
        self._last = 0.0

    def update(self, stats: RecordingStats, writer: Any = None, force: bool = False) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if not force and now - self._last < self.period:
            return
        self._last = now
        el = max(stats.elapsed, 1e-9)
        parts = [f"rec {el:6.1f}s"]
        for k, v in stats.written.items():
            parts.append(f"{k} {v} ({v / el:.1f} Hz)")
        if writer is not None:
            committed = sum(s["n"] for s in writer._streams.values())
            parts.append(f"committed {committed}")
        parts.append(f"dropped {sum(stats.dropped.values())}")
        line = " | ".join(parts)
        if self.tty:
            self.out.write("\r" + line[:200].ljust(80))
        else:
            self.out.write(line + "\n")
        self.out.flush()

    def close(self) -> None:
        if self.enabled and self.tty:
            self.out.write("\n")
            self.out.flush()


@contextmanager
def recording_writer(
    out: str | Path, scene: dict[str, Any], *, overwrite: bool, flush_every: int, info: dict[str, Any], status: bool
) -> Iterator[tuple[Any, StatusLine]]:
    """The session a recorder writes (``scene`` as manifest and as ``scene.yaml``; ``flush_every`` frames per
    commit = the crash-safety granularity) and its status line: ``(SessionWriter, StatusLine)``."""
    from vtrack.io.importers.scene_build import write_scene_yaml
    from vtrack.io.session import SessionWriter

    line = StatusLine(enabled=status)
    with SessionWriter(out, scene, overwrite=overwrite, flush_every=flush_every, info=info) as w:
        write_scene_yaml(w, scene)
        yield w, line
