"""SLAM's observed-surface gate (``SLAMOptions.observed_gate``), evaluated: every session tracked blind with each gate
(0 = off, the old behaviour); the per-run columns of :mod:`slam_option_eval` (object-motion error, spin ratio and
spin error about the object's axis), scored against gt/ by eval code; the tracker sees none of it.

Usage: ``python data_tools/observed_gate_eval.py SECONDS OCCLUSION SEEDS [OBJECTS] [--vision] [--gates 0,0.0025]
[--out PREFIX]`` (2 processes, one thread each). ``--out`` writes PREFIX.csv (one row per run) and PREFIX.png (mean
error per object and gate).
"""

if __name__ == "__main__":
    from slam_option_eval import cli

    cli(
        "observed_gate",
        "0,0.0025",
        "SLAM observed-surface gate: off against on, per session.",
        values_flag="--gates",
        what="observed-surface gate",
        label=lambda g: "gate off" if float(g) == 0 else f"observed_gate {float(g) * 1e3:g} mm",
        column="observed_gate_m",
    )
