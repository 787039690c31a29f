"""Task registry for batch runs: task name -> ``"module:function"``, imported lazily in the worker.

A task function has the signature::

    fn(session_dir: str, out_dir: str, **options) -> dict   # JSON-able metrics

It reads one session, writes its result files into ``out_dir`` (an empty folder that the batch
engine creates and later renames into place, so the function never needs to be atomic itself) and
returns its metrics. Functions may additionally accept either or both of

- ``time_range: tuple[float, float]``: half-open session-time interval ``[t0, t1)`` in seconds;
- ``frames: tuple[int, int]``: half-open frame interval ``[i0, i1)`` of the session's reference
  stream (see :func:`vtrack.batch.plan.reference_stream`),

and then a long session can be split into chunks, one task per chunk (``--chunk-frames``).
Nothing is imported until a worker runs the task, so ``import vtrack.batch`` stays cheap and a
registry entry whose module does not exist yet only fails when it is used.
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
from collections.abc import Callable
from typing import Any

from vtrack.errors import InputError, VtrackError
from vtrack.registry import COMPONENTS, import_target

#: Task name -> "module:function", the ``batch.<task>`` entries of :data:`vtrack.registry.COMPONENTS`.
#: ``reconstruct`` and ``track`` are the pipeline entry points; ``bench`` runs both and reports accuracy and
#: time; ``stats`` is a cheap session QA summary.
TASKS: dict[str, str] = {k.split(".", 1)[1]: v for k, v in COMPONENTS.items() if k.startswith("batch.")}

#: Parameter names through which a task accepts a chunk of a session.
CHUNK_PARAMS = ("time_range", "frames")


def target_of(task: str) -> str:
    """``"module:function"`` of a registered task name, or ``task`` itself when it already is one."""
    if task in TASKS:
        return TASKS[task]
    if ":" in task:
        return task
    raise InputError(
        "unknown batch task", field="task", expected=f"one of {sorted(TASKS)} or 'module:function'", got=task
    )


def is_available(task: str) -> bool:
    """True when the task's module can be found (without importing it)."""
    module = target_of(task).partition(":")[0]
    try:
        return importlib.util.find_spec(module) is not None
    except (ModuleNotFoundError, ValueError):
        return False


def resolve(target: str) -> Callable[..., Any]:
    """Import ``"module:function"`` and return the function.

    Raises:
        VtrackError: the module or the function does not exist.
    """
    module, _, attr = target.partition(":")
    if not module or not attr:
        raise InputError("task target must look like 'module:function'", field="task", got=target)
    fn = import_target(target, f"batch task '{target}'")
    if not callable(fn):
        raise VtrackError(f"batch task '{target}': {module}.{attr} is not a function")
    return fn


def warm_up_hook(target: str) -> Callable[..., Any] | None:
    """The ``warm_up(**params)`` function of a task's module, if it defines one (imports the module)."""
    import sys

    fn = resolve(target)
    hook = getattr(sys.modules.get(fn.__module__), "warm_up", None)
    return hook if callable(hook) else None


def accepted_params(fn: Callable[..., Any]) -> tuple[set[str], bool]:
    """Names of the keyword parameters ``fn`` accepts, and whether it takes ``**kwargs``."""
    sig = inspect.signature(fn)
    names = {
        p.name
        for p in sig.parameters.values()
        if p.kind in (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
    }
    var_kw = any(p.kind is inspect.Parameter.VAR_KEYWORD for p in sig.parameters.values())
    return names, var_kw


def chunk_params(fn: Callable[..., Any]) -> list[str]:
    """Which of :data:`CHUNK_PARAMS` the task accepts explicitly (``**kwargs`` does not count)."""
    names, _ = accepted_params(fn)
    return [p for p in CHUNK_PARAMS if p in names]
