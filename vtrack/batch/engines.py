"""Execution engines: a local process pool and Ray (local cluster or an existing one).

Both run :func:`vtrack.batch.worker.execute` on plain job dicts and hand back outcome dicts, so
the runner's retry and bookkeeping logic is the same for both. A worker that dies (``os._exit``,
SIGKILL, segfault, OOM) becomes an outcome with ``status="crashed"``.

The local engine keeps one single-process ``ProcessPoolExecutor`` per slot instead of one shared
pool: a worker crash breaks a whole pool, and with one pool per slot the crash is attributed to
exactly the job that caused it while the other slots keep running.
"""

from __future__ import annotations

import concurrent.futures as cf
import itertools
import multiprocessing as mp
import os
import signal
import time
from typing import Any

from vtrack.batch.worker import execute, init_local_worker, warm_up
from vtrack.errors import VtrackError
from vtrack.threads import thread_env

RAY_MISSING = (
    "the Ray engine needs the optional 'ray' package: pip install 'vtrack[distributed]' "
    "(or pip install 'ray>=2.30'), or use --engine local"
)


def _crash(token: Any, error: str) -> tuple[Any, dict[str, Any]]:
    return token, {"status": "crashed", "retryable": True, "error": error}


#: Modules the fork server imports once, so forked workers start warm.
FORKSERVER_PRELOAD = ("vtrack.batch.worker", "vtrack.batch.results", "numpy", "zarr", "vtrack.io.session")


class _Slot:
    def __init__(self, ctx: Any, threads: int) -> None:
        self.executor = cf.ProcessPoolExecutor(
            max_workers=1, mp_context=ctx, initializer=init_local_worker, initargs=(threads, os.getpid())
        )
        self.token: int | None = None
        self.future: cf.Future | None = None
        self.procs: list[Any] = []

    def pids(self) -> list[int]:
        # Private attribute, used only to kill a timed-out task and to read a crash's exit code.
        return list((getattr(self.executor, "_processes", None) or {}).keys())

    def remember_processes(self) -> None:
        # The executor forgets its processes once broken; keep them to read the exit code.
        self.procs = list((getattr(self.executor, "_processes", None) or {}).values())

    def exit_codes(self) -> list[int | None]:
        for p in self.procs:
            p.join(timeout=1.0)
        # The pool's manager thread reaps the same dead worker: when its waitpid wins, our join returns
        # with the code not yet stored (a loaded machine showed 'no exit code'); re-read it for a moment.
        codes = [p.exitcode for p in self.procs]
        deadline = time.monotonic() + 3.0
        while any(c is None for c in codes) and time.monotonic() < deadline:
            time.sleep(0.05)
            codes = [p.exitcode for p in self.procs]
        return codes


class LocalEngine:
    """Process pool on this machine: ``workers`` slots, each one spawned worker process.

    Args:
        workers: parallel tasks (default: CPU count).
        threads: BLAS/OpenMP/torch threads per task.
        start_method: "spawn" (default) or "forkserver" (workers fork from a server that already
            imported numpy, zarr and the session reader: faster (re)starts, but the server outlives
            a SIGKILLed driver); never "fork" (the driver has threads).
    """

    name = "local"

    def __init__(self, workers: int | None = None, threads: int = 1, start_method: str | None = None) -> None:
        start_method = start_method or "spawn"
        if start_method not in ("spawn", "forkserver"):
            raise VtrackError(f"unsupported start method '{start_method}' (use spawn or forkserver)")
        self.workers = max(1, int(workers or os.cpu_count() or 1))
        self.threads = threads
        self._ctx = mp.get_context(start_method)
        if start_method == "forkserver":
            # Takes effect when the (per-driver) fork server starts, i.e. on the first pool.
            self._ctx.set_forkserver_preload(list(FORKSERVER_PRELOAD))
        self._slots: list[_Slot] = []
        self._tokens = itertools.count()

    @property
    def capacity(self) -> int:
        return self.workers

    def describe(self) -> dict[str, Any]:
        return {"engine": "local", "workers": self.workers, "start_method": self._ctx.get_start_method()}

    def start(
        self, warm_target: str | None = None, warm_params: dict[str, Any] | None = None, pin_cpus: bool = False
    ) -> None:
        # Workers inherit the environment at spawn time: cap threads before numpy loads in them.
        os.environ.update(thread_env(self.threads))
        self._slots = [_Slot(self._ctx, self.threads) for _ in range(self.workers)]
        if warm_target:
            futs = [
                s.executor.submit(warm_up, warm_target, warm_params, i if pin_cpus else None, self.threads)
                for i, s in enumerate(self._slots)
            ]
            cf.wait(futs)

    def free(self) -> int:
        return sum(1 for s in self._slots if s.future is None)

    def submit(self, job: dict[str, Any]) -> int:
        slot = next(s for s in self._slots if s.future is None)
        token = next(self._tokens)
        try:
            slot.future = slot.executor.submit(execute, job)
        except cf.process.BrokenProcessPool:
            self._replace(slot)
            slot = next(s for s in self._slots if s.future is None)
            slot.future = slot.executor.submit(execute, job)
        slot.token = token
        slot.remember_processes()
        return token

    def _replace(self, slot: _Slot) -> _Slot:
        slot.executor.shutdown(wait=False, cancel_futures=True)
        i = self._slots.index(slot)
        self._slots[i] = _Slot(self._ctx, self.threads)
        return self._slots[i]

    def poll(self, timeout: float) -> list[tuple[Any, dict[str, Any]]]:
        busy = {s.future: s for s in self._slots if s.future is not None}
        if not busy:
            return []
        done, _ = cf.wait(list(busy), timeout=timeout, return_when=cf.FIRST_COMPLETED)
        out = []
        for fut in done:
            slot = busy[fut]
            token = slot.token
            try:
                out.append((token, fut.result()))
                slot.future = slot.token = None
            except cf.process.BrokenProcessPool:
                codes = [c for c in slot.exit_codes() if c]
                what = f"exit code {codes[0]}" if codes else "no exit code"
                if codes and codes[0] < 0:
                    what = f"killed by signal {signal.Signals(-codes[0]).name}"
                out.append(_crash(token, f"worker process died ({what})"))
                self._replace(slot)
            except Exception as e:  # e.g. the job could not be pickled
                out.append((token, {"status": "error", "retryable": False, "error": f"{type(e).__name__}: {e}"}))
                slot.future = slot.token = None
        return out

    def cancel(self, token: Any) -> None:
        """Kill the worker running ``token`` (timeouts); the next poll reports it as crashed."""
        for s in self._slots:
            if s.token == token:
                for pid in s.pids():
                    try:
                        os.kill(pid, signal.SIGKILL)
                    except ProcessLookupError:
                        pass

    def close(self) -> None:
        for s in self._slots:
            s.executor.shutdown(wait=False, cancel_futures=True)
            for pid in s.pids():
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
        self._slots = []


class RayEngine:
    """Ray tasks: a fresh local Ray cluster by default, or an existing cluster at ``address``.

    A local cluster is started with ``num_cpus=workers``, no dashboard, a small object store and
    the node IP pinned to 127.0.0.1 (reliable in a sandbox without network). Each task asks for
    one CPU, so Ray runs as many at once as there are CPUs. If Ray is already initialised in this
    process (e.g. by a test), that connection is reused and left open on close.

    Args:
        workers: parallel tasks (local cluster CPUs; with ``address``: cap on tasks in flight,
            default = the cluster's CPUs).
        address: ``ray://host:10001`` or ``host:6379`` of an existing cluster; None = local.
        threads: BLAS/OpenMP/torch threads per task.
        object_store_mb: object store size of a local cluster (results are small dicts).
        runtime_env: Ray runtime environment for remote clusters (e.g. ``{"working_dir": ...}``).
    """

    name = "ray"

    def __init__(
        self,
        workers: int | None = None,
        address: str | None = None,
        threads: int = 1,
        object_store_mb: int = 200,
        runtime_env: dict[str, Any] | None = None,
    ) -> None:
        self.workers = workers
        self.address = address
        self.threads = threads
        self.object_store_mb = object_store_mb
        self.runtime_env = runtime_env
        self._owns = False
        self._refs: dict[Any, Any] = {}
        self._capacity = 1
        self._remote: Any = None

    @property
    def capacity(self) -> int:
        return self._capacity

    def describe(self) -> dict[str, Any]:
        return {
            "engine": "ray",
            "workers": self._capacity,
            "address": self.address or "local",
            "started_cluster": self._owns,
        }

    def start(
        self, warm_target: str | None = None, warm_params: dict[str, Any] | None = None, pin_cpus: bool = False
    ) -> None:
        os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
        os.environ.update(thread_env(self.threads))
        try:
            import ray
        except ImportError:
            raise VtrackError(RAY_MISSING) from None
        import logging

        if not ray.is_initialized():
            common = {"log_to_driver": False, "logging_level": logging.WARNING, "configure_logging": True}
            if self.runtime_env:
                common["runtime_env"] = self.runtime_env
            if self.address:
                ray.init(address=self.address, **common)
            else:
                n = max(1, int(self.workers or os.cpu_count() or 1))
                ray.init(
                    address="local",
                    num_cpus=n,
                    include_dashboard=False,
                    object_store_memory=int(self.object_store_mb) << 20,
                    _node_ip_address="127.0.0.1",
                    **common,
                )
            self._owns = True
        cpus = int(ray.cluster_resources().get("CPU", 1))
        self._capacity = max(1, int(self.workers)) if self.workers else max(1, cpus)
        # Our runner does the retries (same policy as the local engine), so Ray's are off.
        self._remote = ray.remote(num_cpus=1, max_retries=0)(execute)
        if warm_target:
            warm = ray.remote(num_cpus=1, max_retries=0)(warm_up)
            ray.get(
                [
                    warm.remote(warm_target, warm_params, i if pin_cpus else None, self.threads)
                    for i in range(self._capacity)
                ]
            )

    def free(self) -> int:
        return self._capacity - len(self._refs)

    def submit(self, job: dict[str, Any]) -> Any:
        ref = self._remote.remote(job)
        self._refs[ref] = job["key"]
        return ref

    def poll(self, timeout: float) -> list[tuple[Any, dict[str, Any]]]:
        import ray

        if not self._refs:
            return []
        # Return as soon as one task is done (num_returns=len would wait for all or the timeout, leaving
        # a finished worker idle up to `timeout`: ~10% of a 1 s task), then take whatever else is ready.
        ready, rest = ray.wait(list(self._refs), num_returns=1, timeout=timeout)
        if ready and rest:
            more, _ = ray.wait(rest, num_returns=len(rest), timeout=0)
            ready += more
        out = []
        for ref in ready:
            self._refs.pop(ref, None)
            try:
                out.append((ref, ray.get(ref)))
            except ray.exceptions.RayError as e:
                msg = str(e).strip().splitlines()
                out.append(_crash(ref, f"{type(e).__name__}: {msg[0] if msg else ''}"[:500]))
        return out

    def cancel(self, token: Any) -> None:
        import ray

        try:
            ray.cancel(token, force=True)
        except Exception:
            pass

    def close(self) -> None:
        if self._owns:
            import ray

            ray.shutdown()
            self._owns = False
        self._refs = {}


def make_engine(
    engine: str, workers: int | None = None, address: str | None = None, threads: int = 1, **options: Any
) -> LocalEngine | RayEngine:
    """Engine by name ("local" | "ray")."""
    if engine == "local":
        if address:
            raise VtrackError("--address is only meaningful with --engine ray")
        return LocalEngine(workers, threads=threads, **options)
    if engine == "ray":
        return RayEngine(workers, address=address, threads=threads, **options)
    raise VtrackError(f"unknown engine '{engine}' (choose local or ray)")
