"""Importers: convert recordings made with other tools into vtrack sessions.

- :mod:`vtrack.io.importers.feelsight`: the FeelSight / NeuralFeels folder layout.
- :mod:`vtrack.io.importers.rosbag`: ROS 1 bags and ROS 2 bag folders (``rosbags``).
- :mod:`vtrack.io.importers.mcap_import`: MCAP files (``mcap`` reader + ROS CDR decoding from ``rosbags``).

Every importer returns an :class:`~vtrack.io.importers.report.ImportReport` that lists the
streams written and everything it skipped (and why).
"""

from vtrack.io.importers.report import ImportReport

__all__ = ["ImportReport"]
