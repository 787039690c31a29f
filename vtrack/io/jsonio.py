"""JSON output for every writer (CLI reports, results, session manifests, batch manifests): numpy-aware,
NaN/Inf-safe, atomic.

One owner for "write a file so that readers never see half of it": :func:`atomic_write_text` writes a
temporary file beside the target and renames it (``os.replace`` is atomic on POSIX); ``fsync=True`` also
flushes it to disk first, for files whose presence marks something complete (session and batch manifests).
"""

from __future__ import annotations

import json
import os
import uuid
from pathlib import Path
from typing import Any

import numpy as np


def to_jsonable(obj: Any, bad: list[str] | None = None, _prefix: str = "") -> Any:
    """Convert numpy scalars/arrays and paths for ``json.dump``; non-finite floats become None (JSON has no NaN,
    and a null says "not measured" more honestly than a made-up number) and, when ``bad`` is a list, their
    dotted key paths are appended to it. Other objects become their ``str``."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v, bad, f"{_prefix}{k}.") for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v, bad, f"{_prefix}{i}.") for i, v in enumerate(obj)]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist(), bad, _prefix)
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not np.isfinite(obj):
        if bad is not None:
            bad.append(_prefix.rstrip("."))
        return None
    if isinstance(obj, (str, int, float, bool)) or obj is None:
        return obj
    return str(obj)  # Path, enums, ...


def atomic_write_text(path: str | Path, text: str, *, fsync: bool = False) -> Path:
    """Write ``text`` via a uniquely named temporary file and rename (creates the parent folder)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{uuid.uuid4().hex[:6]}.tmp")
    try:
        with open(tmp, "w") as f:
            f.write(text)
            if fsync:
                f.flush()
                os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def atomic_savez(path: str | Path, **arrays: Any) -> Path:
    """``np.savez_compressed(path, **arrays)`` via a uniquely named temporary file and rename (creates the parent
    folder): a reader never sees a half-written cache file, and two writers of the same key do not collide."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.{uuid.uuid4().hex[:6]}.tmp.npz")
    try:
        np.savez_compressed(tmp, **arrays)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def atomic_torch_save(path: str | Path, obj: Any) -> Path:
    """``torch.save(obj, path)`` via a uniquely named temporary file and rename (creates the parent folder): a
    reader never sees a half-written weights file. torch is imported here, only when a file is written."""
    import torch

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{uuid.uuid4().hex[:6]}.tmp")
    try:
        torch.save(obj, tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def write_json(path: str | Path, data: Any, *, indent: int = 2, fsync: bool = False) -> Path:
    """Write ``data`` (through :func:`to_jsonable`) as JSON, atomically (see :func:`atomic_write_text`)."""
    return atomic_write_text(path, json.dumps(to_jsonable(data), indent=indent, allow_nan=False), fsync=fsync)
