"""Real photographs: register a camera on a printed marker, build the proxy, the light and
the surface albedo, insert a virtual object and render it (``arlight insert``;
``docs/insert.md``).

The names below are imported lazily, so ``arlight --help`` does not load OpenCV."""

from __future__ import annotations

from typing import Any

__all__ = ["InsertRequest", "InsertResult", "build_scene", "run_insert"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        from arlight.insert import pipeline

        return getattr(pipeline, name)
    raise AttributeError(f"module 'arlight.insert' has no attribute {name!r}")
