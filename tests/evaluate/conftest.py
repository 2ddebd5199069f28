"""Fixtures of the evaluation tests: a private synthetic-photo cache per test session."""

from __future__ import annotations

import os
import shutil

import pytest

WARM_CACHE_ENV = "ARLIGHT_TEST_WARM_CACHE"
"""A folder of ground-truth photographs rendered by an earlier, unmutated run
(``tests/test_mutations.py`` sets it): copied into the session's cache, so the photographs are
not rendered again and the original folder is never written."""


@pytest.fixture(scope="session")
def eval_cache(tmp_path_factory):
    """A cache folder shared by the evaluation tests (frames are rendered once per session)."""
    cache = tmp_path_factory.mktemp("arlight-cache")
    warm = os.environ.get(WARM_CACHE_ENV)
    if warm:
        shutil.copytree(warm, cache, dirs_exist_ok=True)
    return cache
