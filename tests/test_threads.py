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


def test_single_thread_blas_inside_the_block_unless_the_cap_was_set():
    """The trackers' block: one BLAS thread (a second spins on 6n x 6n solves: 17-18 vs 11 CPU s for the same wall time
    of `vtrack track` on a 5 s session), restored after; an explicit cap (``vtrack --threads N``) is left alone."""
    pytest.importorskip("threadpoolctl")
    code = (
        "import json, numpy\n"
        "from threadpoolctl import threadpool_info\n"
        "import vtrack.threads as th\n"
        "n = lambda: max(p['num_threads'] for p in threadpool_info() if p['user_api'] == 'blas')\n"
        "out = [n()]\n"
        "with th.single_thread_blas():\n"
        "    out.append(n())\n"
        "out.append(n())\n"
        "th.limit_threads(2)\n"
        "with th.single_thread_blas():\n"
        "    out.append(n())\n"
        "print(json.dumps(out))\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in THREAD_ENV}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120, check=True)
    default, inside, after, explicit = json.loads(out.stdout.strip().splitlines()[-1])
    assert inside == 1 and after == default
    if (os.cpu_count() or 1) > 1:
        assert default > 1 and explicit == 2  # vtrack --threads 2 is respected
