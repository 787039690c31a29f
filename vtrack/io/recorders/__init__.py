"""Recorders: write live sensor data into a session, frame by frame.

- :mod:`vtrack.io.recorders.oakd`: Luxonis OAK-D (depthai 3.x): colour + stereo depth aligned to
  colour, device timestamps, calibration, optional IMU.
- :mod:`vtrack.io.recorders.tactile`: DIGIT / GelSight Mini UVC cameras via OpenCV, with the
  hand's joint states from :mod:`vtrack.io.recorders.joints`.
- :mod:`vtrack.io.recorders.base`: status line, clean Ctrl-C stop, recording statistics.

Recording is crash-safe: frames are committed every ``flush_every`` frames per stream
(:class:`~vtrack.io.session.SessionWriter`); a killed recorder leaves every committed frame readable.
"""
