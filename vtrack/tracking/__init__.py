"""In-hand object pose tracking from vision and touch (known shape and SLAM).

Modules (heavy dependencies are imported inside functions):

- :mod:`~vtrack.tracking.frame`: the per-frame input (:class:`TrackingFrame`, world frame).
- :mod:`~vtrack.tracking.sdf_grid`: dense object-frame SDF grid with trilinear value + gradient.
- :mod:`~vtrack.tracking.window`: robust sliding-window LM on SE(3) (the core optimiser).
- :mod:`~vtrack.tracking.tracker`: :class:`KnownShapeTracker` (SDF from the mesh).
- :mod:`~vtrack.tracking.slam`: :class:`SLAMTracker` (shape mapped while tracking).
- :mod:`~vtrack.tracking.icp`: Open3D point-to-plane ICP baseline.
- :mod:`~vtrack.tracking.frontend`, :mod:`~vtrack.tracking.run`: sessions -> frames -> result folders.
- :mod:`~vtrack.tracking.synth`: tiny synthetic sequences for tests and the quick benchmark.
"""
