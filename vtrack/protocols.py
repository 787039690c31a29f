"""What every tracker and every reconstructor provides, whichever registry entry it is.

Code that drives components (``vtrack track``, ``vtrack reconstruct``, live consumers, benchmarks) relies on these
methods only, so a new implementation registered in :mod:`vtrack.registry` works everywhere once it satisfies the
protocol (``tests/test_lazy_imports.py`` checks every registered tracker and reconstructor).
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Tracker(Protocol):
    """Frame-by-frame object pose tracker (``T_world_object``, 4x4, metres)."""

    mode: str  # "known_shape" | "slam" | "icp" (what result files call the run)

    def step(self, frame: Any) -> np.ndarray:
        """Consume one :class:`~vtrack.tracking.frame.TrackingFrame`; return ``T_world_object`` at ``frame.t``."""
        ...

    def reset(self, T_world_object: np.ndarray) -> None:
        """Restart from a given pose (after a detected loss or from an external detector)."""
        ...

    @property
    def last_info(self) -> Any:
        """Diagnostics of the last step (:class:`~vtrack.tracking.window.StepInfo`), None before the first."""
        ...


@runtime_checkable
class Reconstructor(Protocol):
    """Object-model builder from object-frame observations (points in metres)."""

    def integrate_observation(self, obs: Any) -> Any:
        """Add one :class:`~vtrack.fusion.observations.Observation` (online use)."""
        ...

    def fit(self, observations: list) -> dict[str, Any]:
        """Offline: build the model from all observations; returns timing/size information."""
        ...

    def extract_mesh(self) -> tuple[np.ndarray, np.ndarray]:
        """Surface as (vertices (V, 3) m, faces (F, 3)); empty arrays when there is nothing yet."""
        ...
