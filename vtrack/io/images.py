"""Image files: one reader with clear errors (missing file, undecodable data) for every loader."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vtrack.errors import InputError

#: mode -> OpenCV imread flag name (resolved when reading: cv2 is imported lazily)
_MODES = {"unchanged": "IMREAD_UNCHANGED", "color": "IMREAD_COLOR", "gray": "IMREAD_GRAYSCALE"}


def read_image(path: str | Path, mode: str = "unchanged") -> np.ndarray:
    """Read an image file with OpenCV: ``unchanged`` (as stored, BGR order), ``color`` (3-channel BGR) or
    ``gray`` (one channel).

    Raises:
        InputError: the file does not exist, or cannot be decoded (truncated, corrupt or not an image).
    """
    import cv2

    path = Path(path)
    if not path.is_file():
        raise InputError("image file not found", path=path)
    img = cv2.imread(str(path), getattr(cv2, _MODES[mode]))
    if img is None:
        raise InputError("cannot decode image (truncated, corrupt or not an image)", path=path, expected="PNG/JPEG")
    return img
