"""vtrack.threads.limit_threads caps thread pools that were loaded before it was called."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from vtrack.threads import THREAD_ENV


def test_limit_threads_caps_blas_pools_loaded_before_it():
    """numpy (and its OpenBLAS pool) is loaded first, as in the CLI and in a spawned child process; the cap still
    applies to that pool (without the run-time cap the tactile pipeline in the live touch process kept two BLAS
    threads and took twice the CPU per image)."""
    pytest.importorskip("threadpoolctl")
    code = (
        "import json, numpy\n"
        "from threadpoolctl import threadpool_info\n"
        "before = {p['filepath']: p['num_threads'] for p in threadpool_info() if p['user_api'] == 'blas'}\n"
        "from vtrack.threads import limit_threads\n"
        "limit_threads(1)\n"
        "after = {p['filepath']: p['num_threads'] for p in threadpool_info() if p['user_api'] == 'blas'}\n"
        "print(json.dumps([before, after]))\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in THREAD_ENV}  # the library default pool size
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120, check=True)
    before, after = json.loads(out.stdout.strip().splitlines()[-1])
    assert before and set(before) <= set(after)  # numpy's pool, loaded before the call (+ any loaded by it)
    assert all(n == 1 for n in after.values())
    if (os.cpu_count() or 1) > 1:
        assert max(before.values()) > 1  # the library default it overrode (one thread per core)
