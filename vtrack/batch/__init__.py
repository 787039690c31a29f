"""Batch runs of reconstruction, tracking and evaluation over many sessions (``vtrack batch``).

One task per session (or per chunk of a long session) on a local process pool or on Ray, with
atomic per-job result folders, a summary table, bounded retries and resumable re-runs.
Ray is optional (``pip install 'vtrack[distributed]'``); nothing here imports it at module level.
See ``docs/batch.md``.
"""

from vtrack.batch.runner import run_batch
from vtrack.batch.tasks import TASKS

__all__ = ["TASKS", "run_batch"]
