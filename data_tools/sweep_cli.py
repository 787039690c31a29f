"""Shared command line of the per-session A/B tools over the YCB sessions (anchor_refresh_eval.py,
observed_gate_eval.py, slam_option_eval.py, slam_configs_eval.py): ``SECONDS OCCLUSION SEEDS [OBJECTS] [--vision]
[--out PREFIX]``."""

import argparse
from dataclasses import dataclass


@dataclass
class Sweep:
    seconds: float
    occlusion: str
    seeds: list[int]
    objects: list[str]
    modalities: tuple[str, ...]
    out: str | None


def sweep_parser(description: str) -> argparse.ArgumentParser:
    """The parser with the shared arguments; a tool adds its own before :func:`parse_sweep`."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("seconds", type=float)
    ap.add_argument("occlusion")
    ap.add_argument("seeds", help="comma-separated simulator seeds")
    ap.add_argument("objects", nargs="?", default="", help="comma-separated YCB names (default: all shared)")
    ap.add_argument("--vision", action="store_true", help="vision only")
    ap.add_argument("--out", default=None, help="write PREFIX.csv and PREFIX.png")
    return ap


def parse_sweep(ap: argparse.ArgumentParser) -> tuple[Sweep, argparse.Namespace]:
    """Parsed shared arguments (objects default to every shared YCB mesh) and the namespace for the tool's own."""
    from vtrack.testing.sim import ycb_objects

    a = ap.parse_args()
    sweep = Sweep(
        a.seconds,
        a.occlusion,
        [int(s) for s in a.seeds.split(",")],
        a.objects.split(",") if a.objects else ycb_objects(),
        ("vision",) if a.vision else ("vision", "touch"),
        a.out,
    )
    return sweep, a
