"""ORACLE inputs for ablations: the simulator's own knowledge fed to the pipeline in place of what it
estimates, always labelled (``"oracle": [...]``, ``"blind": false``) in results.

This module is the only place the frames layer gets ground truth from, and only when a run asks for an
oracle (``--tactile-source gt``, ``--segmentation gt``); blind runs never import it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from vtrack.errors import InputError


def gt_tactile_streams(reader: Any, sensors: list[str]) -> dict[str, Any]:
    """The simulator's height-map streams ``gt/tactile/<sensor>`` (fields ``height_mm``, ``contact``)."""
    out = {}
    for s in sensors:
        key = f"gt/tactile/{s}"
        if key not in reader:
            raise InputError(
                "tactile_source 'gt' (oracle) needs the simulator's height maps",
                path=reader.path,
                field=key,
                expected="a synthetic session with ground truth",
            )
        out[s] = reader[key]
    return out


def read_gt_tactile(stream: Any, index: int | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(height_mm, contact) of frame(s) ``index`` of a :func:`gt_tactile_streams` stream."""
    return stream["height_mm"][index], stream["contact"][index]


def gt_mask_stream(reader: Any, camera: str) -> Any:
    """The renderer's exact object masks of ``camera`` (``gt/camera/<cam>``, or the camera stream's own
    ``mask`` field in sessions written before the ``gt/`` layout)."""
    gs = reader.streams.get(f"gt/camera/{camera}")
    if gs is not None and "mask" in gs.fields:
        return gs
    cs = reader.streams.get(f"camera/{camera}")
    if cs is not None and "mask" in cs.fields:
        return cs
    raise InputError(
        "segmentation 'gt' (oracle) needs the simulator's masks", path=reader.path, field=f"gt/camera/{camera}/mask"
    )


def read_gt_mask(stream: Any, index: int) -> np.ndarray:
    """The object mask (uint8, 1 = object) of frame ``index`` of a :func:`gt_mask_stream` stream."""
    return np.asarray(stream["mask"][index])
