"""Fixtures of the evaluation tests: ``eval_cache``, the session's private synthetic-photo
cache, lives in ``tests/conftest.py`` (``tests/test_mutations.py`` shares it)."""

from __future__ import annotations

from tests.conftest import WARM_CACHE_ENV  # noqa: F401 (re-exported)
