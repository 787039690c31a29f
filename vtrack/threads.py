"""One place that caps the CPU threads of every numeric back-end vtrack uses.

Speed figures "on one core" are only honest when nothing runs a hidden thread pool: OpenBLAS/OpenMP
read their caps from the environment when they load, OpenCV sizes its own pool from the core count
(``cv2.setNumThreads``), torch has ``torch.set_num_threads``. Measured here: the tactile pipeline took
2.3 ms wall but 4.6 ms CPU per image with the default pools (two threads busy on two cores).
"""

from __future__ import annotations

import os
import sys

#: Environment variables that cap BLAS/OpenMP threads (read by the libraries when they load).
THREAD_ENV = (
    "OMP_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "MKL_NUM_THREADS",
    "NUMEXPR_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
)


def thread_env(threads: int) -> dict[str, str]:
    """The environment that caps BLAS/OpenMP pools at ``threads`` (for child processes, or before imports)."""
    return {k: str(max(1, int(threads))) for k in THREAD_ENV}


def limit_threads(threads: int) -> None:
    """Cap the thread pools at ``threads``: environment (libraries not loaded yet, child processes),
    OpenCV's pool (always: it is cheap to import and ignores the environment) and torch if loaded.

    numpy's BLAS pool is fixed once numpy is imported; call this before importing numpy (the CLI does)
    for a hard cap, or set the environment variables in the shell.
    """
    n = max(1, int(threads))
    os.environ.update(thread_env(n))
    try:
        import cv2

        cv2.setNumThreads(n)
    except ImportError:  # OpenCV is optional for some entry points
        pass
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(n)
