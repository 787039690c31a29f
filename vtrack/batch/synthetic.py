"""Moved to :mod:`vtrack.testing.sessions` (the one home of synthetic test data); this name is kept only so code
written against the old path keeps working until every branch has moved. Do not add code here."""

from vtrack.testing.sessions import write_synthetic_session  # noqa: F401
