"""ControlTac-style controllable tactile generation (issue #24; Luo et al., ControlTac, paper 004).

From ONE reference tactile image (and its no-contact background) generate the tactile image of the same
contact at another indentation depth / normal force (stage 1, force control) and at another in-plane pose
or contact mask (stage 2, position control, a zero-initialised ControlNet-style branch on the frozen
stage-1 net). Small CPU models trained here (``vtrack tactile generate-train``) on simulated indenter
presses and the training half of the real GelSight presses; weights ship in ``generator_weights.pt``.

Modules: :mod:`.data` (numpy: masks, poses, warps, indenters, training pairs), :mod:`.model` (torch
networks), :mod:`.train`, :mod:`.generator` (:class:`~.generator.TactileGenerator`), :mod:`.evaluate`
(``generate-eval`` on a labelled real press set). torch is imported only by ``model``/``train``/``generator``.
"""

from __future__ import annotations

from pathlib import Path


def default_weights_path() -> Path:
    """The shipped weights (``vtrack/tactile/generate/generator_weights.pt``; package data via ``*.pt``)."""
    return Path(__file__).resolve().parent / "generator_weights.pt"


def __getattr__(name: str):
    if name == "TactileGenerator":
        from vtrack.tactile.generate.generator import TactileGenerator

        return TactileGenerator
    raise AttributeError(name)
