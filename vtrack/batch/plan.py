"""Turn a list of session paths into batch jobs: one per session, or one per chunk of a long session.

A job is a plain JSON-able dict (so it crosses process and Ray boundaries unchanged); the keys are
documented in :func:`make_jobs`. Result folders are named by the job key: the session folder's
name, with a short hash of its absolute path when two sessions of the batch share a name, and
``@f<i0>-<i1>`` for a chunk (frame interval of the reference stream).
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

from vtrack.batch.tasks import chunk_params, resolve, target_of
from vtrack.errors import InputError

SESSION_MANIFEST = "manifest.json"


def is_session(path: Path) -> bool:
    """A folder holding a ``manifest.json`` of the vtrack session format."""
    m = path / SESSION_MANIFEST
    if not m.is_file():
        return False
    try:
        return json.loads(m.read_text()).get("format") == "vtrack-session"
    except (OSError, json.JSONDecodeError, AttributeError):
        return False


def discover_sessions(paths: list[str | Path]) -> list[Path]:
    """Expand arguments into session folders (absolute, deduplicated, in argument order).

    Each argument is a session folder or a folder searched recursively for sessions (session
    folders themselves are not descended into: their ``data.zarr`` can be large).

    Raises:
        InputError: an argument does not exist, or holds no session.
    """
    out: list[Path] = []
    seen: set[Path] = set()
    for arg in paths:
        p = Path(arg).expanduser().resolve()
        if not p.exists():
            raise InputError("session path does not exist", path=p)
        found: list[Path] = []
        if is_session(p):
            found = [p]
        elif p.is_dir():
            for root, dirs, _files in os.walk(p):
                r = Path(root)
                if is_session(r):
                    found.append(r)
                    dirs[:] = []
                    continue
                dirs[:] = sorted(d for d in dirs if not d.startswith("."))
            found.sort()
        if not found:
            raise InputError("no vtrack session here (a session folder holds manifest.json)", path=p)
        for f in found:
            if f not in seen:
                seen.add(f)
                out.append(f)
    return out


def session_fingerprint(session: Path) -> str:
    """Hash of what identifies a session's content: its manifest and every stream's committed count.

    The stream groups' ``zarr.json`` hold the committed frame counts, so a session that is still
    being recorded gets a new fingerprint as it grows, and its old results count as stale.
    """
    h = hashlib.sha256()
    h.update((session / SESSION_MANIFEST).read_bytes())
    try:
        streams = sorted(json.loads((session / SESSION_MANIFEST).read_text()).get("streams", {}))
    except json.JSONDecodeError as e:
        raise InputError(f"corrupt session manifest ({e.msg})", path=session / SESSION_MANIFEST) from None
    for name in streams:
        meta = session / "data.zarr" / name / "zarr.json"
        if meta.is_file():
            h.update(name.encode())
            h.update(meta.read_bytes())
    return h.hexdigest()[:20]


def params_digest(task_target: str, params: dict[str, Any]) -> str:
    """Hash of the task and its options: a result made with other options is stale."""
    blob = json.dumps({"target": task_target, "params": params}, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def session_keys(sessions: list[Path]) -> dict[Path, str]:
    """Result-folder name of each session: its folder name, disambiguated when names collide."""
    by_name: dict[str, list[Path]] = {}
    for s in sessions:
        by_name.setdefault(s.name, []).append(s)
    keys = {}
    for name, group in by_name.items():
        for s in group:
            keys[s] = name if len(group) == 1 else f"{name}-{hashlib.sha1(str(s).encode()).hexdigest()[:6]}"
    return keys


def reference_stream(reader: Any) -> str:
    """The stream whose frames define chunk boundaries: first RGB-D camera, else first tactile
    stream, else the stream with the most frames."""
    names = sorted(reader.streams)
    for kind in ("rgbd", "tactile"):
        for n in names:
            if reader.streams[n].kind == kind and reader.streams[n].n:
                return n
    if not names:
        raise InputError("session has no streams", path=reader.path)
    return max(names, key=lambda n: reader.streams[n].n)


def chunk_ranges(session: Path, chunk_frames: int) -> list[dict[str, Any]]:
    """Split a session into chunks of ``chunk_frames`` reference-stream frames.

    Returns dicts with ``stream``, ``frames`` ``[i0, i1)`` and ``time_range`` ``[t0, t1)`` (s); the
    last chunk's ``t1`` lies one frame period past the last frame so that it includes it.
    """
    from vtrack.io.session import open_session

    if chunk_frames < 1:
        raise InputError("chunk size must be positive", field="chunk_frames", expected=">= 1", got=chunk_frames)
    reader = open_session(session)
    name = reference_stream(reader)
    t = reader.streams[name].t
    n = len(t)
    if n == 0:
        raise InputError("reference stream has no frames: cannot chunk", path=session, field=name)
    period = float(t[-1] - t[-2]) if n > 1 else 1.0
    out = []
    for i0 in range(0, n, chunk_frames):
        i1 = min(n, i0 + chunk_frames)
        t1 = float(t[i1]) if i1 < n else float(t[-1]) + period
        out.append({"stream": name, "frames": [i0, i1], "time_range": [float(t[i0]), t1]})
    return out


def make_jobs(
    task: str,
    sessions: list[Path],
    out_root: Path,
    params: dict[str, Any] | None = None,
    chunk_frames: int | None = None,
    threads: int = 1,
) -> list[dict[str, Any]]:
    """One job per session, or per chunk when ``chunk_frames`` is given.

    Job keys: ``key`` (result folder name), ``task``, ``target`` (``module:function``),
    ``session`` (absolute path), ``out_root``, ``params`` (task options), ``params_digest``,
    ``session_fingerprint``, ``chunk`` (None or the dict of :func:`chunk_ranges`), ``chunk_args``
    (what is passed to the task for the chunk), ``threads`` (BLAS/OpenMP/torch threads per task).

    Raises:
        InputError: chunking asked for a task that cannot take a frame or time range.
    """
    params = dict(params or {})
    target = target_of(task)
    digest = params_digest(target, params)
    keys = session_keys(sessions)
    accepted: list[str] = []
    if chunk_frames:
        # Importing the task here (driver side) is the price of checking its signature up front.
        accepted = chunk_params(resolve(target))
        if not accepted:
            raise InputError(
                "this task cannot process part of a session (it accepts neither "
                "'time_range' nor 'frames'): run without --chunk-frames",
                field="task",
                got=target,
            )
    jobs = []
    for s in sessions:
        fp = session_fingerprint(s)
        chunks = chunk_ranges(s, chunk_frames) if chunk_frames else [None]
        for ch in chunks:
            key = keys[s]
            chunk_args = {}
            if ch is not None:
                key = f"{key}@f{ch['frames'][0]:06d}-{ch['frames'][1]:06d}"
                chunk_args = {p: ch[p] for p in accepted}
            jobs.append(
                {
                    "key": key,
                    "task": task,
                    "target": target,
                    "session": str(s),
                    "out_root": str(out_root),
                    "params": params,
                    "params_digest": digest,
                    "session_fingerprint": fp,
                    "chunk": ch,
                    "chunk_args": chunk_args,
                    "threads": int(threads),
                }
            )
    return jobs
