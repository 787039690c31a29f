"""Moved to :mod:`vtrack.testing.sim` (the one home of synthetic test data); this name is kept only so code
written against the old path keeps working until every branch has moved. Do not add code here."""

from vtrack.testing.sim import DEFAULT_OBJECT, SIM_CACHE_VERSION, tiny_session_path, ycb_objects, ycb_session  # noqa: F401
