"""Load scene YAML files into validated :class:`~vtrack.scene.schema.Scene` objects.

Errors name the file, the field (dotted path, list indices included) and what was expected.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml
from pydantic import ValidationError

from vtrack.errors import InputError
from vtrack.paths import REPO_ROOT, assets_dir, shared_dir
from vtrack.scene.schema import Scene

# Fields holding file paths, as (dotted path with '*' for list items).
_PATH_FIELDS = (
    "object.mesh",
    "hand.urdf",
    "tactile.*.calibration",
    "tactile.*.background",
)


def _expand(value: str, base: Path) -> str:
    s = (
        value.replace("${shared}", str(shared_dir()))
        .replace("${repo}", str(REPO_ROOT))
        .replace("${assets}", str(assets_dir()))
    )
    p = Path(s).expanduser()
    if not p.is_absolute():
        return str((base / p).resolve())
    if not p.exists() and "vtrack/assets/" in p.as_posix():
        # a session written by another vtrack install (older sessions stored the package's assets by absolute
        # path): the same file of this install's assets, if it is there
        mine = assets_dir() / p.as_posix().rsplit("vtrack/assets/", 1)[1]
        if mine.exists():
            return str(mine)
    return str(p)


def abbreviate_path(value: str) -> str:
    """``value`` with this install's assets folder and the shared folder written as ``${assets}`` / ``${shared}``,
    so a scene stored in a session does not point into one machine's checkout (the inverse of loading)."""
    for root, name in ((assets_dir(), "${assets}"), (shared_dir(), "${shared}")):
        try:
            return name + "/" + Path(value).resolve().relative_to(root.resolve()).as_posix()
        except ValueError:
            continue
    return value


def _walk(data: Any, parts: list[str], fn) -> None:
    if not parts or data is None:
        return
    head, rest = parts[0], parts[1:]
    if head == "*":
        if isinstance(data, list):
            for item in data:
                _walk(item, rest, fn)
        return
    if not isinstance(data, dict) or head not in data:
        return
    if rest:
        _walk(data[head], rest, fn)
    elif isinstance(data[head], str):
        data[head] = fn(data[head])


def format_validation_error(err: ValidationError, source: str | Path) -> InputError:
    """Turn a pydantic error into one InputError naming every bad field."""
    lines = []
    first_field = None
    for e in err.errors():
        loc = ".".join(str(x) for x in e["loc"]) or "(top level)"
        first_field = first_field or loc
        msg = e["msg"].removeprefix("Value error, ")
        got = e.get("input")
        got_s = "" if isinstance(got, dict) else f" (got {got!r})"
        lines.append(f"{loc}: {msg}{got_s}")
    # One line (the CLI's error contract): every bad field, separated by "; ".
    return InputError("invalid scene: " + "; ".join(lines), path=source, field=first_field)


def scene_from_dict(
    data: dict, base_dir: Path | None = None, source: Path | None = None, check_files: bool = True
) -> Scene:
    """Validate a scene given as a dict (e.g. parsed YAML or a session manifest)."""
    if not isinstance(data, dict):
        raise InputError(
            "a scene must be a mapping of fields", path=source, expected="YAML mapping", got=type(data).__name__
        )
    data = dict(data)
    base = base_dir or (source.parent if source else Path.cwd())
    import copy

    data = copy.deepcopy(data)
    for f in _PATH_FIELDS:
        _walk(data, f.split("."), lambda v: _expand(v, base))
    try:
        scene = Scene.model_validate(data)
    except ValidationError as err:
        raise format_validation_error(err, source or "<scene>") from None
    scene.source = source
    if check_files:
        _check_files(scene, source)
    return scene


def _check_files(scene: Scene, source: Path | None) -> None:
    checks: list[tuple[str, Path | None]] = [("object.mesh", scene.object.mesh)]
    if scene.hand is not None:
        checks.append(("hand.urdf", scene.hand.urdf))
    for i, t in enumerate(scene.tactile):
        checks += [(f"tactile.{i}.calibration", t.calibration), (f"tactile.{i}.background", t.background)]
    for field, p in checks:
        if p is not None and not Path(p).exists():
            hint = ""
            if str(shared_dir()) in str(p):
                hint = f" (the shared data folder {shared_dir()} is expected beside the repository)"
            raise InputError(f"file does not exist: {p}{hint}", path=source, field=field)


def load_scene(path: str | Path, check_files: bool = True) -> Scene:
    """Read and validate a scene YAML file.

    Raises:
        InputError: the file is missing, not YAML, or a field is invalid (message names it).
    """
    path = Path(path)
    if path.is_dir():
        raise InputError("expected a scene YAML file, got a directory", path=path)
    if not path.exists():
        raise InputError("scene file does not exist", path=path)
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        why = " ".join(str(getattr(err, "problem", None) or err).split())  # one line (CLI error contract)
        raise InputError(f"not valid YAML{where}: {why}", path=path) from None
    except UnicodeDecodeError as err:
        raise InputError(f"scene file is not UTF-8 text (byte {err.start})", path=path) from None
    return scene_from_dict(data, base_dir=path.parent, source=path.resolve(), check_files=check_files)
