"""Error types with messages a user can act on (which file, which field, what was expected)."""

from __future__ import annotations

from pathlib import Path


class VtrackError(Exception):
    """Base class for errors that the CLI reports as a one-line message (no traceback)."""


class InputError(VtrackError, ValueError):
    """Bad user input: a file, field or array that does not match what is expected.

    Args:
        message: what is wrong.
        path: the file or directory concerned, if any.
        field: the field/key/array name concerned, if any.
        expected: a short description of what was expected.
        got: a short description of what was found.
    """

    def __init__(
        self,
        message: str,
        *,
        path: str | Path | None = None,
        field: str | None = None,
        expected: str | None = None,
        got: object | None = None,
    ) -> None:
        self.path = None if path is None else Path(path)
        self.field = field
        self.expected = expected
        self.got = got
        parts = []
        if path is not None:
            parts.append(f"{path}")
        if field:
            parts.append(f"field '{field}'")
        prefix = ": ".join(parts)
        text = f"{prefix}: {message}" if prefix else message
        if expected is not None:
            text += f" (expected {expected}"
            text += f", got {got!r})" if got is not None else ")"
        super().__init__(text)


def require_finite(name: str, value, *, path: str | Path | None = None) -> None:
    """Raise InputError if a numeric array/scalar holds NaN or Inf."""
    import numpy as np

    arr = np.asarray(value)
    if arr.dtype.kind in "fc" and not np.all(np.isfinite(arr)):
        bad = int(np.size(arr) - np.count_nonzero(np.isfinite(arr)))
        raise InputError(f"{bad} non-finite value(s)", path=path, field=name, expected="finite numbers")


def require_range(
    name: str,
    value,
    message: str,
    expected: str,
    lo: float = 0.0,
    hi: float = float("inf"),
    *,
    hi_inclusive: bool = True,
    lo_inclusive: bool = True,
) -> float:
    """``float(value)`` if it is a number in ``[lo, hi]`` (an open end with ``hi_inclusive=False`` /
    ``lo_inclusive=False``: ``hi_inclusive=False`` with the default ``hi`` = finite), else an InputError naming the
    field ``name`` with ``message`` and ``expected``; NaN and non-numbers are errors too."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise InputError(message, field=name, expected=expected, got=value) from None
    above = lo <= x if lo_inclusive else lo < x
    below = x <= hi if hi_inclusive else x < hi
    if not (above and below):  # NaN fails every comparison
        raise InputError(message, field=name, expected=expected, got=value)
    return x
