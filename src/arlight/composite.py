"""Compatibility shim: the compositing equation lives in :mod:`arlight.layers`.

Kept so that ``from arlight.composite import composite`` keeps working; new code imports
:func:`arlight.layers.composite`.
"""

from arlight.layers import composite

__all__ = ["composite"]
