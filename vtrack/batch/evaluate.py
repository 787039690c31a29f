"""``bench`` batch task: reconstruct and track one session, report accuracy metrics and time.

Results: ``out_dir/reconstruction/`` (what ``vtrack reconstruct`` writes) and
``out_dir/tracking/`` (what ``vtrack track`` writes); metrics are prefixed ``reconstruction.`` and
``tracking.``, with the wall time of each stage in ``<stage>.seconds``. A stage whose module is not
installed is skipped (``<stage>.available = False``); if neither is available the task fails.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from vtrack.batch.tasks import TASKS, accepted_params, is_available, resolve, warm_up_hook
from vtrack.errors import InputError

#: stage -> registry task name
STAGES = {"reconstruction": "reconstruct", "tracking": "track"}


def _call(task: str, session_dir: str, out_dir: Path, options: dict[str, Any]) -> dict[str, Any]:
    fn = resolve(TASKS[task])
    names, var_kw = accepted_params(fn)
    # Shared options (e.g. modalities) go to each stage that accepts them.
    kwargs = {k: v for k, v in options.items() if var_kw or k in names}
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    metrics = fn(session_dir, str(out_dir), **kwargs) or {}
    return {**metrics, "seconds": time.perf_counter() - t0, "available": True}


def warm_up(
    stages: list[str] | None = None,
    reconstruction: dict[str, Any] | None = None,
    tracking: dict[str, Any] | None = None,
    **shared: Any,
) -> None:
    """Run the warm-up hooks of the stages :func:`bench_session` will call (batch workers, before timing)."""
    own = {"reconstruction": reconstruction or {}, "tracking": tracking or {}}
    for stage in stages or STAGES:
        task = STAGES.get(stage)
        if task is None or not is_available(task):
            continue
        hook = warm_up_hook(TASKS[task])
        if hook is not None:
            hook(**{**shared, **own[stage]})


def bench_session(
    session_dir: str,
    out_dir: str,
    *,
    stages: list[str] | None = None,
    reconstruction: dict[str, Any] | None = None,
    tracking: dict[str, Any] | None = None,
    **shared: Any,
) -> dict[str, Any]:
    """Run the evaluation stages on one session.

    Args:
        stages: subset of ("reconstruction", "tracking"); default both.
        reconstruction / tracking: options of that stage only (e.g. ``{"method": "tsdf"}``).
        shared: options passed to every stage that accepts them (e.g. ``modalities``).
    """
    wanted = list(stages or STAGES)
    unknown = set(wanted) - set(STAGES)
    if unknown:
        raise InputError(
            "unknown bench stage", field="stages", expected=f"subset of {list(STAGES)}", got=sorted(unknown)
        )
    own = {"reconstruction": reconstruction or {}, "tracking": tracking or {}}
    metrics: dict[str, Any] = {}
    ran = 0
    for stage in wanted:
        task = STAGES[stage]
        if not is_available(task):
            metrics[stage] = {"available": False}
            continue
        metrics[stage] = _call(task, session_dir, Path(out_dir) / stage, {**shared, **own[stage]})
        ran += 1
    if not ran:
        # Not retryable (an InputError): installing the stage is the fix, not another attempt.
        raise InputError(
            "no bench stage is available", field="stages", expected=", ".join(TASKS[STAGES[s]] for s in wanted)
        )
    return metrics
