"""Speed-against-error benchmarks (``vtrack bench``). Results go to ``--out`` (default ``results/benchmarks``;
the repository keeps its tables in ``docs/benchmarks/``).

Each stage lives in a module ``vtrack.bench.<stage>`` exposing ``run(quick: bool) -> BenchTable``.
"""

#: stage name -> module; the CLI imports a stage's module only when it runs.
STAGES: dict[str, str] = {
    "tactile": "vtrack.bench.tactile",
    "fusion": "vtrack.bench.fusion",
    "tracking": "vtrack.bench.tracking",
    "dome": "vtrack.bench.dome",
    "simreal": "vtrack.bench.simreal",
    "segmentation": "vtrack.bench.segmentation",
    "slam": "vtrack.bench.slam",
    "generate": "vtrack.bench.generate",
    "live": "vtrack.bench.live",
    "globalreg": "vtrack.bench.globalreg",
    "generate_downstream": "vtrack.bench.generate_downstream",
    "heavy": "vtrack.bench.heavy",
    "speed": "vtrack.bench.speed",
}
