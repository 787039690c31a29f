"""Scene-driven component registry with lazy imports.

A component is named by a short key and points to ``"module:attribute"``. Nothing is imported
until :func:`load` is called, so a touch-only scene never imports the RGB-D stack and a TSDF
scene never imports torch. :func:`required_components` says which components a scene needs.

Component classes expose ``from_scene(scene, **options)``; their options are typed dataclasses holding the
defaults (``TSDFConfig``, ``NeuralSDFConfig``, ``TrackerOptions``, ``TactileConfig``, ...). The real paths
choose their classes here: ``vtrack reconstruct`` / :func:`vtrack.fusion.reconstruct.reconstruct_session`
load ``reconstruction.<method>``, ``vtrack track`` / :func:`vtrack.tracking.run.build_tracker` load
``tracking.<mode>`` (and ``tracking.icp``), the frames layer loads ``tactile`` and ``segmentation`` (one
segmenter per camera, built with ``(kinematics, camera, T_world_camera)``), ``vtrack live`` loads
``live.<consumer>`` (built with ``(session, **options)``) and the live TSDF consumer ``reconstruction.tsdf``;
``vtrack batch`` runs the functions under ``batch.<task>`` (:mod:`vtrack.batch.tasks`).
"""

from __future__ import annotations

import importlib
from typing import Any

from vtrack.errors import VtrackError

#: key -> "module:attribute". Modules are imported only when the component is loaded.
COMPONENTS: dict[str, str] = {
    "kinematics": "vtrack.kinematics.hand:HandKinematics",
    "tactile": "vtrack.tactile.pipeline:TactilePipeline",  # options: TactileConfig
    # per-camera object segmentation of the frames layer (options: SegmentationOptions)
    "segmentation": "vtrack.frames.segmentation:HandAwareSegmenter",
    "dome": "vtrack.dome.reconstruct:DomeReconstructor",
    "rgbd": "vtrack.fusion.rgbd:RGBDFrontend",
    "reconstruction.tsdf": "vtrack.fusion.tsdf:TSDFReconstructor",
    "reconstruction.neural_sdf": "vtrack.fusion.neural_sdf:NeuralSDFReconstructor",
    "tracking.known_shape": "vtrack.tracking.tracker:KnownShapeTracker",
    "tracking.slam": "vtrack.tracking.slam:SLAMTracker",
    "tracking.icp": "vtrack.tracking.icp:ICPTracker",  # baseline (vtrack track --method icp)
    # live consumers (vtrack live --consumer <kind>): constructed with (session, **options)
    "live.track": "vtrack.live.consumers:TrackConsumer",
    "live.reconstruct": "vtrack.live.consumers:ReconstructConsumer",
    "live.null": "vtrack.live.consumers:NullConsumer",
    # batch tasks (vtrack batch TASK): functions fn(session_dir, out_dir, **options) -> metrics dict
    "batch.reconstruct": "vtrack.fusion.reconstruct:reconstruct_session",
    "batch.track": "vtrack.tracking.run:track_session",
    "batch.bench": "vtrack.batch.evaluate:bench_session",
    "batch.stats": "vtrack.batch.stats:session_stats",
}


def required_components(scene: Any) -> list[str]:
    """Component keys a scene needs, in pipeline order, from what it declares."""
    keys: list[str] = []
    modalities = scene.effective_modalities
    if scene.hand is not None and "touch" in modalities:
        keys.append("kinematics")
    if "touch" in modalities:
        if any(t.type != "dome" for t in scene.tactile):
            keys.append("tactile")
        if any(t.type == "dome" for t in scene.tactile):
            keys.append("dome")
    if "vision" in modalities:
        keys.append("rgbd")
    if scene.pipeline.reconstruction != "off":
        keys.append(f"reconstruction.{scene.pipeline.reconstruction}")
    if scene.pipeline.tracking != "off":
        keys.append(f"tracking.{scene.pipeline.tracking}")
    return keys


def import_target(target: str, what: str = "component") -> Any:
    """Import ``"module:attribute"`` and return the attribute (``what`` names it in the errors).

    Raises:
        VtrackError: the module cannot be imported (an optional back-end missing) or has no such attribute.
    """
    module, _, attr = target.partition(":")
    try:
        mod = importlib.import_module(module)
    except ModuleNotFoundError as e:
        raise VtrackError(f"{what} is not available: cannot import {module} ({e})") from None
    try:
        return getattr(mod, attr)
    except AttributeError:
        raise VtrackError(f"{what}: {module} has no '{attr}'") from None


def load(key: str) -> Any:
    """Import and return the component class registered under ``key``."""
    try:
        target = COMPONENTS[key]
    except KeyError:
        raise VtrackError(f"unknown component '{key}' (known: {sorted(COMPONENTS)})") from None
    return import_target(target, f"component '{key}'")


def build(key: str, scene: Any, **options: Any) -> Any:
    """Load component ``key`` and construct it from the scene."""
    return load(key).from_scene(scene, **options)


def build_all(scene: Any, **options: Any) -> dict[str, Any]:
    """Build every component the scene needs (and only those)."""
    return {key: build(key, scene, **options.get(key, {})) for key in required_components(scene)}
