"""Live pipeline: a stream source (a recorder, or a session replayed at real-time rate) feeds
online consumers (tracking, reconstruction, viewer), dropping frames rather than falling behind.

- :mod:`vtrack.live.sources`: :class:`SessionReplaySource` (real-time replay of a session).
- :mod:`vtrack.live.pipeline`: :class:`LivePipeline` (one worker per consumer, latest-frame
  mailboxes, drop/rate/latency statistics).
- :mod:`vtrack.live.consumers`: ``null`` (throughput), ``track`` (KnownShapeTracker.step per camera
  frame), ``reconstruct`` (TSDF integration per camera frame).
"""
