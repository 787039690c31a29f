"""Known tactile sensor types: native camera format and default scale.

Used by the tactile recorder (to configure the UVC camera) and by importers (to fill in the
scene's tactile entries when the source does not say). Image sizes are as the camera delivers
them (width x height, px); ``mm_per_px`` is a nominal gel scale that a calibration should replace.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class SensorPreset:
    type: str
    width: int
    height: int
    fps: float
    mm_per_px: float
    gel_thickness_mm: float
    #: substrings of the UVC device name / serial that identify this sensor
    name_hints: tuple[str, ...]


SENSOR_PRESETS: dict[str, SensorPreset] = {
    # DIGIT streams QVGA 320x240 at 60 fps (VGA at 30); vtrack stores DIGIT images portrait
    # (240 wide, 320 high) like the sensor is mounted, see `rotate` in the recorder.
    "digit": SensorPreset("digit", 320, 240, 60.0, 0.09, 3.0, ("DIGIT", "Digit")),
    # GelSight Mini: 3280x2464 sensor, usually streamed downscaled; 320x240 is the common working size
    # (0.0634 mm/px at 320x240, from the normalflow configuration listed in shared/data/README.md).
    "gelsight_mini": SensorPreset("gelsight_mini", 320, 240, 25.0, 0.0634, 4.0, ("GelSight Mini", "GelSight")),
    "gelsight": SensorPreset("gelsight", 640, 480, 30.0, 0.0295, 3.0, ("GelSight",)),
}


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
