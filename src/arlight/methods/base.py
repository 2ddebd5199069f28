"""What every method consumes and produces, and the interface a method implements.

* :class:`RenderSettings` — samples, depth, seed and the method's options.
* :class:`Layers` — ``mixed`` (I_m, virtual objects under the real light), ``delta``
  (I_m − I_r, how the real scene changes), ``mask``, the composite (defined in
  :mod:`arlight.layers`, re-exported here), timings and counters.
* :class:`Method` — the protocol: a :class:`~arlight.methods.spec.MethodSpec` (name, typed
  options, capabilities), ``prepare(world, settings) -> state`` for scene-level work,
  ``render(state, view, settings) -> Layers`` per frame, and the one-shot
  ``method(scene, settings)`` that calls both.
* :class:`BaseMethod` — the usual way to implement it: write ``prepare_world`` and
  ``render_view``; option validation, capability checks, posed worlds, the ``time_prepare``
  / ``seconds`` stats and ``Layers.method`` are done once here. See
  ``docs/methods/writing-a-method.md``.
"""

from __future__ import annotations

import threading
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Protocol, runtime_checkable

import numpy as np

from arlight.denoise.options import NAMES as DENOISE_NAMES
from arlight.denoise.options import DenoiseSettings, delta_form
from arlight.errors import InputError
from arlight.layers import Layers
from arlight.methods.spec import MethodSpec, Options
from arlight.scene.load import RENDER_DEFAULTS
from arlight.scene.model import ARScene, FrameView, Light, World
from arlight.timing import StageTimer

if TYPE_CHECKING:
    from arlight.backend.mitsuba_scene import SceneViews


@dataclass
class RenderSettings:
    """Settings shared by the methods.

    Attributes:
        spp: samples per pixel (stratified, multi-jittered, when a perfect square).
        max_depth: longest path in vertices, Mitsuba's convention (1: emitters seen directly,
            2: direct lighting only, -1: unlimited with Russian roulette).
        rr_depth: path depth from which Russian roulette starts.
        seed: master seed; equal seeds give bitwise identical renders.
        spp_per_pass: samples per wavefront pass (None: as many as fit in ~2M lanes).
        progress: show a progress bar.
        options: method options, validated against the method's ``spec.options`` (unknown
            keys are errors; defaults fill the rest; ``arlight methods NAME`` lists them).
    """

    spp: int = RENDER_DEFAULTS["spp"]  # the one set of defaults, shared with scene files
    max_depth: int = RENDER_DEFAULTS["max_depth"]
    rr_depth: int = 5
    seed: int = RENDER_DEFAULTS["seed"]
    spp_per_pass: int | None = None
    progress: bool = False
    options: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.spp < 1:
            raise InputError(f"must be >= 1, got {self.spp}", field="spp")
        if self.max_depth == 0 or self.max_depth < -1:
            raise InputError(f"must be -1 or >= 1, got {self.max_depth}", field="max_depth")


def require_frame(view: Any, source: Path | str | None = None) -> np.ndarray:
    """The background frame of ``view`` (a FrameView or an ARScene), or an error naming the
    scene file (``source``, default ``view.source`` where it has one)."""
    if view.frame is None:
        src = source if source is not None else getattr(view, "source", None)
        raise InputError("the scene has no background frame; add a [frame] table with "
                         "`image = ...` (or synthesise one with `arlight synth`)",
                         file=str(src) if src else None, field="frame")
    return view.frame


@runtime_checkable
class Method(Protocol):
    """A rendering method (see ``docs/methods/writing-a-method.md``).

    ``prepare`` does the scene-level work once per world (Mitsuba scenes, acceleration
    structures, voxelisation, precomputation); ``render`` renders one frame from that state
    and must render the posed world ``world.posed(view.object_transforms)`` when the view
    moves objects. ``method(scene, settings)`` is the one-shot form, bitwise equal to
    ``render(prepare(scene.world, settings), scene.view, settings)``.
    """

    spec: MethodSpec

    def prepare(self, world: World, settings: RenderSettings | None = None) -> Any:
        """Scene-level state for ``world``."""
        ...

    def render(self, state: Any, view: FrameView,
               settings: RenderSettings | None = None) -> Layers:
        """Layers of one frame of the prepared world."""
        ...

    def __call__(self, scene: ARScene, settings: RenderSettings | None = None) -> Layers:
        """One-shot: prepare and render ``scene``."""
        ...


@dataclass
class Prepared:
    """The state :meth:`BaseMethod.prepare` returns.

    Attributes:
        method: name of the method that prepared it (render checks it).
        world: the world it was prepared for (rest pose).
        options: the validated options it was prepared with.
        data: what the method's ``prepare_world`` returned (after :meth:`BaseMethod.relight`
            of a state with ``incremental_pose``: the relit data of the last pose).
        seconds: wall time of the preparation (``time_prepare``), seconds.
    """

    method: str
    world: World
    options: Options
    data: Any
    seconds: float
    lock: threading.RLock = field(default_factory=threading.RLock, repr=False, compare=False)
    """Held while a method with ``incremental_pose`` poses the state and renders it."""
    last: Any = field(default=None, repr=False, compare=False)
    """The data of the last incremental pose (:func:`posed_data`), None before the first."""
    last_transforms: dict[str, np.ndarray] | None = field(default=None, repr=False,
                                                          compare=False)
    """The object transforms ``last`` was posed for."""


class BaseMethod(ABC):
    """Implements :class:`Method` around two hooks a method writes.

    * ``prepare_world(world, options, settings) -> data`` — scene-level work, timed as
      ``time_prepare``.
    * ``render_view(data, view, options, settings, timer) -> Layers`` — one frame; time its
      stages with ``timer.stage("trace")`` etc. (they become ``time_<stage>`` stats).

    The base class validates ``settings.options`` against ``spec.options`` (defaults filled,
    unknown keys are errors), refuses worlds and views the capabilities exclude, re-prepares
    the posed world when ``view.object_transforms`` is not empty (stage ``pose``; override
    :meth:`pose` for something cheaper), and sets ``stats["seconds"]`` (wall time of the
    call) and ``Layers.method``.
    """

    spec: ClassVar[MethodSpec]
    incremental_pose: ClassVar[bool] = False
    """True when :meth:`pose` moves the prepared state *in place* (Mitsuba shapes moved
    through their parameters, caches of the moved object updated): :meth:`render` then
    poses every frame — to the rest pose when the view moves nothing — and renders under the
    state's lock, so a state always renders the pose its view asks for."""

    # ------------------------------------------------------------------ hooks
    @abstractmethod
    def prepare_world(self, world: World, options: Options, settings: RenderSettings) -> Any:
        """Scene-level work for ``world`` (rest pose); returns the method's data."""

    @abstractmethod
    def render_view(self, data: Any, view: FrameView, options: Options,
                    settings: RenderSettings, timer: StageTimer) -> Layers:
        """One frame. ``data`` is already posed: ``view.object_transforms`` is empty."""

    def pose(self, state: Prepared, transforms: dict[str, np.ndarray],
             settings: RenderSettings) -> Any:
        """Data for the world posed by ``transforms`` (default: prepare it again).

        A method with ``incremental_pose`` moves the data of its last pose in place with
        :meth:`move` instead (:func:`posed_data`; ``transforms`` empty: back to the rest
        pose), preparing from scratch where ``move`` cannot; its renders must then be
        bitwise those of ``prepare(state.world.posed(transforms))``."""
        def prepare() -> Any:
            return self.prepare_posed(state, transforms, settings)

        if not self.incremental_pose:
            return prepare()
        return posed_data(state, transforms,
                          lambda data: self.move(data, state.world, transforms, state.options),
                          prepare)

    def prepare_posed(self, state: Prepared, transforms: dict[str, np.ndarray],
                      settings: RenderSettings) -> Any:
        """The data of ``state.world.posed(transforms)`` prepared from scratch (what
        :meth:`pose` falls back to): ``prepare_world`` of the posed world; a method whose
        state carries more than its world (e.g. a light given from outside) overrides it."""
        return self.prepare_world(state.world.posed(transforms), state.options, settings)

    def move(self, data: Any, world: World, transforms: dict[str, np.ndarray],
             options: Options) -> Any | None:
        """``data`` (prepared for ``world`` in any pose) moved in place to
        ``world.posed(transforms)``, or None where that cannot be done (e.g. a real shape
        moved): the hook of ``incremental_pose`` methods."""
        raise NotImplementedError(f"{self.spec.name} sets incremental_pose without move()")

    def relight(self, state: Prepared, lights: Sequence[Light],
                settings: RenderSettings | None = None) -> None:
        """Give the prepared ``state`` new real lights in place (issue #32: a new light
        estimate, a moved lamp): the method's :meth:`relit` recomputes only what depends on
        the light (reduced lights, RSMs, light SH, the mip-mapped environment, the Mitsuba
        views' emitters) and keeps the rest (the views' shapes, proxy voxels, occlusion
        fields, PRT transfer); where it cannot, the world with the new lights is prepared
        from scratch. Later renders are bitwise those of ``prepare(replace(state.world,
        lights=lights))`` in any pose. Thread-safe with :meth:`render` (the state's lock).

        Args:
            state: what :meth:`prepare` returned (modified in place: ``world``, ``data``,
                ``last``).
            lights: the new lights (:class:`~arlight.scene.model.Light`, e.g. from a scene
                file's ``[[lights]]`` or ``LightEstimate.to_scene_lights`` loaded as a
                scene); the same lights again do nothing.
            settings: those of the preparation, for a method that prepares again.
        """
        lights = list(lights)
        with state.lock:
            if same_lights(state.world.lights, lights):
                return
            world = replace(state.world, lights=lights)
            transforms = state.last_transforms or {}
            current = state.last if state.last is not None else state.data
            posed = world.posed(transforms)
            data = self.relit(current, posed, state.options)
            if data is None:
                data = self.prepare_world(posed, state.options, settings or RenderSettings())
            state.world = world
            state.data = data  # posed for an incremental method: its move goes anywhere
            if state.last is not None:
                state.last = data

    def relit(self, data: Any, world: World, options: Options) -> Any | None:
        """``data`` (prepared for a world with other lights, shapes posed as in ``world``)
        with its light-dependent parts recomputed for ``world``'s lights — bitwise the data
        ``prepare_world(world)`` makes — or None (the default) where the method prepares
        again: the hook of :meth:`relight`. May update ``data``'s Mitsuba views in place
        (:func:`relight_views`)."""
        return None

    def aux_view(self, data: Any) -> Any:
        """The Mitsuba scene (a :class:`~arlight.backend.mitsuba_scene.SceneView` of the
        mixed world) the denoiser's albedo and normal buffers are traced in, or None (the
        denoiser then sees the colour only). Default None."""
        return None

    def denoise(self, layers: Layers, data: Any, view: FrameView,
                denoise: DenoiseSettings, timer: StageTimer,
                transforms: dict[str, np.ndarray] | None = None,
                world: World | None = None) -> Layers:
        """The frame's layers denoised (``denoise = oidn``, methods with Monte Carlo noise;
        :func:`arlight.denoise.differential.denoise_layers`): stages ``denoise_aux`` (the
        auxiliary buffers of the denoised window; reused from an earlier frame of the same
        scene view, ``world`` (the state's; a relight replaces it), camera and
        ``transforms`` through
        :data:`arlight.denoise.aux.AUX_CACHE`, stat ``denoise_aux_cached``) and ``denoise``;
        the raw layers stay in the result's ``noisy``."""
        from arlight.denoise.differential import denoise_layers

        scene_view = self.aux_view(data) if denoise.aux else None
        aux, aux_seconds, cached = None, [0.0], [0.0]
        if scene_view is not None:
            from arlight.denoise.aux import AUX_CACHE

            def aux(rows, cols):
                t0 = time.perf_counter()
                buffers, hit = AUX_CACHE.get(scene_view, view.camera, denoise.aux_spp,
                                             transforms, rows, cols, world)
                aux_seconds[0] += time.perf_counter() - t0
                cached[0] = float(hit)
                return buffers
        with timer.stage("denoise"):  # stages do not nest: the buffers' time is moved out
            out = denoise_layers(layers, denoise, aux)
        if aux_seconds[0]:
            timer.seconds["denoise"] -= aux_seconds[0]
            timer.add("denoise_aux", aux_seconds[0])
            out.stats["denoise_aux_cached"] = cached[0]
        return out

    # --------------------------------------------------------------- protocol
    def options(self, settings: RenderSettings | None) -> Options:
        """``settings.options`` validated against ``spec.options``, defaults filled in."""
        return self.spec.parse_options(settings.options if settings else None)

    def check_supported(self, world: World | ARScene, view: FrameView | ARScene | None = None,
                        source: Path | str | None = None) -> None:
        """Raise :class:`InputError` when the capabilities exclude ``world`` / ``view``."""
        if view is not None and self.spec.capabilities.needs_frame:
            require_frame(view, source if source is not None else world.source)
        reason = self.spec.unsupported_reason(world, view)
        if reason:
            raise InputError(reason, file=str(world.source) if world.source else None,
                             field="method")

    def prepare(self, world: World, settings: RenderSettings | None = None) -> Prepared:
        """Validate the options and the world, then run ``prepare_world`` (timed)."""
        settings = settings or RenderSettings()
        opts = self.options(settings)
        self.check_supported(world)
        timer = StageTimer()
        with timer.stage("prepare"):
            data = self.prepare_world(world, opts, settings)
        return Prepared(self.spec.name, world, opts, data, timer.seconds["prepare"])

    def render(self, state: Prepared, view: FrameView,
               settings: RenderSettings | None = None) -> Layers:
        """Render ``view`` of the prepared world (posed by ``view.object_transforms``)."""
        t0 = time.perf_counter()
        settings = settings or RenderSettings()
        if not isinstance(state, Prepared) or state.method != self.spec.name:
            raise TypeError(f"{self.spec.name}.render needs the state of "
                            f"{self.spec.name}.prepare, got {type(state).__name__}")
        opts = self.options(settings)
        if (self.spec.preparation_options(opts)
                != self.spec.preparation_options(state.options)):
            raise InputError(f"{self.spec.name} was prepared with options "
                             f"{dict(state.options)} but renders with {dict(opts)}; "
                             "prepare again", field="options")
        self.check_supported(state.world, view)
        timer = StageTimer()
        if self.incremental_pose:
            with state.lock:
                layers = self._render_posed(state, view, opts, settings, timer)
        else:
            layers = self._render_posed(state, view, opts, settings, timer)
        layers.stats.update(timer.stats())
        layers.stats["seconds"] = time.perf_counter() - t0
        layers.method = self.spec.name
        return layers

    def _render_posed(self, state: Prepared, view: FrameView, opts: Options,
                      settings: RenderSettings, timer: StageTimer) -> Layers:
        """Pose the state for ``view`` (stage ``pose``, recorded when the frame moves an
        object or returns the state to its rest pose), render and denoise it."""
        data, transforms = state.data, view.object_transforms
        if view.object_transforms or self.incremental_pose:
            moves = bool(view.object_transforms or state.last_transforms)
            t0 = time.perf_counter()
            data = self.pose(state, view.object_transforms, settings)
            if moves:  # a still frame of a still state poses nothing: no stage
                timer.add("pose", time.perf_counter() - t0)
            view = replace(view, object_transforms={})
        layers = self.render_view(data, view, opts, settings, timer)
        denoise = DenoiseSettings.from_options(opts)
        if denoise is not None:
            layers = self.denoise(layers, data, view, denoise, timer, transforms,
                                  state.world)
        if delta_form(opts, denoise is not None) == "ratio":
            layers = self.ratio(layers, data, view, opts, timer, transforms, state.world)
        return layers

    def ratio(self, layers: Layers, data: Any, view: FrameView, opts: Options,
              timer: StageTimer, transforms: dict[str, np.ndarray] | None = None,
              world: World | None = None) -> Layers:
        """The photo-consistent change (option ``delta = ratio``,
        :func:`arlight.layers.ratio_change`) on the (denoised) layers: ``s`` from the
        photograph and ``I_r`` in the bounding box of the non-zero delta, ``ρ`` the mixed
        view's first-hit albedo there (the denoiser's auxiliary buffers, through
        :data:`arlight.denoise.aux.AUX_CACHE`: a crop of the denoised window's); stage
        ``ratio``. Without a delta the layers are returned as they are."""
        from arlight.denoise.aux import AUX_CACHE
        from arlight.denoise.differential import window
        from arlight.layers import ratio_change

        changed = np.any(layers.delta != 0, axis=-1)
        scene_view = self.aux_view(data)
        if not changed.any() or scene_view is None:
            return layers
        with timer.stage("ratio"):
            rows, cols = window(changed, 0)
            buffers, _ = AUX_CACHE.get(scene_view, view.camera, opts["denoise_aux_spp"],
                                       transforms, rows, cols, world)
            return ratio_change(layers, buffers.albedo, rows, cols)

    def __call__(self, scene: ARScene, settings: RenderSettings | None = None) -> Layers:
        """One-shot: ``render(prepare(scene.world), scene.view)``; the stats add
        ``time_prepare``, and ``seconds`` covers both."""
        t0 = time.perf_counter()
        settings = settings or RenderSettings()
        self.options(settings)
        self.check_supported(scene, scene)  # before any work
        state = self.prepare(scene.world, settings)
        layers = self.render(state, scene.view, settings)
        layers.stats = {"time_prepare": state.seconds, **layers.stats,
                        "seconds": time.perf_counter() - t0}
        return layers

    def __repr__(self) -> str:
        return f"<method {self.spec.name!r} ({type(self).__name__})>"


def place_views(views: SceneViews, world: World, transforms: dict[str, np.ndarray], *,
                real_moves: bool = False) -> World | None:
    """Move ``views`` (prepared for ``world``) in place to ``world.posed(transforms)`` and
    return that posed world — or None, leaving the views as they were, when the move cannot
    be done in place: ``transforms`` moves a real shape and ``real_moves`` is False (the
    caller keeps real-only solutions that would then be stale), or the views hold another
    world. The caller then prepares the posed world from scratch."""
    posed = world.posed(transforms)
    try:
        moved = views.moved(posed.shapes)
    except ValueError:
        return None
    if not real_moves and any(not posed.shapes[i].is_virtual for i in moved):
        return None
    views.place(posed.shapes)
    return posed


def _same_value(a: Any, b: Any) -> bool:
    """Recursive equality of light parameters (dicts, sequences, arrays, scalars)."""
    if isinstance(a, dict) or isinstance(b, dict):
        return (isinstance(a, dict) and isinstance(b, dict) and a.keys() == b.keys()
                and all(_same_value(a[k], b[k]) for k in a))
    if isinstance(a, str) or isinstance(b, str) or a is None or b is None:
        return a == b
    return np.array_equal(np.asarray(a), np.asarray(b))


def same_lights(a: Sequence[Light], b: Sequence[Light]) -> bool:
    """Whether two light lists are equal (type, name, parameters, radiance map)."""
    return len(a) == len(b) and all(
        x.type == y.type and x.name == y.name and _same_value(x.params, y.params)
        and _same_value(x.radiance_map, y.radiance_map) for x, y in zip(a, b, strict=True))


DISTANT_LIGHTS = frozenset({"envmap", "sh", "constant"})
"""Light types at infinity: what the methods' environment tables (mip maps, distant SH) are
made of."""


def distant_changed(before: Sequence[Light], after: Sequence[Light]) -> bool:
    """Whether the distant lights (:data:`DISTANT_LIGHTS`) differ between two light lists
    (another count, type or parameters): a method keeping environment tables in
    :meth:`BaseMethod.relit` then prepares again."""
    a = [x for x in before if x.type in DISTANT_LIGHTS]
    b = [x for x in after if x.type in DISTANT_LIGHTS]
    return not same_lights(a, b)


def relight_views(views: SceneViews, before: Sequence[Light], after: Sequence[Light]
                  ) -> bool:
    """Give the emitters of ``views`` (loaded with the lights ``before``) the lights
    ``after`` in place, through the scenes' parameters (issue #32): each changed light is
    loaded alone (:func:`~arlight.backend.mitsuba_scene.load_view`, as a full build loads
    it) and its parameters (position, ``to_world``, intensity, radiance, environment data,
    area-light geometry) copied into both views, whose acceleration structures then follow
    an area lamp; what a tracer cached on the views (``_light_samplers``, ``_environment``)
    is dropped. The views then trace
    and sample bitwise what views built with ``after`` do. False, views untouched, when the
    lights differ in number or type (the views must be built again)."""
    import mitsuba as mi

    from arlight.backend.mitsuba_scene import LIGHT_PREFIX, describe_light, load_view

    if len(before) != len(after) or any(
            a.type != b.type for a, b in zip(before, after, strict=True)):
        return False
    changed = {f"{LIGHT_PREFIX}{i}": describe_light(b) for i, (a, b) in
               enumerate(zip(before, after, strict=True)) if not same_lights([a], [b])}
    if not changed:
        return True
    fresh = mi.traverse(load_view({"objects": changed}, {}).scene)
    keys = [k for k in fresh.keys() if k.split(".", 1)[0] in changed]
    targets = list({id(v.base): v.base for v in (views.real, views.mixed)}.values())
    # (a split mixed view shares the real view's scene: SceneView.base)
    if any(k not in view.params for view in targets for k in keys):
        return False
    for view in targets:
        view.update({k: fresh[k] for k in keys})  # a new generation (SceneView.update)
        for key in [k for k in view.__dict__ if k.startswith("_") and k != "_params"]:
            del view.__dict__[key]  # caches made from the emitters (light samplers, env)
    return True


def _same_transforms(a: dict[str, np.ndarray] | None, b: dict[str, np.ndarray]) -> bool:
    return a is not None and a.keys() == b.keys() and all(
        np.array_equal(a[k], b[k]) for k in a)


def posed_data(state: Prepared, transforms: dict[str, np.ndarray],
               move: Callable[[Any], Any | None], prepare: Callable[[], Any]) -> Any:
    """An incremental pose for ``transforms``: ``move(previous)`` updates the data of the
    last pose (the prepared data before the first) in place and returns the posed data, or
    None when it cannot (a real shape moved); then ``prepare()`` prepares the posed world
    from scratch. The result is remembered as ``state.last`` for the next frame; the same
    transforms again return it as it is (a still frame poses nothing)."""
    if state.last is not None and _same_transforms(state.last_transforms, transforms):
        return state.last
    out = move(state.last if state.last is not None else state.data)
    if out is None:
        return prepare()
    state.last = out
    state.last_transforms = {k: np.array(v, np.float64) for k, v in transforms.items()}
    return out


RenderFn = Callable[[ARScene, RenderSettings], Layers]


class FunctionMethod(BaseMethod):
    """A plain ``fn(scene, settings) -> Layers`` as a :class:`Method` (what
    ``@register("name")`` on a function makes): nothing to prepare, the whole call is the
    stage ``render``; ``settings.options`` reach ``fn`` validated, with defaults (the
    denoiser's options excepted: the base class applies them after ``fn``)."""

    def __init__(self, fn: RenderFn, spec: MethodSpec) -> None:
        self.fn = fn
        self.spec = spec  # type: ignore[misc]  # per instance here, not per class
        self.__doc__ = fn.__doc__

    def prepare_world(self, world: World, options: Options, settings: RenderSettings) -> World:
        return world

    def render_view(self, data: World, view: FrameView, options: Options,
                    settings: RenderSettings, timer: StageTimer) -> Layers:
        mine = {k: v for k, v in options.items() if k not in DENOISE_NAMES}  # base denoises
        with timer.stage("render"):
            return self.fn(ARScene.compose(data, view), replace(settings, options=mine))
