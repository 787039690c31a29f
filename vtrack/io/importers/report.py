"""What an import wrote and what it skipped."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


@dataclass
class ImportReport:
    """Summary of one import.

    Attributes:
        source: the imported file or folder.
        session: the written session directory.
        frames: frames written per stream.
        skipped: counts of skipped items, keyed by a short reason (``"topic /x: unsupported type"``).
        notes: free-text remarks (assumptions made, defaults used).
        seconds: wall time of the import, s.
    """

    source: Path
    session: Path
    frames: dict[str, int] = field(default_factory=dict)
    skipped: Counter = field(default_factory=Counter)
    notes: list[str] = field(default_factory=list)
    seconds: float = 0.0

    def skip(self, reason: str, n: int = 1) -> None:
        self.skipped[reason] += n

    def note(self, text: str) -> None:
        if text not in self.notes:
            self.notes.append(text)

    @property
    def total_frames(self) -> int:
        return int(sum(self.frames.values()))

    def to_dict(self) -> dict[str, Any]:
        return {
            "source": str(self.source),
            "session": str(self.session),
            "seconds": round(self.seconds, 3),
            "frames": dict(self.frames),
            "skipped": dict(self.skipped),
            "notes": list(self.notes),
        }

    def lines(self) -> list[str]:
        """Human-readable summary, one item per line."""
        out = [f"imported {self.source} -> {self.session} in {self.seconds:.2f} s"]
        for k, v in self.frames.items():
            out.append(f"  {k}: {v} frames")
        if self.skipped:
            out.append("skipped:")
            out += [f"  {reason}: {n}" for reason, n in sorted(self.skipped.items())]
        if self.notes:
            out.append("notes:")
            out += [f"  {n}" for n in self.notes]
        return out
