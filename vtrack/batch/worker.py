"""What runs inside a worker process (local pool or Ray): one job -> one committed result folder.

:func:`execute` never raises for a failing task: it returns an outcome dict, so the local and Ray
engines report task errors identically. Only a dying worker (segfault, OOM kill, ``os._exit``)
shows up as an engine-level crash, which the engines turn into the same kind of outcome.
"""

from __future__ import annotations

import os
import platform
import shutil
import signal
import sys
import time
import traceback
import uuid
from pathlib import Path
from typing import Any

from vtrack.threads import thread_env

#: CPUs this process may use before any pinning (pinning narrows the mask of a reused worker).
_ALL_CPUS: list[int] = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []


def pin_to_slot(slot: int, threads: int) -> list[int]:
    """Restrict every thread of this process to ``threads`` CPUs chosen by the job's slot.

    Why: some back-ends ignore ``OMP_NUM_THREADS`` (Open3D's CPU hash map runs on TBB, which sizes
    itself from the affinity mask) and are then not bit-reproducible run to run; pinning makes a
    task single-threaded (for ``threads=1``) and deterministic, and keeps concurrent tasks on
    different cores. Returns the CPUs used ([] where affinity is not supported).
    """
    if not _ALL_CPUS or slot < 0:
        return []
    n = len(_ALL_CPUS)
    cpus = sorted({_ALL_CPUS[(slot * threads + k) % n] for k in range(max(1, threads))})
    tids = [int(t) for t in os.listdir("/proc/self/task")] if os.path.isdir("/proc/self/task") else [0]
    for tid in tids:
        try:
            os.sched_setaffinity(tid, cpus)
        except OSError:
            pass
    return cpus


def init_local_worker(threads: int, driver_pid: int) -> None:
    """Initializer of local pool workers: thread caps, and die with the driver.

    ``PR_SET_PDEATHSIG`` (Linux) makes the kernel SIGKILL the worker when its parent dies (the
    driver with "spawn", the fork server with "forkserver", which exits with the driver), so a
    killed batch leaves no orphan that could keep writing into the output folder.
    """
    os.environ.update(thread_env(threads))
    if sys.platform.startswith("linux"):
        ppid = os.getppid()
        try:
            import ctypes

            libc = ctypes.CDLL("libc.so.6", use_errno=True)
            libc.prctl(1, int(signal.SIGKILL))  # PR_SET_PDEATHSIG = 1
        except OSError:
            pass
        try:
            os.kill(driver_pid, 0)
        except ProcessLookupError:
            os._exit(1)  # the driver died before we got here
        if os.getppid() != ppid:  # the parent died before prctl took effect
            os._exit(1)
    # Belt and braces (and the only guard with "forkserver", whose server outlives the driver):
    # exit as soon as the driver process is gone.
    import threading

    def _watch() -> None:
        while True:
            time.sleep(0.5)
            try:
                os.kill(driver_pid, 0)
            except ProcessLookupError:
                os._exit(1)
            except PermissionError:
                pass

    threading.Thread(target=_watch, name="vtrack-batch-driver-watch", daemon=True).start()


def _apply_threads(threads: int) -> None:
    for k, v in thread_env(threads).items():
        os.environ.setdefault(k, v)
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(max(1, int(threads)))


def _inject_fault(job: dict[str, Any], stage: str) -> None:
    """Testing hook: crash or delay on purpose, as described by ``job["fault"]`` (set by the runner
    from a fault-plan file, see :func:`vtrack.batch.runner.load_fault_plan`)."""
    fault = job.get("fault")
    if not fault:
        return
    if stage == "start" and fault.get("delay_s"):
        time.sleep(float(fault["delay_s"]))
    if job.get("attempt", 1) > int(fault.get("times", 0)):
        return
    mode = fault.get("mode", "")
    at = "before_commit" if mode.endswith("_before_commit") else "start"
    if at != stage:
        return
    mode = mode.removesuffix("_before_commit")
    if mode == "exit":
        os._exit(17)
    if mode == "kill":
        os.kill(os.getpid(), signal.SIGKILL)
    if mode == "raise":
        raise RuntimeError(f"injected failure (attempt {job.get('attempt', 1)})")
    if mode == "hang":
        time.sleep(3600)


def execute(job: dict[str, Any]) -> dict[str, Any]:
    """Run one job: task into a temp folder, checksummed manifest last, atomic rename into place.

    Returns:
        outcome dict: ``key``, ``status`` ("ok" | "error"), ``retryable``, ``error``, ``traceback``,
        ``metrics``, ``nonfinite`` (metric keys that were NaN/Inf, stored as null), ``seconds``
        (task wall time), ``cpu_seconds`` (CPU time of the worker process during the task),
        ``host``, ``pid``, ``attempt``, ``commit``.
    """
    from vtrack.batch import results
    from vtrack.batch.tasks import resolve
    from vtrack.errors import VtrackError

    t0 = time.perf_counter()
    c0 = time.process_time()
    out = {
        "key": job["key"],
        "attempt": job.get("attempt", 1),
        "host": platform.node(),
        "pid": os.getpid(),
        "started_unix": time.time(),
    }
    out_root = Path(job["out_root"])
    tmp = out_root / f"{results.TMP_PREFIX}{job['key']}-{uuid.uuid4().hex[:8]}"
    try:
        _apply_threads(job.get("threads", 1))
        if job.get("cpu_slot") is not None:
            out["cpus"] = pin_to_slot(int(job["cpu_slot"]), int(job.get("threads", 1)))
        _inject_fault(job, "start")
        fn = resolve(job["target"])
        tmp.mkdir(parents=True)
        kwargs = {**job.get("params", {}), **{k: tuple(v) for k, v in (job.get("chunk_args") or {}).items()}}
        metrics = fn(job["session"], str(tmp), **kwargs)
        if metrics is None:
            metrics = {}
        if not isinstance(metrics, dict):
            raise TypeError(f"task returned {type(metrics).__name__}, expected a dict of metrics")
        bad: list[str] = []
        from vtrack.io.jsonio import to_jsonable

        metrics = to_jsonable(metrics, bad)
        seconds = time.perf_counter() - t0
        cpu_seconds = time.process_time() - c0
        results.write_manifest(
            tmp,
            job,
            metrics,
            {
                "attempt": out["attempt"],
                "host": out["host"],
                "pid": out["pid"],
                "seconds": seconds,
                "cpu_seconds": cpu_seconds,
                "nonfinite": bad,
                "finished_unix": time.time(),
                "vtrack_version": _version(),
            },
        )
        _inject_fault(job, "before_commit")
        out["commit"] = results.commit(tmp, out_root / job["key"], job)
        out.update(status="ok", metrics=metrics, nonfinite=bad, seconds=seconds, cpu_seconds=cpu_seconds)
    except Exception as e:
        # Bad input is deterministic: retrying it would only fail again.
        retryable = not (isinstance(e, VtrackError) and isinstance(e, ValueError))
        out.update(
            status="error",
            retryable=retryable,
            error=f"{type(e).__name__}: {e}",
            traceback=traceback.format_exc(limit=8),
            seconds=time.perf_counter() - t0,
        )
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return out


def warm_up(target: str, params: dict[str, Any] | None = None, cpu_slot: int | None = None, threads: int = 1) -> int:
    """Import a task's module in this worker and run its ``warm_up(**params)`` hook if it has one, so
    that timing excludes start-up cost; returns the pid.

    Why the hook: task modules import their heavy dependencies lazily (Open3D, torch, trimesh, scipy),
    so importing the module alone left ~2 s of imports inside each worker's first task (measured: first
    TSDF reconstruction 3.0 s, later ones 1.2 s).
    With ``cpu_slot`` the worker is pinned first, as a task would be: Open3D's TBB sizes its thread pool
    from the affinity mask when it loads, and a pool sized for all CPUs makes results differ run to run.
    """
    from vtrack.batch.tasks import warm_up_hook

    try:
        _apply_threads(threads)
        if cpu_slot is not None:
            pin_to_slot(int(cpu_slot), int(threads))
        hook = warm_up_hook(target)
        if hook is not None:
            hook(**(params or {}))
    except Exception:
        pass  # the real run reports it
    return os.getpid()


def _version() -> str:
    from vtrack import __version__

    return __version__
