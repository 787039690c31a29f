"""Load one module file of an older code snapshot beside this tree's (the micro A/B scripts' old side).

``load("OLD/vtrack/tracking/window.py", "old_window")`` imports that file under a new name; its own ``vtrack``
imports still resolve to this tree, so only the file's own code is the old one.
"""

from __future__ import annotations

import importlib.util
import sys
from types import ModuleType


def load(path: str, name: str) -> ModuleType:
    """Import the Python file ``path`` as module ``name`` (registered in ``sys.modules``)."""
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise SystemExit(f"{path}: not a Python module file (expected a snapshot made with `git archive REV vtrack`)")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod
