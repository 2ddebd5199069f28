"""Fixtures of the evaluation tests: a private synthetic-photo cache per test session."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def eval_cache(tmp_path_factory):
    """A cache folder shared by the evaluation tests (frames are rendered once per session)."""
    return tmp_path_factory.mktemp("arlight-cache")
