"""Visualisation: the interactive viser viewer, pyvista screenshots and shared matplotlib plots.

- :mod:`vtrack.viz.data` loads a session and/or result folder into a backend-neutral
  :class:`~vtrack.viz.data.ViewData` (static geometry + per-frame state).
- :mod:`vtrack.viz.viewer` serves it in the browser with viser (``vtrack view PATH``).
- :mod:`vtrack.viz.screenshot` renders the same scene offscreen with pyvista
  (:func:`~vtrack.viz.screenshot.render_result`).
- :mod:`vtrack.viz.plots` error-over-time and speed-vs-error (Pareto) plots for benchmarks.

Nothing heavy is imported here: viser, pyvista, trimesh and matplotlib load inside the modules
that need them.
"""
