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


def run_contact_mode_sweep(description: str, run) -> None:
    """The per-session tools over sessions of one simulator contact mode (contact_mode_evidence.py,
    contact_mode_diagnostics.py): the shared arguments plus ``--contacts slide|stick``; ``run((object, occlusion,
    seconds, seed, contacts))`` -> row dict on 2 processes; the rows to ``PREFIX.csv`` with ``--out``."""
    import csv
    from multiprocessing import Pool

    ap = sweep_parser(description)
    ap.add_argument("--contacts", default="slide", choices=("slide", "stick"), help="the sessions' sim.contact_mode")
    sw, a = parse_sweep(ap)
    jobs = [(o, sw.occlusion, sw.seconds, s, a.contacts) for s in sw.seeds for o in sw.objects]
    with Pool(2) as pool:
        rows = pool.map(run, jobs, chunksize=1)
    if sw.out:
        with open(f"{sw.out}.csv", "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
