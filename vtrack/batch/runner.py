"""Batch driver: plan jobs, skip complete results, run the rest on an engine with bounded retries,
write the summary table.

Guarantees (tested in ``tests/batch``):
- one result folder per job, committed atomically (see :mod:`vtrack.batch.results`);
- a job that raises or kills its worker is retried up to ``retries`` times (bad input, i.e. a
  :class:`~vtrack.errors.InputError`, is not retried: it would fail the same way), then reported
  as failed; the other jobs carry on;
- re-running the same command skips jobs whose results are complete and valid, so a killed batch
  resumes where it stopped, without lost or duplicated results;
- one driver per output folder at a time (an ``flock`` on ``OUT/.batch.lock``, released by the
  kernel if the driver is killed).
"""

from __future__ import annotations

import collections
import fcntl
import json
import os
import platform
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from vtrack.batch import results
from vtrack.batch.engines import LocalEngine, RayEngine, make_engine
from vtrack.batch.plan import discover_sessions, make_jobs
from vtrack.errors import InputError

LOCK_FILE = ".batch.lock"
#: Environment variable naming a fault-plan JSON file (testing hook, see :func:`load_fault_plan`).
FAULT_PLAN_ENV = "VTRACK_BATCH_FAULT_PLAN"

Event = dict[str, Any]


class _Lock:
    """Exclusive ``flock`` on the output folder's lock file (released automatically on death)."""

    def __init__(self, out_root: Path) -> None:
        self.path = out_root / LOCK_FILE
        self.fd: int | None = None

    def __enter__(self) -> _Lock:
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 200, 0).decode(errors="replace").strip()
            os.close(fd)
            raise InputError(
                f"another batch is writing to this folder ({holder or 'unknown process'})", path=self.path.parent
            ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"pid {os.getpid()} on {platform.node()}".encode(), 0)
        self.fd = fd
        return self

    def __exit__(self, *exc: Any) -> None:
        if self.fd is not None:
            fcntl.flock(self.fd, fcntl.LOCK_UN)
            os.close(self.fd)
            self.fd = None


def load_fault_plan(plan: str | Path | dict | None) -> dict[str, dict[str, Any]]:
    """Testing hook: ``{job key | session folder name | "*": {"mode", "times", "delay_s"}}``.

    ``mode`` is ``exit`` (``os._exit``), ``kill`` (SIGKILL itself), ``raise``, ``hang``, or one of
    those with ``_before_commit`` (crash after the result is written but before it is renamed into
    place); the fault fires on attempts ``1..times``. ``delay_s`` sleeps at the start of every attempt.
    """
    if plan is None:
        plan = os.environ.get(FAULT_PLAN_ENV) or None
    if plan is None:
        return {}
    if isinstance(plan, dict):
        return plan
    try:
        data = json.loads(Path(plan).read_text())
    except (OSError, ValueError) as e:
        raise InputError(
            "cannot read the fault plan",
            path=plan,
            field=FAULT_PLAN_ENV,
            expected="a JSON file {key: {mode, times, delay_s}}",
            got=type(e).__name__,
        ) from None
    if not isinstance(data, dict):
        raise InputError(
            "the fault plan must be a JSON object",
            path=plan,
            field=FAULT_PLAN_ENV,
            expected="{key: {mode, times, delay_s}}",
            got=type(data).__name__,
        )
    return data


def _fault_for(job: dict[str, Any], plan: dict[str, Any]) -> dict[str, Any] | None:
    return plan.get(job["key"]) or plan.get(Path(job["session"]).name) or plan.get("*")


def run_batch(
    task: str,
    sessions: list[str | Path],
    out: str | Path,
    *,
    engine: str | LocalEngine | RayEngine = "local",
    workers: int | None = None,
    address: str | None = None,
    retries: int = 2,
    params: dict[str, Any] | None = None,
    chunk_frames: int | None = None,
    force: bool = False,
    threads: int = 1,
    timeout_s: float | None = None,
    warm_up: bool = True,
    pin_cpus: bool | None = None,
    on_event: Callable[[Event], None] | None = None,
    fault_plan: str | Path | dict | None = None,
) -> dict[str, Any]:
    """Run ``task`` over sessions; see the module docstring for the guarantees.

    Args:
        task: registered task name (:data:`vtrack.batch.tasks.TASKS`) or ``"module:function"``.
        sessions: session folders, or folders searched for sessions.
        out: output folder: ``OUT/<key>/`` per job, ``OUT/summary.{csv,json}``.
        engine: "local", "ray", or an engine object.
        workers: parallel tasks (default: CPU count / the Ray cluster's CPUs).
        address: existing Ray cluster address (Ray engine only).
        retries: extra attempts after a failure or a worker crash.
        params: task options (part of the result identity: other options = other results).
        chunk_frames: split each session into chunks of this many reference-stream frames.
        force: recompute even complete results.
        threads: BLAS/OpenMP/torch threads per task.
        timeout_s: per-attempt time limit; an attempt over it is killed and counts as a failure.
        warm_up: import the task (and run its module's ``warm_up(**params)`` hook) in every worker
            before timing starts.
        pin_cpus: pin each running task to its own ``threads`` CPUs (default: on, except for an
            existing Ray cluster given by ``address``, whose nodes this driver cannot see). Makes
            thread-pool back-ends that ignore ``OMP_NUM_THREADS`` (Open3D/TBB) deterministic.
        on_event: callback for progress (``{"type": "start"|"done"|"retry"|"end", ...}``).
        fault_plan: testing hook (see :func:`load_fault_plan`).

    Returns:
        ``{"run": run info incl. tasks/min, "results": one record per job, "paths": summary files}``.
    """
    emit = on_event or (lambda e: None)
    out_root = Path(out).expanduser().resolve()
    out_root.mkdir(parents=True, exist_ok=True)
    if retries < 0:
        raise InputError("retries must be >= 0", field="retries", got=retries)
    with _Lock(out_root):
        removed = results.clean_leftovers(out_root)
        session_dirs = discover_sessions(list(sessions))
        jobs = make_jobs(task, session_dirs, out_root, params, chunk_frames, threads)
        keys = [j["key"] for j in jobs]
        if len(set(keys)) != len(keys):
            raise InputError("two jobs map to the same result folder", field="sessions")
        plan = load_fault_plan(fault_plan)
        records: dict[str, dict[str, Any]] = {}
        todo: collections.deque[dict[str, Any]] = collections.deque()
        for job in jobs:
            man = None if force else results.read_valid_result(out_root / job["key"], job)
            if man is not None:
                records[job["key"]] = _record(job, "cached", 0, man)
            else:
                fault = _fault_for(job, plan)
                if fault:
                    job["fault"] = fault
                todo.append(job)
        run_info: dict[str, Any] = {
            "task": task,
            "target": jobs[0]["target"] if jobs else task,
            "params": params or {},
            "out": str(out_root),
            "jobs": len(jobs),
            "cached": len(records),
            "to_run": len(todo),
            "retries": retries,
            "threads_per_task": threads,
            "removed_leftovers": removed,
            "chunk_frames": chunk_frames,
            "started_unix": time.time(),
            "host": platform.node(),
        }
        emit({"type": "start", "total": len(jobs), "cached": len(records), "to_run": len(todo)})
        for rec in records.values():
            emit({"type": "done", "record": rec})
        eng = make_engine(engine, workers, address, threads) if isinstance(engine, str) else engine
        stats = {"attempts": 0, "crashes": 0}
        try:
            if pin_cpus is None:
                pin_cpus = not (getattr(eng, "address", None))
            run_info["pin_cpus"] = bool(pin_cpus)
            t_start = time.perf_counter()
            if todo:
                eng.start(jobs[0]["target"] if warm_up else None, params or {}, bool(pin_cpus))
            t_ready = time.perf_counter()
            run_info.update(eng.describe())
            _loop(eng, todo, records, retries, timeout_s, emit, out_root, run_info, stats, bool(pin_cpus))
            t_end = time.perf_counter()
        finally:
            eng.close()
        # Temp folders of attempts that died (their workers are gone now) are never results.
        run_info["removed_leftovers"] += results.clean_leftovers(out_root)
        ran = sum(1 for r in records.values() if r["status"] == "ok")
        wall = t_end - t_ready
        run_info.update(
            {
                "engine_start_seconds": round(t_ready - t_start, 3),
                "wall_seconds": round(wall, 3),
                "ok": ran,
                "failed": sum(1 for r in records.values() if r["status"] == "failed"),
                "attempts": stats["attempts"],
                "crashes": stats["crashes"],
                "tasks_per_min": round(60.0 * ran / wall, 3) if wall > 0 and ran else None,
                # CPU the tasks actually got / (wall x workers): < 1 means the workers waited for cores.
                "task_cpu_seconds": round(
                    sum(r.get("cpu_seconds") or 0.0 for r in records.values() if r["status"] == "ok"), 3
                ),
            }
        )
        n_workers = run_info.get("workers") or 1
        run_info["cpu_utilisation"] = (
            round(run_info["task_cpu_seconds"] / (wall * n_workers), 3) if wall > 0 and ran else None
        )
        ordered = [records[k] for k in keys]
        paths = results.write_summary(out_root, ordered, run_info)
        emit({"type": "end", "run": run_info})
        return {"run": run_info, "results": ordered, "paths": {k: str(v) for k, v in paths.items()}}


def _record(
    job: dict[str, Any],
    status: str,
    attempts: int,
    man: dict[str, Any] | None = None,
    outcome: dict[str, Any] | None = None,
    errors: list[str] | None = None,
) -> dict[str, Any]:
    src = man or outcome or {}
    rec = {
        "key": job["key"],
        "session": job["session"],
        "chunk": job["chunk"],
        "status": status,
        "attempts": attempts,
        "seconds": src.get("seconds"),
        "cpu_seconds": src.get("cpu_seconds"),
        "host": src.get("host", ""),
        "metrics": src.get("metrics"),
        "result_dir": str(Path(job["out_root"]) / job["key"]),
    }
    if errors:
        rec["error"] = errors[-1]
        rec["attempt_errors"] = errors
    if status == "failed":
        rec["result_dir"] = None
        rec["traceback"] = (outcome or {}).get("traceback")
    return rec


def _loop(
    eng: Any,
    todo: collections.deque,
    records: dict[str, dict[str, Any]],
    retries: int,
    timeout_s: float | None,
    emit: Callable[[Event], None],
    out_root: Path,
    run_info: dict[str, Any],
    stats: dict[str, int],
    pin_cpus: bool,
) -> None:
    inflight: dict[Any, tuple[dict[str, Any], float, int]] = {}
    free_slots = set(range(eng.capacity))
    attempts: dict[str, int] = collections.Counter()
    errors: dict[str, list[str]] = collections.defaultdict(list)
    timed_out: set[Any] = set()
    last_summary = time.monotonic()
    while todo or inflight:
        while todo and eng.free() > 0:
            job = todo.popleft()
            attempts[job["key"]] += 1
            stats["attempts"] += 1
            # A CPU slot per task in flight: the worker pins itself to it (see worker.pin_to_slot).
            slot = min(free_slots) if free_slots else -1
            free_slots.discard(slot)
            job = {**job, "attempt": attempts[job["key"]], "cpu_slot": slot if pin_cpus else None}
            inflight[eng.submit(job)] = (job, time.monotonic(), slot)
        for token, outcome in eng.poll(0.25):
            job, _t, slot = inflight.pop(token)
            if slot >= 0:
                free_slots.add(slot)
            key = job["key"]
            if outcome.get("status") == "ok":
                records[key] = _record(job, "ok", attempts[key], outcome=outcome, errors=errors.get(key))
                emit({"type": "done", "record": records[key]})
                continue
            if outcome.get("status") == "crashed":
                stats["crashes"] += 1
            err = outcome.get("error", "unknown error")
            if token in timed_out:
                err = f"timed out after {timeout_s:g} s ({err})"
                timed_out.discard(token)
            errors[key].append(f"attempt {attempts[key]}: {err}")
            if outcome.get("retryable", True) and attempts[key] <= retries:
                todo.append(job)  # to the back: the others carry on first
                emit({"type": "retry", "key": key, "attempt": attempts[key], "error": err})
            else:
                records[key] = _record(job, "failed", attempts[key], outcome=outcome, errors=errors[key])
                emit({"type": "done", "record": records[key]})
        if timeout_s:
            now = time.monotonic()
            for token, (_job, t0, _slot) in inflight.items():
                if token not in timed_out and now - t0 > timeout_s:
                    timed_out.add(token)
                    eng.cancel(token)
        if time.monotonic() - last_summary > 2.0:
            # Keep the summary current so a killed driver still leaves a consistent table.
            results.write_summary(out_root, list(records.values()), {**run_info, "in_progress": True})
            last_summary = time.monotonic()
