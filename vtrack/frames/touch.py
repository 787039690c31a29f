"""Touch from tactile images: contact points, gel normals and penetration per sensor (sensor frame).

``TouchSource`` turns one tactile frame of one sensor into a :class:`Contact` with points in the sensor
frame of :mod:`vtrack.geometry.tactile_frame` (metres; ``z`` = outward gel normal), ready for
``T_world_sensor`` from forward kinematics.

Sources (``source``):
- ``"pipeline"`` (default, the only one that works on a real recording): the tactile IMAGE through the
  sensor's calibrated :class:`~vtrack.tactile.pipeline.TactilePipeline` (calibration file from
  ``vtrack calibrate`` named in the scene's ``tactile[i].calibration``). A sensor without a calibration is
  an error that says how to make one.
- ``"gt"``: the simulator's height maps, from :mod:`vtrack.eval.oracle` (an ORACLE ablation, labelled as such in
  every result; never the default).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from vtrack.errors import InputError

TOUCH_SOURCES = ("pipeline", "gt")


@dataclass
class Contact:
    """Contact of one sensor at one time (sensor frame, metres).

    Attributes:
        points: (N, 3) contact points on the gel surface (= on the object).
        normals: (N, 3) unit gel normals there (the object's outward normal is minus this).
        penetration_mm: (N,) indentation of the gel at each point, mm.
        in_contact: the sensor reports contact (N > 0).
        valid: the frame could be interpreted (False for saturated/dark frames: neither contact nor free).
    """

    points: np.ndarray
    normals: np.ndarray
    penetration_mm: np.ndarray
    valid: bool = True

    @property
    def in_contact(self) -> bool:
        return len(self.points) > 0


def _empty(valid: bool = True) -> Contact:
    return Contact(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), valid)


def tactile_sensor_names(reader: Any) -> list[str]:
    """Names of the tactile sensors recorded in a session (``tactile/<name>`` streams with frames)."""
    return sorted(k.split("/", 1)[1] for k, s in reader.streams.items() if k.startswith("tactile/") and s.n)


class TouchSource:
    """Contacts of a session's tactile sensors from their images (or, as an oracle, from GT height maps).

    Args:
        reader: an open :class:`~vtrack.io.session.SessionReader`.
        scene: the session's scene (tactile specs with calibrations).
        source: ``"pipeline"`` | ``"gt"`` (see module docstring).
        point_stride: keep every n-th contact pixel of the pipeline's working resolution.
        sensors: restrict to these sensors (default: all recorded tactile streams).
    """

    def __init__(
        self,
        reader: Any,
        scene: Any,
        source: str = "pipeline",
        point_stride: int = 3,
        sensors: list[str] | None = None,
        downsample: int | str = "auto",
    ) -> None:
        if source not in TOUCH_SOURCES:
            raise InputError(
                "unknown tactile source", field="tactile_source", expected="pipeline | gt (oracle)", got=source
            )
        self.source = source
        self.reader = reader
        self.point_stride = max(1, int(point_stride))
        names = tactile_sensor_names(reader) if sensors is None else list(sensors)
        specs = {t.name: (i, t) for i, t in enumerate(scene.tactile)}
        self.sensors = [s for s in names if s in specs and specs[s][1].type != "dome"]
        self.mm_per_px = {s: float(specs[s][1].mm_per_px) for s in self.sensors}
        self.threshold_mm = {s: float(specs[s][1].contact_threshold_mm) for s in self.sensors}
        self.size = {s: (int(specs[s][1].width), int(specs[s][1].height)) for s in self.sensors}
        self.streams = {}
        self.pipelines: dict[str, Any] = {}
        if source == "gt":
            from vtrack.eval.oracle import gt_tactile_streams

            self.streams = gt_tactile_streams(reader, self.sensors)
            return
        from vtrack import registry

        TactilePipeline = registry.load("tactile")
        for s in self.sensors:
            i, spec = specs[s]
            if spec.calibration is None:
                raise InputError(
                    f"tactile sensor '{s}' has no calibration",
                    path=getattr(scene, "source", None),
                    field=f"tactile[{i}].calibration",
                    expected="a file from `vtrack calibrate PRESSSET --out calib.npz` (ball presses "
                    "of this sensor; see docs/tactile.md)",
                )
            self.pipelines[s] = TactilePipeline._from_spec(spec, point_stride=self.point_stride, downsample=downsample)
            self.streams[s] = reader[f"tactile/{s}"]

    def times(self, sensor: str) -> np.ndarray:
        return self.streams[sensor].t

    def read(self, sensor: str, index: int | np.ndarray) -> Any:
        """Decoded input(s) of frame(s) ``index`` (disk IO + decompression)."""
        st = self.streams[sensor]
        if self.source == "gt":
            from vtrack.eval.oracle import read_gt_tactile

            return read_gt_tactile(st, index)
        return st["image"][index]

    def contact(self, sensor: str, raw: Any) -> Contact:
        """The contact of ``sensor`` from one decoded frame (what :meth:`read` returned for one index)."""
        from vtrack.tactile.pipeline import TactilePipeline

        mmpp = self.mm_per_px[sensor]
        if self.source == "gt":
            h, c = raw
            h = np.asarray(h, np.float64)
            m = (np.asarray(c) > 0) & np.isfinite(h) & (h > self.threshold_mm[sensor])
            if m.sum() < 3:
                return _empty()
            P, N = TactilePipeline.contact_points(h, m, mmpp, self.point_stride)
        else:
            P, N, quality = self.pipelines[sensor].contact_only(raw)  # points only: no maps, no statistics
            return _pipeline_contact(P, N, quality)
        return _finite_contact(P, N)

    def contacts(self, frames: list[tuple[str, Any]]) -> list[Contact]:
        """``[contact(sensor, raw) for sensor, raw in frames]``, the same values; with the tactile pipeline the
        frames go through it together (:func:`vtrack.tactile.pipeline.contact_only_many`: the four sensors of a
        time step cost about a third less CPU than one by one)."""
        if self.source != "pipeline" or len(frames) < 2:
            return [self.contact(s, raw) for s, raw in frames]
        from vtrack.tactile.pipeline import contact_only_many

        got = contact_only_many([self.pipelines[s] for s, _ in frames], [raw for _, raw in frames])
        return [_pipeline_contact(P, N, quality) for P, N, quality in got]


def _pipeline_contact(P: np.ndarray, N: np.ndarray, quality: str) -> Contact:
    if quality != "ok":
        return _empty(valid=False)
    if len(P) < 3:
        return _empty()
    return _finite_contact(P, N)


def _finite_contact(P: np.ndarray, N: np.ndarray) -> Contact:
    ok = np.isfinite(P).all(1) & np.isfinite(N).all(1)
    P, N = P[ok], N[ok]
    # the gel surface is z = -h (tactile_frame): penetration is -z, in mm
    return Contact(P, N, np.clip(-P[:, 2] * 1e3, 0.0, None), True)


def gel_free_points(width: int, height: int, mm_per_px: float, n_rows: int = 5, n_cols: int = 4) -> np.ndarray:
    """A coarse grid of points on the flat gel surface (sensor frame, m): where a sensor that reports no
    contact says the object is not (the tracker's non-penetration term)."""
    from vtrack.geometry.tactile_frame import pixel_grid_to_sensor_xy

    rows, cols = np.meshgrid(np.linspace(0, height - 1, n_rows), np.linspace(0, width - 1, n_cols), indexing="ij")
    xy = pixel_grid_to_sensor_xy(rows.ravel(), cols.ravel(), width, height, mm_per_px)
    return np.concatenate([xy, np.zeros((len(xy), 1))], axis=1)
