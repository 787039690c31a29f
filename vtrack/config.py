"""Typed option dataclasses built from plain dicts (CLI, scene files, batch options) with clear errors."""

from __future__ import annotations

from dataclasses import fields, replace
from typing import Any, TypeVar

from vtrack.errors import InputError

T = TypeVar("T")


def checked_fields(cls: type[T], opts: dict[str, Any], what: str) -> dict[str, Any]:
    """``opts`` unchanged if every key is a field of the dataclass ``cls`` and every value of a ``bool`` field is a
    bool; else an InputError naming the unknown keys (a typo in an option must not be silently ignored) or the field
    (a string such as ``"no"`` would read as true)."""
    fs = fields(cls)  # type: ignore[arg-type]
    names = {f.name for f in fs}
    unknown = set(opts) - names
    if unknown:
        raise InputError(
            f"unknown {what} option(s)", field=", ".join(sorted(unknown)), expected=f"some of {sorted(names)}"
        )
    for f in fs:
        if f.name in opts and f.type in ("bool", bool) and type(opts[f.name]).__name__ not in ("bool", "bool_"):
            raise InputError(f"{what} option must be true or false", field=f.name, expected="bool", got=opts[f.name])
    return opts


def build_config(cls: type[T], opts: dict[str, Any] | None, what: str, base: T | None = None) -> T:
    """A ``cls`` (a dataclass holding a component's defaults) with ``opts`` applied over ``base`` (default:
    the dataclass defaults). Unknown keys raise one :class:`InputError` naming them (see
    :func:`checked_fields`); ``what`` names the component in that message."""
    o = checked_fields(cls, dict(opts or {}), what)
    return replace(base, **o) if base is not None else cls(**o)  # type: ignore[type-var]
