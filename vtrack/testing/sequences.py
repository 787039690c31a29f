"""Ray-cast tracking sequences (no hand model) for tests and the quick tracking benchmark.

The implementation lives in :mod:`vtrack.tracking.synth` (owned with the trackers); this is its entry in
the test-data home so every builder is found under :mod:`vtrack.testing`.
"""

from vtrack.tracking.synth import SynthSequence, make_sequence, run_sequence

__all__ = ["SynthSequence", "make_sequence", "run_sequence"]
