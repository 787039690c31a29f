"""Synthetic test data: the one home of the builders used by tests, benchmarks and the demo cache.

Nothing heavy is imported here; each module imports what it needs when a builder is called.

- :mod:`vtrack.testing.sim`: cached simulator sessions of the default scene (``tiny_session_path``,
  ``ycb_session``, ``ycb_objects``; ``SIM_CACHE_VERSION`` keys the cache).
- :mod:`vtrack.testing.sessions`: tiny deterministic sessions written with the session API, no simulator
  (``write_synthetic_session`` for the batch engine, ``write_live_session``, ``write_sphere_session``).
- :mod:`vtrack.testing.observations`: ray-cast vision + touch observations of a mesh in the object frame
  (fusion tests and the quick fusion benchmark).
- :mod:`vtrack.testing.sequences`: ray-cast tracking sequences (``make_sequence``, ``run_sequence``;
  implemented in :mod:`vtrack.tracking.synth`).
- :mod:`vtrack.testing.views`: single synthetic views of a mesh for global registration (``synthetic_frame``).
- :mod:`vtrack.testing.recordings`: other tools' recordings (FeelSight logs, ROS 1/2 bags, MCAP) and
  tactile videos, for the importer and recorder tests.
- :mod:`vtrack.testing.viewer`: a tiny session with reconstruction and tracking result folders for the
  viewer tests.
"""
