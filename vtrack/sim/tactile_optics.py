"""Physically based optical model of a vision-based tactile sensor (simulation side only).

This renderer is deliberately independent of the tactile pipeline: it shares no code, tables or
calibration with :mod:`vtrack.tactile.calibration` / :mod:`vtrack.tactile.render`, so a synthetic
session's tactile accuracy is not an "inverse crime" (the pipeline inverting its own forward model).

Geometry (sensor frame, mm): x = image columns (right), y = image rows (down), z = towards the camera.
The membrane's inner surface is ``z = h(x, y)`` with ``h`` the indentation in mm (>= 0; the object
pushes the membrane towards the camera). The camera pinhole sits on the optical axis at
``camera_height_mm`` above the image centre.

Image formation, per pixel and per light ``l`` (a small LED with a colour, a position and a gain):

1. elastomer blur: the gel smooths the indenter shape (Gaussian, ``blur_mm``) before shading;
2. shading: Lambert ``kd * max(n.l, 0)`` plus Blinn-Phong specular ``ks * max(n.h, 0)^shininess``
   (the membrane's semi-specular paint), with inverse-square fall-off ``(d0 / d)^2`` from the LED;
3. cast shadows: the height map is ray-marched towards each light (direction and elevation of the LED as
   seen from the image centre); a pixel is shadowed by the amount the surface rises above the ray, with a
   soft penumbra ``shadow_soft_mm`` (the LEDs are not points);
4. the colour change ``sum_l colour_l * (I_l(h) - I_l(flat))`` is attenuated by camera vignetting
   (cos^4 of the off-axis angle) and added to a real no-contact frame (which already holds the
   sensor's own illumination pattern, vignetting and gel texture);
5. camera noise: shot (variance proportional to the signal) + read noise, then 8-bit quantisation.

Per-sensor variation: :meth:`OpticalModel.for_sensor` jitters each LED's gain, azimuth, elevation and
colour cross-talk with a seeded RNG, so two DIGITs with different seeds render differently (as two real
units do) and each needs its own calibration.

Light layouts (stated assumptions, plausible rather than measured):
- ``digit``: red, green and blue LEDs 120 deg apart around the gel (TACTO's DIGIT config places its three
  lights at 120 deg spacing), low elevation (~30 deg) because they shine in from the sides of the gel;
- ``gelsight``: the original GelSight / Taxim sensor: red, green and blue LEDs from three sides; the
  azimuths follow the colour change of the shared real presses (red brightens slopes facing +x, green
  facing -y, blue facing +y/-x), elevation ~35 deg;
- ``gelsight_mini``: GelSight Mini: red, green, blue LED strips plus a weaker white-ish strip on the
  fourth side, elevation ~30 deg.

Speed: vectorised numpy/OpenCV; 240x320 frames render in a few ms (``vtrack bench simreal`` reports it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from vtrack.errors import InputError


@dataclass(frozen=True)
class Light:
    """One LED.

    Attributes:
        colour_bgr: relative emission per camera channel (B, G, R), incl. cross-talk into other channels.
        azimuth_deg: direction of the LED from the image centre, in the image plane (0 = +x / right,
            90 = +y / down).
        elevation_deg: elevation of the LED above the gel plane seen from the image centre.
        distance_mm: distance of the LED from the image centre (sets the fall-off across the frame).
        gain: grey levels of colour change for a unit change of the shading term at the centre.
    """

    colour_bgr: tuple[float, float, float]
    azimuth_deg: float
    elevation_deg: float
    distance_mm: float
    gain: float

    def position_mm(self, centre_xy_mm: tuple[float, float]) -> np.ndarray:
        """LED position in the sensor frame (mm)."""
        az, el = math.radians(self.azimuth_deg), math.radians(self.elevation_deg)
        return np.array(
            [
                centre_xy_mm[0] + self.distance_mm * math.cos(el) * math.cos(az),
                centre_xy_mm[1] + self.distance_mm * math.cos(el) * math.sin(az),
                self.distance_mm * math.sin(el),
            ]
        )


#: Preset LED layouts per sensor type (see the module docstring); distances in mm from the image centre.
_PRESETS: dict[str, dict[str, Any]] = {
    "digit": {
        "lights": [
            Light((0.05, 0.12, 1.0), 90.0, 30.0, 16.0, 70.0),
            Light((0.08, 1.0, 0.10), 210.0, 30.0, 16.0, 70.0),
            Light((1.0, 0.15, 0.05), 330.0, 30.0, 16.0, 70.0),
        ],
        "kd": 1.0,
        "ks": 0.25,
        "shininess": 18.0,
        "blur_mm": 0.25,
        "camera_height_mm": 22.0,
        "shadow_soft_mm": 0.06,
        "read_noise": 1.0,
        "shot_gain": 0.02,
    },
    "gelsight": {
        "lights": [
            Light((0.05, 0.10, 1.0), 0.0, 35.0, 20.0, 80.0),
            Light((0.10, 1.0, 0.10), 270.0, 35.0, 20.0, 70.0),
            Light((1.0, 0.20, 0.05), 135.0, 35.0, 20.0, 70.0),
        ],
        "kd": 1.0,
        "ks": 0.15,
        "shininess": 12.0,
        "blur_mm": 0.12,
        "camera_height_mm": 30.0,
        "shadow_soft_mm": 0.05,
        "read_noise": 1.0,
        "shot_gain": 0.02,
    },
    "gelsight_mini": {
        "lights": [
            Light((0.05, 0.10, 1.0), 0.0, 30.0, 14.0, 70.0),
            Light((0.10, 1.0, 0.10), 120.0, 30.0, 14.0, 65.0),
            Light((1.0, 0.15, 0.05), 240.0, 30.0, 14.0, 65.0),
            Light((0.6, 0.6, 0.6), 300.0, 25.0, 14.0, 20.0),
        ],
        "kd": 1.0,
        "ks": 0.2,
        "shininess": 15.0,
        "blur_mm": 0.2,
        "camera_height_mm": 18.0,
        "shadow_soft_mm": 0.05,
        "read_noise": 1.0,
        "shot_gain": 0.02,
    },
}
SENSOR_TYPES = tuple(_PRESETS)


@dataclass
class OpticalModel:
    """Optical model of one (simulated) tactile sensor unit; see the module docstring.

    Attributes:
        lights: the LEDs.
        kd, ks, shininess: Lambert weight, Blinn-Phong specular weight and exponent of the membrane.
        blur_mm: std of the elastomer's Gaussian smoothing of the indenter shape (mm).
        camera_height_mm: pinhole height above the gel (view vector for the specular term, vignetting).
        shadow_soft_mm: penumbra width of the cast shadows (mm of occluder height above the ray).
        read_noise: camera read noise std (grey levels); shot_gain: shot-noise variance per grey level.
        sensor_type: preset name; seed: per-unit jitter seed (None = the nominal preset).
    """

    lights: list[Light]
    kd: float = 1.0
    ks: float = 0.2
    shininess: float = 15.0
    blur_mm: float = 0.2
    camera_height_mm: float = 20.0
    shadow_soft_mm: float = 0.05
    read_noise: float = 1.0
    shot_gain: float = 0.02
    sensor_type: str = "digit"
    seed: int | None = None
    _geom_cache: dict = field(default_factory=dict, repr=False, compare=False)

    # ------------------------------------------------------------------ construction
    @classmethod
    def for_sensor(cls, sensor_type: str, seed: int | None = None, jitter: float = 1.0) -> OpticalModel:
        """Preset of ``sensor_type`` (digit | gelsight | gelsight_mini), jittered per unit by ``seed``.

        ``jitter`` scales the unit-to-unit variation (1 = gains +-8 %, azimuth +-4 deg, elevation +-3 deg,
        colour cross-talk +-0.03; 0 = the nominal preset).
        """
        if sensor_type not in _PRESETS:
            raise InputError(
                "no optical model for this tactile sensor type",
                field="type",
                expected=" | ".join(SENSOR_TYPES),
                got=sensor_type,
            )
        p = dict(_PRESETS[sensor_type])
        lights = list(p.pop("lights"))
        if seed is not None and jitter > 0:
            rng = np.random.default_rng(seed)
            out = []
            for li in lights:
                c = np.clip(np.asarray(li.colour_bgr) + jitter * rng.uniform(-0.03, 0.03, 3), 0.0, None)
                out.append(
                    replace(
                        li,
                        colour_bgr=tuple(float(x) for x in c),
                        azimuth_deg=li.azimuth_deg + jitter * rng.uniform(-4, 4),
                        elevation_deg=li.elevation_deg + jitter * rng.uniform(-3, 3),
                        gain=li.gain * (1.0 + jitter * rng.uniform(-0.08, 0.08)),
                    )
                )
            lights = out
        return cls(lights=lights, sensor_type=sensor_type, seed=seed, **p)

    def with_lights(self, lights: list[Light]) -> OpticalModel:
        """Copy with other LEDs (e.g. fitted to real presses)."""
        return replace(self, lights=list(lights), _geom_cache={})

    # ------------------------------------------------------------------ geometry per frame size
    def _geometry(self, shape: tuple[int, int], mm_per_px: float) -> dict[str, Any]:
        key = (shape, round(mm_per_px, 9))
        g = self._geom_cache.get(key)
        if g is not None:
            return g
        H, W = shape
        x = (np.arange(W, dtype=np.float32) + 0.5) * mm_per_px
        y = (np.arange(H, dtype=np.float32) + 0.5) * mm_per_px
        X, Y = np.meshgrid(x, y)
        c = (W * mm_per_px / 2.0, H * mm_per_px / 2.0)
        r2 = (X - c[0]) ** 2 + (Y - c[1]) ** 2
        # cos^4 vignetting of a pinhole camera at camera_height_mm over the gel
        cos_t = self.camera_height_mm / np.sqrt(r2 + self.camera_height_mm**2)
        g = {
            "X": X,
            "Y": Y,
            "centre": c,
            "vignette": (cos_t**4).astype(np.float32),
            "pos": [li.position_mm(c).astype(np.float32) for li in self.lights],
            "cam": np.array([c[0], c[1], self.camera_height_mm], np.float32),
        }
        self._geom_cache[key] = g
        return g

    # ------------------------------------------------------------------ shading
    def _shadow(self, h: np.ndarray, mm_per_px: float, light: Light) -> np.ndarray:
        """Soft cast-shadow factor in [0, 1] (1 = lit) of ``light`` by ray-marching the height map."""
        import cv2

        H, W = h.shape
        hmax = float(h.max())
        tan_el = math.tan(math.radians(max(light.elevation_deg, 1.0)))
        # the ray rises tan(el) mm per mm: beyond hmax / tan(el) nothing can occlude it
        reach_px = min(hmax / tan_el / mm_per_px, 0.5 * max(H, W))
        if reach_px < 1.0:
            return np.ones_like(h)
        n_steps = int(min(24, max(4, math.ceil(reach_px / 2.0))))
        step_px = reach_px / n_steps
        az = math.radians(light.azimuth_deg)
        ux, uy = math.cos(az), math.sin(az)
        occ = np.zeros_like(h)
        for k in range(1, n_steps + 1):
            t = k * step_px
            # sample h at p + t*u (towards the light); outside the frame the gel is flat
            M = np.array([[1.0, 0.0, -t * ux], [0.0, 1.0, -t * uy]], np.float32)
            hs = cv2.warpAffine(h, M, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
            np.maximum(occ, hs - h - np.float32(t * mm_per_px * tan_el), out=occ)
        return np.clip(1.0 - occ / np.float32(self.shadow_soft_mm), 0.0, 1.0)

    def _intensity(
        self,
        X: np.ndarray,
        Y: np.ndarray,
        z: np.ndarray,
        nx: np.ndarray,
        ny: np.ndarray,
        nz: np.ndarray,
        geom: dict,
        i: int,
    ) -> np.ndarray:
        """Shading term of light ``i`` at points (X, Y, z) mm with unit normals n (Lambert + Blinn-Phong,
        inverse-square fall-off), unitless."""
        li = self.lights[i]
        P = geom["pos"][i]
        lx, ly, lz = P[0] - X, P[1] - Y, P[2] - z
        d2 = lx * lx + ly * ly + lz * lz
        inv = 1.0 / np.sqrt(d2)
        lx, ly, lz = lx * inv, ly * inv, lz * inv
        ndl = np.maximum(nx * lx + ny * ly + nz * lz, 0.0)
        cam = geom["cam"]
        vx, vy, vz = cam[0] - X, cam[1] - Y, cam[2] - z
        vinv = 1.0 / np.sqrt(vx * vx + vy * vy + vz * vz)
        hx, hy, hz = lx + vx * vinv, ly + vy * vinv, lz + vz * vinv
        hinv = 1.0 / np.sqrt(hx * hx + hy * hy + hz * hz)
        ndh = np.maximum((nx * hx + ny * hy + nz * hz) * hinv, 0.0)
        spec = np.power(ndh, np.float32(self.shininess)) * (ndl > 0)
        falloff = np.float32(li.distance_mm**2) / d2
        return (self.kd * ndl + self.ks * spec) * falloff

    def colour_change(self, height_mm: np.ndarray, mm_per_px: float) -> np.ndarray:
        """(H, W, 3) float32 BGR colour change against the flat gel (grey levels, before vignetting/noise)."""
        import cv2

        h = np.nan_to_num(np.asarray(height_mm, np.float32), nan=0.0, posinf=0.0, neginf=0.0)
        if h.ndim != 2 or h.size == 0:
            raise InputError("height map must be a 2-D array", field="height_mm", expected="(H, W)", got=h.shape)
        if not (np.isfinite(mm_per_px) and mm_per_px > 0):
            raise InputError("pixel pitch must be positive", field="mm_per_px", expected="> 0", got=mm_per_px)
        geom = self._geometry(h.shape, float(mm_per_px))
        out = np.zeros((*h.shape, 3), np.float32)
        if float(np.abs(h).max()) < 1e-6:
            return out
        sigma = self.blur_mm / mm_per_px
        if sigma > 0.3:
            h = cv2.GaussianBlur(h, (0, 0), sigma, borderType=cv2.BORDER_REPLICATE)
        # Shade only the box around the indentation (+ shadow reach): elsewhere the gel is flat and lit,
        # so its colour change is exactly 0. This keeps small contacts cheap.
        rows = np.flatnonzero((h > 1e-4).any(1))
        cols = np.flatnonzero((h > 1e-4).any(0))
        if rows.size == 0:
            return out
        min_tan = math.tan(math.radians(max(1.0, min(li.elevation_deg for li in self.lights))))
        pad = int(math.ceil(float(h.max()) / min_tan / mm_per_px)) + 2
        H, W = h.shape
        r0, r1 = max(0, rows[0] - pad), min(H, rows[-1] + pad + 1)
        c0, c1 = max(0, cols[0] - pad), min(W, cols[-1] + pad + 1)
        hc = np.ascontiguousarray(h[r0:r1, c0:c1])
        X, Y = geom["X"][r0:r1, c0:c1], geom["Y"][r0:r1, c0:c1]
        gy, gx = np.gradient(hc, np.float32(mm_per_px))
        inv = 1.0 / np.sqrt(gx * gx + gy * gy + 1.0)
        nx, ny, nz = -gx * inv, -gy * inv, inv
        zero = np.zeros_like(hc)
        one = np.ones_like(hc)
        roi = out[r0:r1, c0:c1]
        for i, li in enumerate(self.lights):
            lit = self._intensity(X, Y, hc, nx, ny, nz, geom, i) * self._shadow(hc, mm_per_px, li)
            flat = self._intensity(X, Y, zero, zero, zero, one, geom, i)
            d = np.float32(li.gain) * (lit - flat)
            roi += d[..., None] * np.asarray(li.colour_bgr, np.float32)[None, None, :]
        return out

    def render(
        self,
        height_mm: np.ndarray,
        mm_per_px: float,
        background_bgr: np.ndarray,
        rng: np.random.Generator | None = None,
        noise: float = 1.0,
    ) -> np.ndarray:
        """Tactile image (uint8 BGR, (H, W, 3)) of the indentation ``height_mm`` (mm, (H, W)).

        Args:
            height_mm: indentation of the membrane towards the camera, mm (0 = no contact).
            mm_per_px: pixel pitch, mm.
            background_bgr: real no-contact frame of the same size (uint8 BGR).
            rng: noise source; None renders without camera noise (still quantised to 8 bits).
            noise: scale of the shot + read noise (0 = none).
        """
        bg = np.asarray(background_bgr)
        h = np.asarray(height_mm)
        if bg.ndim != 3 or bg.shape[2] != 3 or bg.shape[:2] != h.shape:
            raise InputError(
                "background must be a BGR image of the height map's size",
                field="background",
                expected=f"{h.shape[0]}x{h.shape[1]}x3",
                got=bg.shape,
            )
        import cv2

        geom = self._geometry(h.shape, float(mm_per_px))
        img = bg.astype(np.float32)
        cc = self.colour_change(h, mm_per_px)
        img += geom["vignette"][..., None] * cc
        if rng is not None and noise > 0:
            var = np.float32(self.read_noise**2) + np.float32(self.shot_gain) * np.clip(img, 0.0, 255.0)
            # OpenCV's Gaussian generator is ~3x faster than numpy's; seeded from ``rng`` so a session
            # stays reproducible from its seed
            cv2.setRNGSeed(int(rng.integers(0, 2**31 - 1)))
            z = np.empty(img.shape, np.float32)
            # as one channel: a 3-channel Mat would take the std as Scalar(std, 0, 0) (noise in B only)
            cv2.randn(z.reshape(img.shape[0], -1), 0.0, float(noise))
            img += np.sqrt(var) * z
        return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def optics_fingerprint() -> str:
    """Hash of this module's source: part of every cache key of data rendered with it."""
    import hashlib
    from pathlib import Path

    return hashlib.sha1(Path(__file__).read_bytes()).hexdigest()[:12]
