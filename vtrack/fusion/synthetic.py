"""Moved to :mod:`vtrack.testing.observations` (the one home of synthetic test data); this name is kept only so code
written against the old path keeps working until every branch has moved. Do not add code here."""

from vtrack.testing.observations import make_observations, raycast_depth, ring_cameras  # noqa: F401
