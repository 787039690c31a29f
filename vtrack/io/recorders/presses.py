"""Guided recording of a ball-press calibration set from a tactile camera (or a video file of one).

``vtrack record presses --camera SOURCE --out DIR``: the first frames (gel untouched) become
``background.png``; then every press is found as an episode of colour change against it. The deepest frame
of each episode (largest change) is checked with the automatic contact detector
(:func:`vtrack.tactile.autolabel.detect_contact`) and saved as ``press_NN.png`` with a one-line read-out
(centre, contact radius, estimated depth) and a warning when the press is too shallow, cut by the image
border, saturated, or not a single round contact. The folder is a press set ``vtrack calibrate`` reads
(``meta.json`` with the sensor, pitch and ball radius; ``labels.auto.csv`` for review).

The sensor preset (:data:`vtrack.tactile.sensors.SENSOR_PRESETS`) sets the camera format of a device, the
orientation frames are stored in (a DIGIT is stored portrait, as ``vtrack record tactile`` stores it, so a
calibration from these presses fits that sensor's sessions) and, when the pitch is not given, its nominal
pitch at the stored frame size, flagged ``mm_per_px_source: preset`` in ``meta.json``.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vtrack.errors import InputError


@dataclass
class PressRecording:
    """What :func:`record_presses` did (counts and per-press read-outs)."""

    out: str
    frames_read: int = 0
    background_frames: int = 0
    presses_saved: int = 0
    episodes: int = 0
    warnings: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {
            "out": self.out,
            "frames_read": self.frames_read,
            "background_frames": self.background_frames,
            "episodes": self.episodes,
            "presses_saved": self.presses_saved,
            "warnings": len(self.warnings),
        }


def _quick_change(frame: np.ndarray, background: np.ndarray, step: int) -> float:
    """Fast per-frame press signal: 99.9th percentile of |frame - background| (grey levels, summed channels) on a
    strided grid; the global drift of the frame (lighting) is removed by subtracting the median change."""
    d = frame[::step, ::step].astype(np.int16) - background[::step, ::step]
    d = d - np.median(d.reshape(-1, 3), axis=0).astype(np.int16)
    return float(np.percentile(np.abs(d).sum(axis=2), 99.9))


def record_presses(
    source: str,
    out: str | Path,
    *,
    sensor: str,
    ball_radius_mm: float,
    mm_per_px: float | None = None,
    n_presses: int | None = None,
    background_frames: int = 15,
    start_level: float = 15.0,
    max_frames: int | None = None,
    overwrite: bool = False,
    echo: Callable[[str], None] = print,
) -> PressRecording:
    """Record a press set (see module docstring).

    Args:
        source: device index, ``/dev/videoN``, ``serial:S`` or a video file.
        out: press-set folder to create (must be new or empty unless ``overwrite``).
        sensor: digit | gelsight_mini | gelsight (camera format for devices; ``meta.json`` ``sensor``).
        ball_radius_mm, mm_per_px: the ball pressed and the gel's pixel pitch (mm); ``mm_per_px`` None: the
            preset's nominal pitch at the stored frame size (flagged in ``meta.json``).
        n_presses: stop after this many saved presses. None: the preset's
            :attr:`~vtrack.tactile.sensors.SensorPreset.calib_presses` (60; DIGIT 100): a per-pixel model only
            knows the parts of the gel it was shown (simulated DIGIT, true circles: 4.66 +- 0.31 deg from 45
            training presses over 9 sets, 4.22-4.62 deg from 68-90; docs/benchmarks/calib_digit_seeds.md).
        background_frames: untouched frames at the start, averaged (median) into the background.
        start_level: press signal (grey levels above the background's own frame-to-frame level) that starts
            an episode; it ends when the signal falls below half of it.
    """
    import cv2

    from vtrack.io.recorders.tactile import TactileCamera, _rotate, _rotation, open_capture
    from vtrack.sim.presses import press_depth_mm  # ball geometry only (no renderer)
    from vtrack.tactile.autolabel import Detection, detect_contact, write_auto_labels
    from vtrack.tactile.sensors import sensor_preset

    preset = sensor_preset(sensor, "--sensor")
    if n_presses is None:
        n_presses = preset.calib_presses
    pitch_given = mm_per_px is not None
    if not (
        np.isfinite(ball_radius_mm)
        and ball_radius_mm > 0
        and (not pitch_given or (np.isfinite(mm_per_px) and mm_per_px > 0))
    ):
        raise InputError(
            "ball radius and pixel pitch must be positive",
            field="--ball-radius-mm/--mm-per-px",
            got=(ball_radius_mm, mm_per_px),
        )
    out = Path(out)
    if out.exists() and any(out.iterdir()) and not overwrite:
        raise InputError("output folder exists and is not empty (pass --force to add to it)", path=out)
    cam = TactileCamera(name="presses", source=source, type=sensor)  # rotate=None: the preset's orientation
    cap, _ = open_capture(cam)
    rep = PressRecording(str(out))
    rotate: int | None = None
    R_px = float("nan")  # set from the pitch once the stored frame size is known
    bg_stack: list[np.ndarray] = []
    background = None
    noise = 0.0
    best: tuple[float, np.ndarray] | None = None
    dets: list[Detection] = []

    def finish_episode() -> None:
        nonlocal best
        if best is None:
            return
        rep.episodes += 1
        img = best[1]
        best = None
        name = f"press_{rep.presses_saved:02d}.png"
        d = detect_contact(img, background, R_px, name)
        if not d.ok:
            why = d.reason
            if why.startswith("no contact") or why.startswith("too shallow"):
                why = f"too shallow: press deeper ({why})"
            msg = f"episode {rep.episodes}: not saved: {why}"
            rep.warnings.append(msg)
            echo("  ! " + msg)
            return
        warn = []
        if d.contact_radius_px < 0.4 * R_px:
            warn.append("shallow: press deeper")
        H, W = img.shape[:2]
        margin = min(d.center_x_px, d.center_y_px, W - 1 - d.center_x_px, H - 1 - d.center_y_px)
        if margin < d.contact_radius_px:
            warn.append("off-centre: contact cut by the image border")
        depth = press_depth_mm(ball_radius_mm, d.contact_radius_px * mm_per_px)
        cv2.imwrite(str(out / name), img)
        dets.append(d)
        rep.presses_saved += 1
        line = (
            f"press {rep.presses_saved:2d}/{n_presses}: centre ({d.center_x_px:.0f}, {d.center_y_px:.0f}) px, "
            f"contact radius {d.contact_radius_px:.1f} px, depth ~{depth:.2f} mm"
        )
        if warn:
            rep.warnings.extend(f"{name}: {w}" for w in warn)
            line += "  ! " + "; ".join(warn)
        echo(line)

    out.mkdir(parents=True, exist_ok=True)
    try:
        in_press = False
        while rep.presses_saved < n_presses and (max_frames is None or rep.frames_read < max_frames):
            ok, frame = cap.read()
            if not ok or frame is None:
                break
            if frame.ndim != 3 or frame.shape[2] < 3:
                raise InputError("tactile camera delivers non-colour frames", field="--camera", got=frame.shape)
            if rotate is None:
                rotate = _rotation(cam, frame)
                h, w = _rotate(frame, rotate).shape[:2]
                if not pitch_given:
                    mm_per_px = preset.pitch_at(w, h)
                    echo(f"pixel pitch: {mm_per_px:.4f} mm/px (nominal {sensor} preset at {w}x{h}; unverified)")
                R_px = ball_radius_mm / mm_per_px
            frame = np.ascontiguousarray(_rotate(frame[..., :3], rotate))
            rep.frames_read += 1
            if background is None:
                bg_stack.append(frame)
                if len(bg_stack) < background_frames:
                    continue
                background = np.median(np.stack(bg_stack), axis=0).astype(np.uint8)
                if float(background.std()) < 2.0:
                    raise InputError(
                        "background frames are blank (constant colour): is the camera covered?",
                        field="--camera",
                        got=source,
                    )
                step = max(1, int(np.sqrt(background.shape[0] * background.shape[1] / 4000.0)))
                noise = float(np.median([_quick_change(f, background, step) for f in bg_stack]))
                rep.background_frames = len(bg_stack)
                cv2.imwrite(str(out / "background.png"), background)
                echo(f"background from {len(bg_stack)} frames (noise level {noise:.1f}); press the ball now")
                continue
            level = _quick_change(frame, background, step) - noise
            if level > start_level:
                in_press = True
                if best is None or level > best[0]:
                    best = (level, frame.copy())
            elif in_press and level < 0.5 * start_level:
                in_press = False
                finish_episode()
        if in_press:
            finish_episode()
    finally:
        cap.release()
        if background is not None:
            (out / "meta.json").write_text(
                json.dumps(
                    {
                        "sensor": sensor,
                        "mm_per_px": float(mm_per_px),
                        # "preset": nominal, unverified; calibrate flags it like a meta.json without a pitch
                        "mm_per_px_source": "given" if pitch_given else "preset",
                        "ball_radius_mm": float(ball_radius_mm),
                        "recorded_with": "vtrack record presses",
                    },
                    indent=1,
                )
            )
            if dets:
                write_auto_labels(out / "labels.auto.csv", dets)
    if background is None:
        raise InputError(
            f"the source ended after {rep.frames_read} frames, before the {background_frames} background frames",
            field="--camera",
            got=source,
        )
    return rep
