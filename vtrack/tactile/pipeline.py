"""Real-time tactile pipeline: BGR image -> slopes -> height (mm) -> contact mask -> sensor-frame points.

Registry key ``"tactile"`` (``TactilePipeline.from_scene(scene, sensor_name=None)``). Points and normals are in
the sensor frame of :mod:`vtrack.geometry.tactile_frame` (metres), ready for ``T_world_sensor`` from forward
kinematics. Optional stages: marker shear (:mod:`~vtrack.tactile.markers`), slip
(:mod:`~vtrack.tactile.slip`) and force (:mod:`~vtrack.tactile.force`).

Speed: slopes and Poisson run at a working resolution ``downsample`` times smaller than the image (slopes
are in mm/mm so they do not depend on resolution; the height map is returned at full image size).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vtrack.errors import InputError
from vtrack.geometry.tactile_frame import height_to_points
from vtrack.tactile.calibration import (
    Calibration,
    drift_offset,
    drift_offsets,
    gate_mask_images,
    lambertian_calibration,
    shift_background,
)
from vtrack.tactile.contact import ContactStats, contact_mask, contact_stats
from vtrack.tactile.poisson import poisson_dct, poisson_dct_stack, poisson_fft, poisson_masked_lsq


@dataclass
class TactileFrame:
    """Output of :meth:`TactilePipeline.process` for one image.

    Attributes:
        height_mm: (H, W) float32 indentation into the gel, mm (>= 0 in contact, ~0 elsewhere).
        contact: (H, W) bool contact mask.
        points: (N, 3) float64 contact points, sensor frame, m.
        normals: (N, 3) float64 outward unit normals at ``points`` (sensor frame).
        stats: contact area / centroid / axes / depth.
        shear: marker shear estimate (``markers.ShearEstimate``) or None.
        slip: slip signal (``slip.SlipState``) or None.
        force: force estimate (``force.ForceEstimate``) or None.
        timings_ms: per-stage wall time, ms.
    """

    height_mm: np.ndarray
    contact: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    stats: ContactStats
    shear: Any = None
    slip: Any = None
    force: Any = None
    timings_ms: dict[str, float] = field(default_factory=dict)
    quality: str = "ok"  # "ok" | "saturated" | "dark" (then no height/contact is reported)
    drift: tuple[float, float, float] = (0.0, 0.0, 0.0)  # removed global colour offset vs background (B, G, R)

    @property
    def in_contact(self) -> bool:
        return self.stats.area_px > 0


def _sim_background(spec: Any) -> np.ndarray | None:
    """The no-contact frame the simulator renders this sensor on (scenes with a ``sim`` section), so a
    synthetic session whose first frame is already in contact still has the right reference. None when it
    cannot be read (the first frame is used then)."""
    from vtrack.tactile.sensors import default_background

    try:
        return np.asarray(default_background(spec.type, spec.width, spec.height, spec.background), np.uint8)
    except Exception:  # noqa: BLE001 - any failure falls back to the first-frame background
        return None


def auto_downsample(shape_hw: tuple[int, int]) -> int:
    """Working-resolution factor chosen from the tactile benchmark's Pareto front (see TactilePipeline)."""
    pixels = int(shape_hw[0]) * int(shape_hw[1])
    if pixels >= 640 * 480:
        return 4
    if pixels >= 320 * 240:
        return 2
    return 1


@dataclass
class TactileConfig:
    """Tuning of :class:`TactilePipeline` and its defaults (the one place they are set).

    Attributes:
        solver: ``dct`` (default), ``fft`` or ``lsq`` (masked sparse LSQ on the colour-change region).
        downsample: working-resolution factor for slopes + Poisson (1 = full resolution); outputs are
            resized back to full resolution. ``"auto"`` (default) picks the operating point on the Pareto
            front of ``vtrack bench tactile`` (docs/benchmarks/tactile.md) from the image size: 1 below
            320x240 pixels, 2 from 320x240 (~3 ms/frame, normal error within 0.3 deg of full resolution),
            4 from 640x480 (full resolution there costs 5x the time for no accuracy gain).
        contact_threshold_mm: minimum indentation counted as contact (noise-aware floor, see contact.py).
        contact_rel: also require ``h > contact_rel * max(h)`` (rejects the deformed skirt around a contact).
        point_stride: keep every n-th contact pixel (in working pixels) as a point.
        markers / slip: optional extra stages (marker tracking, slip detection).
        drift_compensation: remove a global per-channel colour offset (illumination/background drift),
            estimated as the median colour change over the frame (contact covers a minority of pixels); only
            applied when the median absolute deviation of the change is <= ``drift_max_spread`` grey levels.
        gate_k: noise-aware colour gate: pixels whose (5x5 mean) total colour change is below
            ``max(calibration gate, gate_k * median total change)`` are treated as flat gel.
        bad_fraction: frames with more than this fraction of saturated (>= 250) or dark (<= 5) pixels are
            reported with ``quality`` "saturated"/"dark" and no contact instead of a meaningless height map.
    """

    solver: str = "dct"
    downsample: int | str = "auto"
    contact_threshold_mm: float = 0.05
    contact_rel: float = 0.15
    point_stride: int = 1
    markers: bool = False
    slip: bool = False
    drift_compensation: bool = True
    drift_max_spread: float = 6.0
    gate_k: float = 2.0
    bad_fraction: float = 0.5


class TactilePipeline:
    """Image -> height -> contact -> points for one vision-based tactile sensor.

    Args:
        calib: a :class:`Calibration` (or path to its ``.npz``); None -> Lambertian model (matches
            :func:`vtrack.tactile.render.render_tactile_image` without calibration).
        mm_per_px: pixel pitch (default: the calibration's).
        background: no-contact BGR frame (default: the calibration's; with neither, the first frame).
        image_shape: (H, W) px of the images when there is no calibration.
        force_model: optional force estimator (:mod:`vtrack.tactile.force`).
        sensor_name: the scene's name of the sensor.
        config: tuning (:class:`TactileConfig`); ``opts`` override single fields of it by name
            (``TactilePipeline(calib, downsample=2)``); an unknown name raises :class:`InputError`.
    """

    def __init__(
        self,
        calib: Calibration | str | Path | None = None,
        *,
        mm_per_px: float | None = None,
        background: np.ndarray | None = None,
        image_shape: tuple[int, int] | None = None,
        force_model: Any = None,
        sensor_name: str = "tactile",
        config: TactileConfig | None = None,
        **opts: Any,
    ) -> None:
        from vtrack.config import build_config

        self.config = c = build_config(TactileConfig, opts, "tactile pipeline", base=config)
        if isinstance(calib, (str, Path)):
            calib = Calibration.load(calib)
        if c.solver not in ("dct", "fft", "lsq"):
            raise InputError("unknown Poisson solver", field="solver", expected="dct | fft | lsq", got=c.solver)
        downsample = c.downsample
        self._auto_downsample = downsample == "auto"
        if self._auto_downsample:
            downsample = 1  # resolved from the image size in set_background
        elif not isinstance(downsample, (int, np.integer)) or int(downsample) < 1:
            raise InputError("downsample must be an integer >= 1 or 'auto'", field="downsample", got=downsample)
        self.sensor_name = sensor_name
        self.calib = calib
        self.mm_per_px = float(mm_per_px if mm_per_px is not None else (calib.mm_per_px if calib else 0.0))
        if not self.mm_per_px > 0:
            raise InputError("mm_per_px is required without a calibration", field="mm_per_px", expected="> 0")
        self.solver = c.solver
        self.downsample = int(downsample)
        self.contact_threshold_mm = float(c.contact_threshold_mm)
        self.contact_rel = float(c.contact_rel)
        self.point_stride = max(1, int(c.point_stride))
        self.drift_compensation = bool(c.drift_compensation)
        self.drift_max_spread = float(c.drift_max_spread)
        self.gate_k = float(c.gate_k)
        self.bad_fraction = float(c.bad_fraction)
        self.image_shape = image_shape if calib is None else calib.shape
        self._bg_full: np.ndarray | None = None
        self._bg_work: np.ndarray | None = None
        self._shifted: tuple | None = None
        self._bg_from_frame = False  # background taken from a frame (may itself have been in contact)
        self._model: Calibration | None = None
        self.noise_mm = float(calib.info.get("height_noise_mm", 0.0)) if calib is not None else 0.0
        bg = background if background is not None else (calib.background if calib is not None else None)
        if bg is not None:
            self.set_background(bg)
        self.markers = None
        if c.markers:
            from vtrack.tactile.markers import MarkerTracker

            self.markers = MarkerTracker(mm_per_px=self.mm_per_px)
        self.slip = None
        if c.slip:
            from vtrack.tactile.slip import SlipDetector

            self.slip = SlipDetector()
        self.force_model = force_model
        self.sensors: dict[str, TactilePipeline] = {sensor_name: self}

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_scene(cls, scene: Any, sensor_name: str | None = None, **options: Any) -> TactilePipeline:
        """Pipeline of one tactile sensor of a scene (default: the first non-dome sensor).

        All non-dome sensors get their own pipeline in ``.sensors`` (name -> pipeline).
        """
        specs = [t for t in scene.tactile if t.type != "dome"]
        if not specs:
            raise InputError("scene has no (non-dome) tactile sensor", field="tactile")
        if sensor_name is not None and sensor_name not in {t.name for t in specs}:
            raise InputError(
                "unknown tactile sensor",
                field="sensor_name",
                expected=" | ".join(t.name for t in specs),
                got=sensor_name,
            )
        built = {t.name: cls._from_spec(t, synthetic=scene.sim is not None, **options) for t in specs}
        main = built[sensor_name or specs[0].name]
        main.sensors = built
        return main

    @classmethod
    def _from_spec(cls, spec: Any, synthetic: bool = False, **options: Any) -> TactilePipeline:
        from vtrack.tactile.pressset import read_bgr

        bg = read_bgr(spec.background) if spec.background is not None else None
        if bg is None and spec.calibration is None and synthetic and "background" not in options:
            bg = _sim_background(spec)
        opts = {"contact_threshold_mm": spec.contact_threshold_mm, **options}
        bg = opts.pop("background", bg)
        return cls(
            spec.calibration,
            mm_per_px=spec.mm_per_px,
            background=bg,
            image_shape=(spec.height, spec.width),
            sensor_name=spec.name,
            **opts,
        )

    def for_sensor(self, name: str) -> TactilePipeline:
        try:
            return self.sensors[name]
        except KeyError:
            raise InputError(
                "unknown tactile sensor", field="sensor", expected=" | ".join(self.sensors), got=name
            ) from None

    # ------------------------------------------------------------------ background / working resolution
    def _check(self, image: np.ndarray, name: str = "image") -> np.ndarray:
        img = np.asarray(image)
        if img.ndim == 2:  # grey has lost the colour -> slope information the calibration reads
            raise InputError(
                "tactile image is greyscale; the calibration needs the colour channels",
                field=name,
                expected="(H, W, 3) BGR",
                got=img.shape,
            )
        if img.ndim != 3 or img.shape[2] != 3 or img.size == 0:
            raise InputError("tactile image must be (H, W, 3) BGR", field=name, expected="(H, W, 3)", got=img.shape)
        if self.image_shape is not None and img.shape[:2] != tuple(self.image_shape):
            raise InputError(
                "image size differs from the sensor calibration",
                field=name,
                expected=f"{self.image_shape[0]}x{self.image_shape[1]} (HxW)",
                got=img.shape[:2],
            )
        if img.dtype != np.uint8:
            # float images: NaN/Inf -> 0 and clip into 8 bits (the calibration is defined on 8-bit colour)
            img = np.clip(np.nan_to_num(img.astype(np.float32), nan=0.0, posinf=255.0, neginf=0.0), 0, 255)
            img = img.astype(np.uint8)
        return img

    def _to_work(self, img: np.ndarray) -> np.ndarray:
        import cv2

        if self.downsample == 1:
            return img
        H, W = img.shape[:2]
        w, h = max(1, W // self.downsample), max(1, H // self.downsample)
        return cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)

    def set_background(self, background: np.ndarray) -> None:
        """Set the no-contact reference frame (e.g. re-taken when the lighting drifts)."""
        bg = self._check(background, "background")
        if self._auto_downsample:
            self.downsample = auto_downsample(bg.shape[:2])
        if self.image_shape is None:
            self.image_shape = bg.shape[:2]
        self._bg_full = bg
        self._bg_work = self._to_work(bg)
        self._shifted = None
        self._bg_from_frame = False  # callers that derive it from a live frame set this afterwards
        wh = self._bg_work.shape[:2]
        if self.calib is None:
            self._model = lambertian_calibration(self._bg_work, self.mm_per_px * self.downsample)
        elif self.downsample == 1:
            self._model = self.calib
        else:
            self._model = self.calib.resized(self._bg_work)
        assert self._model.shape == wh

    @property
    def background(self) -> np.ndarray | None:
        return self._bg_full

    # ------------------------------------------------------------------ processing
    def height_work(self, image_bgr: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(checked full-res image, height_mm at working resolution float32, colour-change gate there)."""
        img, hw, gate, _, _ = self._height_work(image_bgr)
        return img, hw, gate

    def _height_work(self, image_bgr: np.ndarray):
        img, work, quality = self._work_image(image_bgr)
        gate, quality, drift, g = self._slopes_work(work, quality)
        if g is None:
            return img, np.zeros(work.shape[:2], np.float32), gate, quality, drift
        return img, self._integrate(g[0], g[1], gate), gate, quality, drift

    def _work_image(self, image_bgr: np.ndarray) -> tuple[np.ndarray, np.ndarray, str]:
        """(checked full-res image, image at the working resolution, quality "ok" | "saturated" | "dark")."""
        img = self._check(image_bgr)
        if self._bg_full is None:
            self.set_background(img)  # first frame is the reference: assumed out of contact
            self._bg_from_frame = True
        work = self._to_work(img)
        probe = work[::4, ::4]
        quality = "ok"
        if probe.size:
            # channel by channel (the same booleans): numpy's reductions over a last axis of 3 are slow
            b, g, r = probe[..., 0], probe[..., 1], probe[..., 2]
            if ((b >= 250) & (g >= 250) & (r >= 250)).mean() > self.bad_fraction:
                quality = "saturated"
            elif ((b <= 5) & (g <= 5) & (r <= 5)).mean() > self.bad_fraction:
                quality = "dark"
        return img, work, quality

    def _slopes_work(self, work: np.ndarray, quality: str, drift_level: tuple | None = None):
        """(colour-change gate, quality, drift, (gx, gy) in mm/px at the working resolution or None where the
        height is flat zero: a bad frame or no colour change). ``drift_level``: this frame's
        ``drift_offset(work, background)`` when already computed (:func:`contact_only_many`)."""
        model = self._model
        bg = self._bg_work
        if quality != "ok":
            return np.zeros(work.shape[:2], bool), quality, (0.0, 0.0, 0.0), None
        drift = (0.0, 0.0, 0.0)
        gate_level = float(model.info.get("gate", 6.0))
        if work[::4, ::4].size:
            if drift_level is None:
                drift_level = drift_offset(work, bg, self.drift_max_spread if self.drift_compensation else -1.0)
            med, level = drift_level
            if med.any():
                drift = tuple(float(x) for x in med)
                if self._shifted is None or self._shifted[0] != drift:  # drift changes slowly: reuse
                    self._shifted = (drift, shift_background(bg, med))
                bg = self._shifted[1]
            # noise-aware gate: colour changes below gate_k x the frame's median change are sensor noise
            gate_level = max(gate_level, self.gate_k * level)
        gate = gate_mask_images(work, bg, gate_level)
        if not gate.any():
            # no colour change anywhere: zero slopes integrate to a flat gel (what the solvers return, exactly)
            return gate, quality, drift, None
        gx, gy = model.slopes_from_images(work, bg, gate)
        s = np.float32(self.mm_per_px * self.downsample)
        gx *= s
        gy *= s
        return gate, quality, drift, (gx, gy)

    def _integrate(self, gx: np.ndarray, gy: np.ndarray, gate: np.ndarray) -> np.ndarray:
        """Height (mm, float32) from slopes in mm/px with this pipeline's Poisson solver."""
        import cv2

        if self.solver == "dct":
            hw = poisson_dct(gx, gy, dtype=np.float32)
        elif self.solver == "fft":
            hw = poisson_fft(gx, gy)
        else:
            # the gel skirt around a deep press has little colour change: integrate over a margin of ~5 % of
            # the image around the gate (3 px margin: 7.9 deg on the real presses, 11 px: 5.5 deg = DCT)
            k = max(5, min(gate.shape) // 20) | 1
            m = cv2.dilate(gate.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))) > 0
            hw = poisson_masked_lsq(gx, gy, m)
        return hw.astype(np.float32, copy=False)

    def height(self, image_bgr: np.ndarray) -> np.ndarray:
        """Height map (mm, float32) at full image resolution."""
        img, hw, _ = self.height_work(image_bgr)
        return self._to_full(hw, img.shape[:2])

    def _to_full(self, a: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        import cv2

        if self.downsample == 1 or a.shape[:2] == tuple(shape):
            return a
        H, W = shape
        if a.dtype == bool:
            return cv2.resize(a.view(np.uint8), (W, H), interpolation=cv2.INTER_NEAREST).view(bool)
        return cv2.resize(a, (W, H), interpolation=cv2.INTER_LINEAR)

    def process(
        self, image_bgr: np.ndarray | str, image: np.ndarray | None = None, full_res: bool = True
    ) -> TactileFrame:
        """Run the pipeline on one BGR image of this sensor (see :class:`TactileFrame`).

        ``process(image)`` uses this sensor; ``process(sensor_name, image)`` dispatches to the pipeline of
        another sensor of the scene (``from_scene`` builds one per sensor).

        Contact detection and point lifting run at the working resolution (points are spaced
        ``downsample * point_stride`` image pixels); height and mask are returned at full resolution, or
        at the working resolution with ``full_res=False`` (consumers of the points only: saves two resizes).
        """
        if isinstance(image_bgr, str):
            if image is None:
                raise InputError("process(sensor_name, image) needs an image", field="image")
            return self.for_sensor(image_bgr).process(image, full_res=full_res)
        t0 = time.perf_counter()
        img, hw, mask_w, quality, drift, t1 = self._contact_work(image_bgr)
        s_work = self.mm_per_px * self.downsample
        stats = contact_stats(hw, mask_w, s_work)
        if self.downsample > 1 and stats.area_px:
            d = self.downsample
            stats.area_px *= d * d
            stats.centroid_px = tuple(c * d + (d - 1) / 2.0 for c in stats.centroid_px)
            stats.axes_px = tuple(a * d for a in stats.axes_px)
        t2 = time.perf_counter()
        pts, nrm = self.contact_points(hw, mask_w, s_work, self.point_stride)
        t3 = time.perf_counter()
        H, W = img.shape[:2]
        if not full_res and self.slip is None:  # slip reads the full-resolution contact mask
            H, W = hw.shape  # working-resolution maps: _to_full is then a no-op
        frame = TactileFrame(
            self._to_full(hw, (H, W)),
            self._to_full(mask_w, (H, W)),
            pts,
            nrm,
            stats,
            timings_ms={"height": (t1 - t0) * 1e3, "contact": (t2 - t1) * 1e3, "points": (t3 - t2) * 1e3},
            quality=quality,
            drift=drift,
        )
        if self.markers is not None:
            frame.shear = self.markers.update(img)
        if self.slip is not None:
            frame.slip = self.slip.update(img, frame.contact)
        if self.force_model is not None:
            frame.force = self.force_model.predict_frame(frame)
        frame.timings_ms["total"] = (time.perf_counter() - t0) * 1e3
        return frame

    def _contact_work(self, image_bgr: np.ndarray):
        """(checked image, height_mm, contact mask (both at the working resolution), quality, drift, time after the
        height map): the part of :meth:`process` that every output needs."""
        img, hw, gate, quality, drift = self._height_work(image_bgr)
        if self._bg_from_frame and hw.size and self._background_was_pressed(hw):
            # The reference frame was itself in contact: this frame is the flat gel (a pure "negative press").
            self.set_background(img)
            self._bg_from_frame = True
            img, hw, gate, quality, drift = self._height_work(img)
        t1 = time.perf_counter()
        return img, hw, self._contact_mask(hw, gate), quality, drift, t1

    def _contact_mask(self, hw: np.ndarray, gate: np.ndarray) -> np.ndarray:
        return contact_mask(hw, self.contact_threshold_mm, noise_mm=self.noise_mm, rel=self.contact_rel, diff_mask=gate)

    def contact_only(self, image_bgr: np.ndarray) -> tuple[np.ndarray, np.ndarray, str]:
        """Sensor-frame contact points (N, 3, m), their gel normals and the frame quality of one BGR image: what a
        tracker consumes, the same values as :meth:`process` gives (same state updates) without the contact
        statistics, full-size maps and the frame record (~15 % of the pipeline's CPU on a DIGIT at 1/4 resolution).
        With markers, slip or force attached it runs :meth:`process` (their state must follow every frame)."""
        if self.markers is not None or self.slip is not None or self.force_model is not None:
            fr = self.process(image_bgr, full_res=False)
            return fr.points, fr.normals, fr.quality
        _, hw, mask_w, quality, _, _ = self._contact_work(image_bgr)
        pts, nrm = self.contact_points(hw, mask_w, self.mm_per_px * self.downsample, self.point_stride)
        return pts, nrm, quality

    def _batchable(self) -> bool:
        """Whether :func:`contact_only_many` may take this pipeline's frames with others': no stage with state
        of its own (markers, slip, force) and a fixed background (not one taken from a live frame, which the
        next frame may replace)."""
        return (
            self.markers is None
            and self.slip is None
            and self.force_model is None
            and self._bg_full is not None
            and not self._bg_from_frame
        )

    def _background_was_pressed(self, hw: np.ndarray) -> bool:
        """A frame-derived background that contained a press shows up as a dent *out of* the gel."""
        tau = max(self.contact_threshold_mm, 3.0 * self.noise_mm, 0.05)
        lo, hi = float(hw.min()), float(hw.max())
        return lo < -3.0 * tau and hi < 0.5 * abs(lo)

    @staticmethod
    def contact_points(
        height_mm: np.ndarray, mask: np.ndarray, mm_per_px: float, stride: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        """Sensor-frame points (m) and normals of the contact pixels of a height map with pitch ``mm_per_px``.

        Only the contact bounding box is lifted (with ``height_to_points``), then shifted to full-map coordinates.
        """
        if not mask.any():
            return np.zeros((0, 3)), np.zeros((0, 3))
        H, W = mask.shape
        rows = np.flatnonzero(mask.any(axis=1))
        cols = np.flatnonzero(mask.any(axis=0))
        r0, r1 = max(rows[0] - 1, 0), min(rows[-1] + 2, H)
        c0, c1 = max(cols[0] - 1, 0), min(cols[-1] + 2, W)
        # align the stride grid with the full image so points do not jump between frames
        r0s, c0s = r0 - r0 % stride, c0 - c0 % stride
        sub_h = height_mm[r0s:r1, c0s:c1]
        sub_m = mask[r0s:r1, c0s:c1]
        pts, nrm = height_to_points(sub_h, mm_per_px, mask=sub_m, stride=stride)
        # height_to_points centres the crop: shift to full-image sensor coordinates
        s = mm_per_px / 1000.0
        hs, ws = sub_h.shape
        pts[:, 0] += (c0s + (ws - 1) / 2.0 - (W - 1) / 2.0) * s
        pts[:, 1] += (r0s + (hs - 1) / 2.0 - (H - 1) / 2.0) * s
        return pts, nrm


def contact_only_many(
    pipes: list[TactilePipeline], images: list[np.ndarray]
) -> list[tuple[np.ndarray, np.ndarray, str]]:
    """``[pipes[j].contact_only(images[j]) for j]`` (e.g. the four sensors of a hand at one time step): the same
    values, with the steps that do not depend on a sensor's model (drift estimate, DCT Poisson integration) done
    for all frames of one working size in one numpy call each instead of one per frame. Pipelines that cannot
    share (:meth:`TactilePipeline._batchable`, another solver or size) run on their own."""
    n = len(pipes)
    if n != len(images):
        raise InputError("one image per pipeline", field="images", expected=n, got=len(images))
    out: list[Any] = [None] * n
    together = [j for j in range(n) if pipes[j]._batchable()]
    if len(together) < 2:
        together = []
    for j in set(range(n)) - set(together):
        out[j] = pipes[j].contact_only(images[j])
    if not together:
        return out
    prep = {j: pipes[j]._work_image(images[j]) for j in together}
    # the drift of every "ok" frame of one size and drift setting, at once
    drifts: dict[int, tuple] = {}
    groups: dict[tuple, list[int]] = {}
    for j in together:
        p, (_, work, quality) = pipes[j], prep[j]
        if quality == "ok" and work[::4, ::4].size:
            spread = p.drift_max_spread if p.drift_compensation else -1.0
            groups.setdefault((work.shape, spread), []).append(j)
    for (_, spread), js in groups.items():
        works, bgs = np.stack([prep[j][1] for j in js]), np.stack([pipes[j]._bg_work for j in js])
        offs, levels = drift_offsets(works, bgs, spread)
        drifts.update({j: (offs[i], float(levels[i])) for i, j in enumerate(js)})
    slopes = {j: pipes[j]._slopes_work(prep[j][1], prep[j][2], drifts.get(j)) for j in together}
    hw: dict[int, np.ndarray] = {}
    stacks: dict[tuple, list[int]] = {}
    for j in together:
        gate, _, _, g = slopes[j]
        if g is None:
            hw[j] = np.zeros(gate.shape, np.float32)
        elif pipes[j].solver == "dct":
            stacks.setdefault(gate.shape, []).append(j)
        else:
            hw[j] = pipes[j]._integrate(g[0], g[1], gate)
    for js in stacks.values():
        hs = poisson_dct_stack(np.stack([slopes[j][3][0] for j in js]), np.stack([slopes[j][3][1] for j in js]))
        hw.update({j: hs[i].astype(np.float32, copy=False) for i, j in enumerate(js)})
    for j in together:
        p, gate, quality = pipes[j], slopes[j][0], slopes[j][1]
        mask_w = p._contact_mask(hw[j], gate)
        pts, nrm = p.contact_points(hw[j], mask_w, p.mm_per_px * p.downsample, p.point_stride)
        out[j] = (pts, nrm, quality)
    return out
