"""The on-disk cache directory shared by the ground truth and the methods.

``$ARLIGHT_CACHE`` or ``~/.cache/arlight``; the synthetic photographs live in
``synthetic/``, the PRT transfer in ``prt/``. Its own module so that a method (PRT) and the
ground truth (:mod:`arlight.synthetic`) share a path, not code. Core tier: imports nothing of
arlight.
"""

from __future__ import annotations

import os
from pathlib import Path


def default_cache_dir() -> Path:
    """``$ARLIGHT_CACHE`` or ``~/.cache/arlight``."""
    return Path(os.environ.get("ARLIGHT_CACHE", Path.home() / ".cache" / "arlight"))


__all__ = ["default_cache_dir"]
