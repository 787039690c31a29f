"""Synthetic in-hand visuo-tactile sessions with exact ground truth (``vtrack.sim.generate``)."""
