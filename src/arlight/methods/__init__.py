"""Method registry: every rendering method registers itself here by name.

    from arlight.methods import get_method
    layers = get_method("reference")(scene, RenderSettings(spp=64))

A new method is a module in this package (or anywhere) with a function decorated by
``@register("name")``; built-in modules are imported on first lookup, so the CLI and the
evaluation harness see every method without special cases.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable

from arlight.errors import InputError
from arlight.methods.base import Layers, RenderSettings, require_frame
from arlight.scene.model import ARScene

RenderFn = Callable[[ARScene, RenderSettings], Layers]
_REGISTRY: dict[str, RenderFn] = {}
_DOCS: dict[str, str] = {}
BUILTIN_MODULES = ("arlight.methods.reference", "arlight.methods.onepass")


def register(name: str) -> Callable[[RenderFn], RenderFn]:
    """Decorator: register ``fn(scene, settings) -> Layers`` under ``name``."""

    def wrap(fn: RenderFn) -> RenderFn:
        def named(scene: ARScene, settings: RenderSettings) -> Layers:
            layers = fn(scene, settings)
            layers.method = name
            return layers

        named.__doc__ = fn.__doc__
        named.__name__ = fn.__name__
        _REGISTRY[name] = named
        _DOCS[name] = (fn.__doc__ or "").strip().splitlines()[0] if fn.__doc__ else ""
        return named

    return wrap


def _load_builtins() -> None:
    for mod in BUILTIN_MODULES:
        importlib.import_module(mod)


def available_methods() -> dict[str, str]:
    """Registered method names with their one-line descriptions."""
    _load_builtins()
    return dict(sorted(_DOCS.items()))


def get_method(name: str) -> RenderFn:
    """The render function registered as ``name``; an error lists the known names."""
    _load_builtins()
    if name not in _REGISTRY:
        raise InputError(f"unknown method {name!r}; available: "
                         f"{', '.join(sorted(_REGISTRY)) or 'none'}", field="method")
    return _REGISTRY[name]


__all__ = ["Layers", "RenderSettings", "available_methods", "get_method", "register",
           "require_frame"]
