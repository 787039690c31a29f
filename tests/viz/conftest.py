"""Viewer test fixture: the tiny session + result folders of :func:`vtrack.testing.viewer.make_view_fixture`."""

from __future__ import annotations

from pathlib import Path

import pytest

from vtrack.testing.viewer import make_view_fixture


@pytest.fixture(scope="session")
def view_fixture(tmp_path_factory) -> dict[str, Path]:
    return make_view_fixture(tmp_path_factory.mktemp("viz") / "tiny")
