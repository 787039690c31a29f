"""Where things live: the package's own assets, the repository root (checkouts only), shared data beside it,
and the cache for generated data."""

from __future__ import annotations

import os
from pathlib import Path

#: Repository root (the folder holding pyproject.toml, vtrack/, scenes/) of a checkout; for an installed wheel
#: this is site-packages, so nothing a user runs may depend on it (see :func:`assets_dir`).
REPO_ROOT = Path(__file__).resolve().parent.parent


def assets_dir() -> Path:
    """Data shipped inside the package (``vtrack/assets``: default scene, Allegro+DIGIT URDF and meshes, the
    soup-can mesh, sensor backgrounds, with their licences); scene files call it ``${assets}``."""
    return Path(__file__).resolve().parent / "assets"


def shared_dir() -> Path:
    """The ``shared/`` folder beside the repository (real data and assets).

    Overridable with ``VTRACK_SHARED``. The folder may be absent on a user's machine; callers
    that need it should check ``.exists()`` and say so.
    """
    env = os.environ.get("VTRACK_SHARED")
    if env:
        return Path(env).expanduser().resolve()
    return (REPO_ROOT.parent / "shared").resolve()


def shared_data_dir() -> Path:
    """``shared/data`` (see its README for what each folder holds)."""
    return shared_dir() / "data"


def cache_dir() -> Path:
    """Cache for generated data and trained models (never committed).

    ``VTRACK_CACHE`` overrides; default ``$XDG_CACHE_HOME/vtrack`` or ``~/.cache/vtrack``.
    """
    env = os.environ.get("VTRACK_CACHE")
    if env:
        path = Path(env).expanduser()
    else:
        base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
        path = base / "vtrack"
    path.mkdir(parents=True, exist_ok=True)
    return path


def scenes_dir() -> Path:
    """The repository's ``scenes/`` folder (example and benchmark scene YAMLs; checkouts only)."""
    return REPO_ROOT / "scenes"


def default_scene_path() -> Path:
    """The embedded default scene used by ``vtrack demo`` (shipped in the package)."""
    return assets_dir() / "scenes" / "default.yaml"
