"""Compatibility shim: variant selection lives in :mod:`arlight.jit` (core tier, so that
``io`` and ``sampling`` need not import the backend). New code imports
``arlight.jit.ensure_variant``."""

from arlight.jit import ensure_variant

__all__ = ["ensure_variant"]
