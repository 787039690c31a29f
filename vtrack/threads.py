"""One place that caps the CPU threads of every numeric back-end vtrack uses.

Speed figures "on one core" are only honest when nothing runs a hidden thread pool: OpenBLAS/OpenMP
read their caps from the environment when they load, OpenCV sizes its own pool from the core count
(``cv2.setNumThreads``), torch has ``torch.set_num_threads``. Measured here: the tactile pipeline took
2.3 ms wall but 4.6 ms CPU per image with the default pools (two threads busy on two cores).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager

#: Environment variables that cap BLAS/OpenMP threads (read by the libraries when they load).
THREAD_ENV = (
    "OMP_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "MKL_NUM_THREADS",
    "NUMEXPR_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
)


#: the cap set by :func:`limit_threads` in this process (None: never called)
_LIMIT: int | None = None


def available_cpus() -> int:
    """CPUs this process may run on (its affinity mask where the OS has one, else ``os.cpu_count()``)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def thread_limit() -> int | None:
    """The thread cap :func:`limit_threads` set in this process (e.g. ``vtrack --threads 1``), or None."""
    return _LIMIT


def thread_env(threads: int) -> dict[str, str]:
    """The environment that caps BLAS/OpenMP pools at ``threads`` (for child processes, or before imports)."""
    return {k: str(max(1, int(threads))) for k in THREAD_ENV}


def limit_threads(threads: int) -> None:
    """Cap the thread pools at ``threads``: environment (libraries not loaded yet, child processes),
    OpenCV's pool (always: it is cheap to import and ignores the environment) and torch if loaded.

    Pools already loaded (numpy's and scipy's OpenBLAS, an OpenMP runtime) ignore the environment; they are
    capped through ``threadpoolctl``. The CLI imports numpy before its ``--threads`` option is read, and a
    spawned child process imports numpy (to unpickle its target) before it can call this: without the
    run-time cap both kept two BLAS threads (the tactile pipeline in the live touch process: 6.1-6.4 vs
    2.7-3.2 ms CPU per image, measured interleaved on the loaded 2-core machine).
    """
    global _LIMIT
    n = max(1, int(threads))
    _LIMIT = n
    os.environ.update(thread_env(n))
    try:
        import cv2

        cv2.setNumThreads(n)
    except ImportError:  # OpenCV is optional for some entry points
        pass
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(n)
    if any(m in sys.modules for m in ("numpy", "scipy", "open3d")):
        try:
            from threadpoolctl import threadpool_limits

            threadpool_limits(n)  # the pools loaded by now (process-wide, not a context)
        except ImportError:  # declared in pyproject; without it the environment caps only later loads
            pass


@contextmanager
def single_thread_blas() -> Iterator[None]:
    """One BLAS thread inside the block, unless this process's cap was set explicitly (:func:`limit_threads`, e.g.
    ``vtrack --threads N``), which is left as it is.

    For work on small matrices (the trackers' 6n x 6n solves, 3x3 products): a second BLAS thread finds nothing to
    share and spins. Measured 2026-11-28 on 2 cores, ``vtrack track`` of a 5 s session: 16.8 / 18.0 CPU s for
    10.9 / 11.5 s wall with the default pools, 11.4 / 11.5 CPU s for 11.3 / 11.5 s with ``OPENBLAS_NUM_THREADS=1``.
    OpenMP pools (Open3D's registration) are not touched.
    """
    if _LIMIT is not None:
        yield
        return
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # declared in pyproject
        yield
        return
    with threadpool_limits(1, user_api="blas"):
        yield
