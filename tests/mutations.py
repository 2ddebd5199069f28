"""Mutation testing of the evaluation harness: ``pytest --mutation NAME`` breaks the code under
test on purpose, and the ground-truth tests must notice (``tests/test_mutations.py`` checks
that they do; ``docs/testing.md`` lists which test catches which mutation).

Every mutation is applied at a seam that every method passes through, so any method —
today's and future ones — is graded the same way:

* :func:`arlight.layers.composite` — the one compositing equation
  (``composite-mixed``, ``mask-0``, ``mask-1``, ``delta-0``);
* :meth:`arlight.methods.base.Layers.assemble` — where a method hands over its layers
  (``radiance-5pct``);
* :class:`arlight.methods.base.RenderSettings` — the settings every method renders with
  (``depth-3``).

The ground-truth renderer (:mod:`arlight.synthetic`, Mitsuba's own ``mi.render``) uses none
of these seams, so mutations leave the synthetic photographs alone; ``tests/test_mutations.py``
checks that bit for bit. The plugin is registered by ``tests/conftest.py``; without
``--mutation`` it does nothing.

Adding a mutation: write ``apply(patch) -> None`` that replaces attributes through
``patch(obj, name, value)`` (undone at the end of the session), add it to :data:`MUTATIONS`
with a one-line description, and add it to the table in ``docs/testing.md`` after a run of
``tests/test_mutations.py``.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pytest

Patch = Callable[[object, str, object], None]


@dataclass(frozen=True)
class Mutation:
    description: str
    apply: Callable[[Patch], None]


def _patch_function(patch: Patch, module: str, name: str, replacement: Callable) -> None:
    """Replace function ``module.name`` and every reference to it that an ``arlight`` module
    took with ``from module import name`` (so callers see the mutant wherever they bound it)."""
    original = getattr(sys.modules[module], name)
    for modname, mod in list(sys.modules.items()):
        if modname == "arlight" or modname.startswith("arlight."):
            for attr, value in list(vars(mod).items()):
                if value is original:
                    patch(mod, attr, replacement)


def _composite_with(transform: Callable) -> Callable[[Patch], None]:
    """A mutation of :func:`arlight.layers.composite` that rewrites its arguments (or its
    result) with ``transform(background, mixed, delta, mask, original) -> image``."""

    def apply(patch: Patch) -> None:
        import arlight.layers

        original = arlight.layers.composite

        def mutant(background, mixed, delta, mask):
            return transform(background, mixed, delta, mask, original)

        _patch_function(patch, "arlight.layers", "composite", mutant)

    return apply


def _radiance_5pct(patch: Patch) -> None:
    from arlight.methods.base import Layers

    original = Layers.assemble

    def assemble(background, mixed, delta, mask, **kwargs):
        if kwargs.get("real") is not None:
            kwargs["real"] = np.asarray(kwargs["real"]) * 1.05
        return original(background, np.asarray(mixed) * 1.05, np.asarray(delta) * 1.05, mask,
                        **kwargs)

    patch(Layers, "assemble", staticmethod(assemble))


def _depth_3(patch: Patch) -> None:
    from arlight.methods.base import RenderSettings

    original = RenderSettings.__post_init__

    def post_init(self) -> None:
        original(self)
        if self.max_depth == -1 or self.max_depth > 3:
            self.max_depth = 3

    patch(RenderSettings, "__post_init__", post_init)


MUTATIONS: dict[str, Mutation] = {
    "composite-mixed": Mutation(
        "composite := I_m (the render replaces the camera frame everywhere)",
        _composite_with(lambda bg, mixed, delta, mask, f: np.array(
            mixed, dtype=np.result_type(bg, mixed)))),
    "mask-0": Mutation(
        "M := 0 (virtual pixels get I_c + I_m - I_r instead of I_m)",
        _composite_with(lambda bg, mixed, delta, mask, f: f(bg, mixed, delta,
                                                            np.zeros_like(mask)))),
    "mask-1": Mutation(
        "M := 1 (I_m everywhere: the frame is dropped)",
        _composite_with(lambda bg, mixed, delta, mask, f: f(bg, mixed, delta,
                                                            np.ones_like(mask)))),
    "delta-0": Mutation(
        "delta := 0 (no shadows, bleeding or reflections on the real scene)",
        _composite_with(lambda bg, mixed, delta, mask, f: f(bg, mixed, np.zeros_like(delta),
                                                            mask))),
    "radiance-5pct": Mutation(
        "+5 % radiance (the method's I_m and I_r, i.e. mixed and delta x1.05)",
        _radiance_5pct),
    "depth-3": Mutation(
        "paths cut to depth 3 (every method's RenderSettings.max_depth forced to <= 3)",
        _depth_3),
}


class Patcher:
    """Attribute replacements that can be undone in reverse order."""

    def __init__(self) -> None:
        self._undo: list[tuple[object, str, object, bool]] = []

    def __call__(self, obj: object, name: str, value: object) -> None:
        had = name in vars(obj)
        self._undo.append((obj, name, vars(obj).get(name), had))
        setattr(obj, name, value)

    def undo(self) -> None:
        while self._undo:
            obj, name, old, had = self._undo.pop()
            if had:
                setattr(obj, name, old)
            else:
                delattr(obj, name)


def apply_mutation(name: str) -> Patcher:
    """Apply mutation ``name`` in this process; ``.undo()`` on the result reverts it."""
    if name not in MUTATIONS:
        raise KeyError(f"unknown mutation {name!r}; known: {', '.join(MUTATIONS)}")
    from arlight.methods import methods

    methods()  # import every method module first, so the scan sees their bindings
    patcher = Patcher()
    try:
        MUTATIONS[name].apply(patcher)
    except BaseException:
        patcher.undo()
        raise
    return patcher


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--mutation", choices=sorted(MUTATIONS), default=None,
                     help="break the code under test on purpose (see tests/mutations.py): "
                          + "; ".join(f"{k}: {m.description}" for k, m in MUTATIONS.items()))


@pytest.fixture(scope="session", autouse=True)
def mutation_session(request: pytest.FixtureRequest):
    """Applies ``--mutation`` for the whole session (after collection, before the first
    test) and reverts it at the end."""
    name = request.config.getoption("--mutation")
    if not name:
        yield None
        return
    patcher = apply_mutation(name)
    try:
        yield name
    finally:
        patcher.undo()
