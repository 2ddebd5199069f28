"""Method registry: every rendering method is found here by name.

    from arlight.methods import get_method, RenderSettings
    method = get_method("onepass")
    layers = method(scene, RenderSettings(spp=64))                   # one-shot
    state = method.prepare(scene.world, settings)                    # once per world
    layers = method.render(state, scene.view, settings)              # per frame
    method.spec.name, method.spec.options, method.spec.capabilities

Methods are discovered through the package entry-point group ``arlight.methods``: a package
declares

    [project.entry-points."arlight.methods"]
    mymethod = "mypackage.mymethod:MyMethod"

(a :class:`Method` class, instantiated without arguments, or an instance) and the CLI, the
evaluation harness and progressive rendering find it with no list to edit. The built-ins
are declared the same way in arlight's ``pyproject.toml`` and are also loaded directly when
the package metadata is missing (a source tree without ``pip install -e .``). In-process
code can :func:`register` a method instance or class, or a plain ``fn(scene, settings) ->
Layers`` with ``@register("name")``. An entry point that fails to load is reported by
:func:`load_errors` and ``arlight methods``, and only its own name fails to resolve.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import types
import warnings
from collections.abc import Callable, Mapping
from typing import Any

from arlight.errors import InputError
from arlight.methods.base import (
    BaseMethod,
    FunctionMethod,
    Layers,
    Method,
    Prepared,
    RenderFn,
    RenderSettings,
    require_frame,
)
from arlight.methods.spec import Capabilities, Field, MethodSpec, Options

ENTRY_POINT_GROUP = "arlight.methods"
BUILTINS: dict[str, str] = {
    "reference": "arlight.methods.reference:ReferenceMethod",
    "onepass": "arlight.methods.onepass:OnePassMethod",
    "dlpv": "arlight.methods.dlpv:DLPVMethod", "dir": "arlight.methods.dir:DIRMethod",
    "probeless": "arlight.methods.probeless:ProbelessMethod",
    "dvct": "arlight.methods.dvct:DVCTMethod",
    "ibl": "arlight.methods.ibl:IBLMethod", "prt": "arlight.methods.prt:PRTMethod",
    "dic": "arlight.methods.dic:DicMethod",
    "nearfield": "arlight.methods.nearfield:NearFieldMethod",
}
"""Built-in methods as entry-point values (the fallback when package metadata is missing)."""

_REGISTRY: dict[str, Method] = {}
_ERRORS: dict[str, str] = {}  # entry-point name -> why it failed to load
_discovered = False


def _as_method(obj: Any) -> Method:
    """A Method instance from a Method class or instance (TypeError otherwise)."""
    if isinstance(obj, type):
        obj = obj()
    if not isinstance(getattr(obj, "spec", None), MethodSpec) or not all(
            callable(getattr(obj, a, None)) for a in ("prepare", "render", "__call__")):
        raise TypeError(f"{obj!r} is not a Method: it needs a MethodSpec `spec`, `prepare`, "
                        "`render` and `__call__` (subclass arlight.methods.BaseMethod)")
    return obj


def _add(method: Method, replace: bool = True) -> Method:
    name = method.spec.name
    if not replace and name in _REGISTRY and _REGISTRY[name] is not method:
        return _REGISTRY[name]
    _REGISTRY[name] = method
    _ERRORS.pop(name, None)
    return method


def register(target: Any = None, /, *, description: str | None = None,
             options: Mapping[str, Field] | None = None,
             capabilities: Capabilities | None = None) -> Any:
    """Register a method; returns what it was given, so it works as a decorator.

    * ``register(MyMethod)`` / ``@register`` on a :class:`BaseMethod` subclass: registers an
      instance under ``MyMethod.spec.name``.
    * ``register(instance)``: registers a :class:`Method` instance.
    * ``@register("name", description=..., options=..., capabilities=...)`` on a plain
      ``fn(scene, settings) -> Layers``: wraps it in a :class:`FunctionMethod` (description
      defaults to the docstring's first line; options default to none).

    A later registration of the same name replaces the earlier one.
    """
    if isinstance(target, str):
        name = target

        def wrap(fn: RenderFn) -> RenderFn:
            doc = description
            if doc is None:
                doc = (fn.__doc__ or "").strip().splitlines()[0] if fn.__doc__ else ""
            spec = MethodSpec(name=name, description=doc, options=dict(options or {}),
                              capabilities=capabilities or Capabilities())
            _add(FunctionMethod(fn, spec))
            return fn

        return wrap
    if target is None:
        raise TypeError("register() needs a Method class or instance, or a name")
    _add(_as_method(target))
    return target


def unregister(name: str) -> None:
    """Remove ``name`` from the registry (tests; a discovered method returns on
    :func:`refresh`)."""
    _REGISTRY.pop(name, None)
    _ERRORS.pop(name, None)


def _load(name: str, loader: Callable[[], Any]) -> None:
    try:
        obj = loader()
        if isinstance(obj, types.ModuleType):  # a module: importing it registered its methods
            return
        method = _as_method(obj)
        if method.spec.name != name:
            raise TypeError(f"entry point {name!r} loads method {method.spec.name!r}; the "
                            "names must match")
        _add(method, replace=False)
    except Exception as exc:  # noqa: BLE001 — a broken plug-in must not break the others
        _ERRORS[name] = f"{type(exc).__name__}: {exc}"
        warnings.warn(f"arlight method {name!r} failed to load: {_ERRORS[name]}",
                      RuntimeWarning, stacklevel=3)


def _load_value(value: str) -> Any:
    module, _, attr = value.partition(":")
    obj: Any = importlib.import_module(module)
    for part in filter(None, attr.split(".")):
        obj = getattr(obj, part)
    return obj


def refresh() -> None:
    """(Re)discover methods: entry points of group ``arlight.methods``, then the built-ins
    that are still missing. Methods registered in-process stay."""
    global _discovered
    _discovered = True
    for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        if ep.name not in _REGISTRY:
            _load(ep.name, ep.load)
    for name, value in BUILTINS.items():
        if name not in _REGISTRY:
            _load(name, lambda v=value: _load_value(v))


def _discover() -> None:
    if not _discovered:
        refresh()


def methods() -> dict[str, Method]:
    """Every registered method by name, sorted."""
    _discover()
    return dict(sorted(_REGISTRY.items()))


def available_methods() -> dict[str, str]:
    """Registered method names with their one-line descriptions, sorted."""
    return {name: m.spec.description for name, m in methods().items()}


def load_errors() -> dict[str, str]:
    """Entry points that failed to load: name -> reason."""
    _discover()
    return dict(_ERRORS)


def get_method(name: str) -> Method:
    """The method registered as ``name``; an error lists the known names."""
    _discover()
    if name in _REGISTRY:
        return _REGISTRY[name]
    if name in _ERRORS:
        raise InputError(f"method {name!r} failed to load: {_ERRORS[name]}", field="method")
    raise InputError(f"unknown method {name!r}; available: "
                     f"{', '.join(sorted(_REGISTRY)) or 'none'}", field="method")


__all__ = ["BaseMethod", "Capabilities", "ENTRY_POINT_GROUP", "Field", "FunctionMethod",
           "Layers", "Method", "MethodSpec", "Options", "Prepared", "RenderSettings",
           "available_methods", "get_method", "load_errors", "methods", "refresh", "register",
           "require_frame", "unregister"]
