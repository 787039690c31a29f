"""Sensor presets: what vtrack knows about each vision-based tactile sensor type before calibration.

One table (:data:`SENSOR_PRESETS`) used by the recorder (camera format), the scene schema (default image size,
scale and gel of a ``tactile`` entry), ``vtrack calibrate`` / press sets (nominal pixel pitch when the user
does not know theirs) and the simulator (image size and pitch of simulated units). Image sizes are given as
the camera delivers them (``width`` x ``height``, px) and as vtrack stores them (:attr:`SensorPreset.stored_size`;
DIGIT is stored portrait, the way it is mounted). ``mm_per_px`` is a **nominal** gel scale at the native
width: a unit's own calibration (or ``--mm-per-px``) replaces it, and anything computed from it is flagged.

Sources: DIGIT QVGA 320x240 at 60 fps (Lambeta et al. 2020); GelSight Mini 0.0634 mm/px at 320x240 (the
normalflow configuration listed in ``shared/data/README.md``); GelSight (Taxim data pack) 0.0295 mm/px at
640x480 (``shared/data/gelsight_ball_presses``). The light layouts describe the hardware for people and
the simulator's defaults; the pipeline learns colour -> normal from presses and never assumes them. They
are given in image coordinates (azimuth from +x = right towards +y = DOWN, the simulator's convention) and
match the simulator's optical model (tested); the GelSight layout matches the light directions photometric
stereo fits to the shared real presses (red ~0 deg, green ~245, blue ~125; tested). An earlier version of
this table had red and blue swapped (a BGR tuple read as RGB) and called the angles counter-clockwise.
"""

from __future__ import annotations

from dataclasses import dataclass

from vtrack.errors import InputError


@dataclass(frozen=True)
class SensorPreset:
    """Nominal properties of one tactile sensor type (px, mm, Hz)."""

    type: str
    width: int  # camera format, px
    height: int
    fps: float
    mm_per_px: float  # nominal gel scale at ``width`` (mm per px)
    gel_thickness_mm: float
    #: degrees clockwise vtrack rotates the camera frame by when storing it (DIGIT: portrait)
    rotate_deg: int
    #: LEDs around the gel: (colour, azimuth deg in image coordinates: from +x (right) towards +y (down))
    lights: tuple[tuple[str, float], ...]
    #: substrings of the UVC device name / serial that identify this sensor
    name_hints: tuple[str, ...]
    #: ball presses `vtrack record presses` records by default and `vtrack calibrate` asks for. A per-pixel
    #: colour-to-normal model only knows the parts of the gel it was shown; the DIGIT's LEDs sit just outside
    #: its small gel, so its shading changes fastest near the border and it needs more presses
    #: (docs/benchmarks/calib_digit_seeds.md: simulated DIGIT, true circles, 45 training presses 4.66 +- 0.31 deg
    #: over 9 sets, 68-90 presses 4.22-4.62 deg over 4)
    calib_presses: int = 60

    @property
    def stored_size(self) -> tuple[int, int]:
        """(width, height) of the stored images (after :attr:`rotate_deg`), px."""
        return (self.height, self.width) if self.rotate_deg % 180 else (self.width, self.height)

    def pitch_at(self, width_px: int, height_px: int) -> float:
        """Nominal mm/px for images of ``width_px`` x ``height_px`` (the same field of view, resampled);
        the longer side is compared with the preset's longer side, so portrait/landscape both work."""
        if width_px <= 0 or height_px <= 0:
            raise InputError("image size must be positive", field="size", got=(width_px, height_px))
        return self.mm_per_px * max(self.width, self.height) / max(width_px, height_px)


SENSOR_PRESETS: dict[str, SensorPreset] = {
    # DIGIT streams QVGA 320x240 at 60 fps (VGA at 30); stored portrait (240 wide, 320 high).
    "digit": SensorPreset(
        "digit",
        320,
        240,
        60.0,
        0.09,
        3.0,
        90,
        (("red", 90.0), ("green", 210.0), ("blue", 330.0)),
        ("DIGIT", "Digit"),
        calib_presses=100,
    ),
    # GelSight Mini: 3280x2464 sensor, usually streamed downscaled; 320x240 is the common working size.
    "gelsight_mini": SensorPreset(
        "gelsight_mini",
        320,
        240,
        25.0,
        0.0634,
        4.0,
        0,
        (("red", 0.0), ("green", 120.0), ("blue", 240.0), ("white", 300.0)),
        ("GelSight Mini", "GelSight"),
    ),
    "gelsight": SensorPreset(
        "gelsight", 640, 480, 30.0, 0.0295, 3.0, 0, (("red", 0.0), ("green", 270.0), ("blue", 135.0)), ("GelSight",)
    ),
}


#: No-contact frames shipped in ``vtrack/assets/backgrounds`` (licences beside them), per sensor type.
_BACKGROUNDS = {
    "digit": "digit_bg_tacto_240x320.jpg",
    "gelsight_mini": "gelsight_mini_bg_normalflow_320x240.png",
    "gelsight": "gelsight_mini_bg_normalflow_320x240.png",
}


def default_background(sensor_type: str, width: int, height: int, path=None):
    """A no-contact frame (uint8 BGR, (height, width, 3)) for a sensor without its own: ``path`` when given and
    readable, else the shipped real frame of this type (rotated to the orientation, resized to the size), else
    a plausible flat, slightly vignetted gel. For simulation and the generated calibration sets; a real
    recording brings its own background."""
    from pathlib import Path

    import cv2
    import numpy as np

    from vtrack.paths import assets_dir

    candidates = [Path(path)] if path is not None else []
    if sensor_type in _BACKGROUNDS:
        candidates.append(assets_dir() / "backgrounds" / _BACKGROUNDS[sensor_type])
    for p in candidates:
        img = cv2.imread(str(p), cv2.IMREAD_COLOR) if p.is_file() else None
        if img is not None:
            if img.shape[:2] != (height, width):
                if img.shape[:2] == (width, height):
                    img = np.ascontiguousarray(np.rot90(img))
                img = cv2.resize(img, (width, height), interpolation=cv2.INTER_AREA)
            return img
    yy, xx = np.mgrid[0:height, 0:width]
    r = np.hypot((xx - width / 2) / width, (yy - height / 2) / height)
    base = np.array([150.0, 140.0, 130.0])[None, None] * (1.0 - 0.4 * r[..., None])
    return base.astype(np.uint8)


def sensor_preset(sensor_type: str, field: str = "sensor") -> SensorPreset:
    """The preset of ``sensor_type``; a clear InputError naming ``field`` for an unknown type."""
    p = SENSOR_PRESETS.get(sensor_type)
    if p is None:
        raise InputError(
            "unknown tactile sensor type", field=field, expected=" | ".join(SENSOR_PRESETS), got=sensor_type
        )
    return p


def orientation_warning(sensor_type: str, width_px: int, height_px: int) -> str | None:
    """A warning when images of ``width_px`` x ``height_px`` are not in the orientation vtrack stores this
    sensor type in (:attr:`SensorPreset.stored_size`; e.g. a DIGIT recorded landscape by another tool): a
    calibration from them would not fit the sensor's frames recorded by vtrack. None when they match, the
    type is unknown or the images are square."""
    p = SENSOR_PRESETS.get(sensor_type)
    if p is None or width_px == height_px:
        return None
    sw, sh = p.stored_size
    if (width_px > height_px) == (sw > sh):
        return None
    return (
        f"{sensor_type} images are {width_px}x{height_px} but vtrack stores {sensor_type} frames {sw}x{sh} "
        f"({'portrait' if sh > sw else 'landscape'}): a calibration from them will not fit frames recorded by "
        "vtrack (rotate the press images, or record them with `vtrack record presses`)"
    )


def press_count_warning(sensor_type: str, n_presses: int) -> str | None:
    """A warning when a calibration set of ``sensor_type`` has fewer usable presses than the preset asks for
    (:attr:`SensorPreset.calib_presses`); None when it has enough or the type is unknown."""
    p = SENSOR_PRESETS.get(sensor_type)
    if p is None or n_presses >= p.calib_presses:
        return None
    return (
        f"only {n_presses} usable presses for a {sensor_type}: its normals get better and more repeatable with "
        f"more (record {p.calib_presses} over the whole gel, edges included; docs/tactile.md)"
    )


def guess_sensor_type(name: str, default: str = "digit") -> str:
    """Guess a sensor type from a topic / device / folder name (case-insensitive)."""
    low = name.lower()
    if "mini" in low:
        return "gelsight_mini"
    if "gelsight" in low:
        return "gelsight"
    if "digit" in low:
        return "digit"
    return default
