"""What a method declares about itself: name, description, typed options, capabilities.

    SPEC = MethodSpec(
        name="mymethod",
        description="One line that `arlight methods` prints.",
        options={"reproject": Field("bool", True, "camera-image reprojection (Kán §5.2)")},
        capabilities=Capabilities(interactive=True, progressive=True),
    )
    opts = SPEC.parse_options({"reproject": "false"})     # Options(reproject=False)
    opts.reproject, opts["reproject"]

Options are declared with the :class:`~arlight.scene.schema.Field` tables of the scene format
and validated by its :class:`~arlight.scene.schema.Validator`, so they have the same kinds,
ranges, units and error messages as scene fields (errors name ``options.<key>``; unknown keys
list the known ones). Strings from the command line are first converted by the field's kind
(``"false"`` → False for ``bool``, ``"4"`` → 4 for ``int``, ``"0.5,0.5,0.5"`` → a list for
``rgb``/``vec3``), so ``--option reproject=false`` and ``options={"reproject": False}`` mean
the same.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from arlight.denoise.options import NAMES as DENOISE_NAMES
from arlight.denoise.options import NOT_NOISY
from arlight.denoise.options import OPTIONS as DENOISE_OPTIONS
from arlight.scene.schema import (
    LIGHT_TYPES,
    MATERIAL_TYPES,
    REQUIRED,
    SHAPE_TYPES,
    Field,
    Validator,
)

_TRUE = ("true", "yes", "on", "1")
_FALSE = ("false", "no", "off", "0")
_VECTOR_KINDS = ("rgb", "vec2", "vec3", "rgb_list", "mat4")


class Options(Mapping[str, Any]):
    """Validated method options with defaults filled in (read-only).

    Read as attributes (``opts.reproject``) or items (``opts["reproject"]``); compares equal
    to a dict with the same items.
    """

    __slots__ = ("_values",)

    def __init__(self, values: Mapping[str, Any] | None = None) -> None:
        object.__setattr__(self, "_values", dict(values or {}))

    def __getattr__(self, name: str) -> Any:
        try:
            return self._values[name]
        except KeyError:
            raise AttributeError(f"no option {name!r}; options: "
                                 f"{', '.join(self._values) or 'none'}") from None

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("Options are read-only")

    def __getitem__(self, key: str) -> Any:
        return self._values[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._values)

    def __len__(self) -> int:
        return len(self._values)

    def __repr__(self) -> str:
        return "Options(" + ", ".join(f"{k}={v!r}" for k, v in self._values.items()) + ")"


@dataclass(frozen=True)
class Capabilities:
    """What a method can do and what it needs; the harness skips cells it cannot handle.

    Attributes:
        interactive: meant to run per frame at interactive rates (a preview or real-time
            method), not only offline.
        progressive: renders with different seeds are independent, unbiased estimates, so
            their running mean converges (``arlight render --progressive``).
        needs_depth: needs the frame's depth image (RGB-D input).
        needs_frame: needs the background frame ``I_c`` (every differential method does).
        materials: supported material types (default: all of
            :data:`arlight.scene.schema.MATERIAL_TYPES`).
        lights: supported light types (default: all of
            :data:`arlight.scene.schema.LIGHT_TYPES`).
        virtual_shapes: shape types a virtual object may have (default: all of
            :data:`arlight.scene.schema.SHAPE_TYPES`; e.g. per-vertex transfer needs
            triangle meshes).
        noisy: renders carry Monte Carlo noise (default: ``progressive``); such a method
            gets the denoiser's options (:data:`arlight.denoise.options.OPTIONS`) as frame
            options, and a deterministic one refuses them.
    """

    interactive: bool = False
    progressive: bool = False
    needs_depth: bool = False
    needs_frame: bool = True
    materials: frozenset[str] = frozenset(MATERIAL_TYPES)
    lights: frozenset[str] = frozenset(LIGHT_TYPES)
    virtual_shapes: frozenset[str] = frozenset(SHAPE_TYPES)
    noisy: bool | None = None

    def __post_init__(self) -> None:
        if self.noisy is None:
            object.__setattr__(self, "noisy", self.progressive)
        for name, known in (("materials", MATERIAL_TYPES), ("lights", LIGHT_TYPES),
                            ("virtual_shapes", SHAPE_TYPES)):
            value = frozenset(getattr(self, name))
            object.__setattr__(self, name, value)
            unknown = sorted(value - set(known))
            if unknown:
                raise ValueError(f"capabilities.{name}: unknown type(s) {', '.join(unknown)}; "
                                 f"known: {', '.join(known)}")

    def summary(self) -> dict[str, str]:
        """Human-readable values, one line each (for ``arlight methods NAME``)."""

        def types(have: frozenset[str], every: Mapping[str, Any]) -> str:
            return "all" if have == frozenset(every) else (", ".join(sorted(have)) or "none")

        def yes(flag: bool) -> str:
            return "yes" if flag else "no"

        return {"interactive": yes(self.interactive), "progressive": yes(self.progressive),
                "needs depth": yes(self.needs_depth), "needs frame": yes(self.needs_frame),
                "Monte Carlo noise": yes(bool(self.noisy)),
                "materials": types(self.materials, MATERIAL_TYPES),
                "lights": types(self.lights, LIGHT_TYPES),
                "virtual shapes": types(self.virtual_shapes, SHAPE_TYPES)}


def _coerce(value: Any, spec: Field) -> Any:
    """A command-line string converted by the field's kind; anything else unchanged (the
    validator then reports what is wrong)."""
    if not isinstance(value, str):
        return value
    text = value.strip()
    try:
        if spec.kind == "bool" and text.lower() in _TRUE + _FALSE:
            return text.lower() in _TRUE
        if spec.kind == "int":
            return int(text)
        if spec.kind == "float":
            return float(text)
        if spec.kind in _VECTOR_KINDS:
            if text.startswith("["):
                return json.loads(text)
            parts = [float(x) for x in text.split(",")]
            return parts[0] if len(parts) == 1 and spec.kind == "rgb" else parts
    except ValueError:  # json.JSONDecodeError is a ValueError
        return value
    return value


@dataclass(frozen=True)
class MethodSpec:
    """A method's self-description.

    Attributes:
        name: the registered name (``arlight render -m NAME``).
        description: one line for ``arlight methods``.
        options: option name -> :class:`~arlight.scene.schema.Field` (kind, default, doc,
            unit, range, choices), as in the scene schema.
        capabilities: what the method supports and needs.
        check: optional cross-option check, called with the validated options; raises
            :class:`InputError` naming ``options.<key>``.
        frame_options: options that only choose what a frame draws (e.g. ``sample_offset``)
            and never enter preparation: a render may set them differently from the options
            the world was prepared with.
        drag_options: ``(options, factor) -> {option: value}``: the options of a frame the
            studio renders at 1/``factor`` of its size while the pointer drags (issue #32),
            for per-frame work that does not shrink with the image (RSM size, volume
            resolution, propagation steps, VPL count); None: the same options at every
            size. Where they change preparation options the studio prepares a second state
            for drag frames (off the render path).
    """

    name: str
    description: str
    options: Mapping[str, Field] = field(default_factory=dict)
    capabilities: Capabilities = field(default_factory=Capabilities)
    check: Callable[[Options], None] | None = None
    frame_options: frozenset[str] = frozenset()
    drag_options: Callable[[Options, int], dict[str, Any]] | None = None

    def drag(self, opts: Options, factor: int) -> dict[str, Any]:
        """The option overrides of a drag frame at downscale ``factor`` (:attr:`drag_options`;
        none at factor 1 or without them), validated like any options."""
        if factor <= 1 or self.drag_options is None:
            return {}
        out = self.drag_options(opts, factor)
        self.parse_options({**opts, **out})  # a spec's own ladder must stay in range
        return out

    def __post_init__(self) -> None:
        if not self.name or any(c.isspace() or c in ".=,+" for c in self.name):
            raise ValueError(f"method name {self.name!r}: no spaces, dots, commas, '=' or "
                             "'+' (eval's variants)")
        if "\n" in self.description.strip():
            raise ValueError(f"method {self.name!r}: the description must be one line")
        if self.capabilities.noisy:  # the denoiser's options, never preparation options
            object.__setattr__(self, "options", {**self.options, **DENOISE_OPTIONS})
            object.__setattr__(self, "frame_options",
                               frozenset(self.frame_options) | DENOISE_NAMES)
        if extra := sorted(set(self.frame_options) - set(self.options)):
            raise ValueError(f"method {self.name!r}: frame option {extra[0]!r} is not an option")

    def preparation_options(self, opts: Options) -> dict[str, Any]:
        """``opts`` without the :attr:`frame_options` (what preparation may depend on)."""
        return {k: v for k, v in opts.items() if k not in self.frame_options}

    def parse_options(self, raw: Mapping[str, Any] | None) -> Options:
        """Validate ``raw`` (e.g. ``RenderSettings.options``) and fill in the defaults.

        Raises :class:`InputError` naming ``options.<key>``: for an unknown key (the message
        lists the known options), a value of the wrong kind or out of range, a missing
        required option, or a failed cross-option check.
        """
        raw = dict(raw or {})
        v = Validator(f"method {self.name!r}", Path.cwd())
        unknown = sorted(set(raw) - set(self.options))
        if unknown and unknown[0] in DENOISE_NAMES:
            raise v.fail(f"options.{unknown[0]}", NOT_NOISY.format(method=self.name))
        if unknown:
            known = ", ".join(sorted(self.options))
            raise v.fail(f"options.{unknown[0]}",
                         f"unknown option; known options: {known}" if known else
                         f"unknown option; {self.name} takes no options")
        coerced = {k: _coerce(val, self.options[k]) for k, val in raw.items()}
        opts = Options(v.fields(coerced, dict(self.options), "options"))
        if self.check is not None:
            self.check(opts)
        return opts

    def defaults(self) -> Options:
        """The options with every default (fails if an option is required)."""
        return self.parse_options({})

    def unsupported_reason(self, world, view=None) -> str | None:
        """Why this method cannot render ``world`` (seen in ``view``), or None if it can.

        ``world`` is anything with ``shapes`` and ``lights`` (a World or an ARScene);
        ``view`` anything with ``frame`` and ``depth`` (a FrameView or an ARScene; None:
        only the world is checked).
        """
        caps = self.capabilities
        mats = sorted({s.material.type for s in world.shapes} - caps.materials)
        if mats:
            return (f"{self.name} does not support material type {', '.join(mats)} "
                    f"(supports {', '.join(sorted(caps.materials)) or 'none'})")
        lights = sorted({x.type for x in world.lights} - caps.lights)
        if lights:
            return (f"{self.name} does not support light type {', '.join(lights)} "
                    f"(supports {', '.join(sorted(caps.lights)) or 'none'})")
        shapes = sorted({s.type for s in world.shapes if s.is_virtual} - caps.virtual_shapes)
        if shapes:
            return (f"{self.name} does not support virtual {', '.join(shapes)} shapes "
                    f"(supports {', '.join(sorted(caps.virtual_shapes))})")
        if view is not None:
            if caps.needs_frame and view.frame is None:
                return f"{self.name} needs a background frame; the scene has none"
            if caps.needs_depth and view.depth is None:
                return f"{self.name} needs a depth image; the scene has none"
        return None

    def options_rows(self) -> list[tuple[str, str, str, str, str]]:
        """(name, type, default, unit, doc) per option, for tables."""
        rows = []
        for name, f in self.options.items():
            kind = f.kind if not f.choices else " | ".join(f.choices)
            default = "required" if f.default is REQUIRED else (
                "—" if f.default is None else f.default if isinstance(f.default, str)
                else json.dumps(f.default))
            rows.append((name, kind, default, f.unit, f.doc))
        return rows


def parse_option_pairs(pairs: list[str], form: str = "key=value") -> dict[str, str]:
    """``--option`` arguments as ``{key: value}``; values stay strings (each method's option
    table converts them by kind, see :meth:`MethodSpec.parse_options`). ``form`` is how the
    error message spells a valid pair."""
    from arlight.errors import InputError

    out: dict[str, str] = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip():
            raise InputError(f"expected {form}, got {pair!r}", field="--option")
        out[key.strip()] = value
    return out


__all__ = ["Capabilities", "Field", "MethodSpec", "Options", "parse_option_pairs"]
