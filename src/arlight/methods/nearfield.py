"""``nearfield``: Rohmer et al. 2015 — near-field light from HDR fisheye cameras as virtual
area lights (VALs) plus 9 SH coefficients per virtual object, rendered with per-vertex PRT,
two visibilities per VAL and the differential composite of Eq. 14.

* **prepare** (once per world): the G-buffer views (the real view plus each virtual object
  in object space, :func:`arlight.backend.object_space.build_split_views`: a pose moves no
  Mitsuba scene), the proxy scene and the virtual-object occluder, the per-vertex PRT
  transfer of every virtual mesh (``prt``'s,
  :func:`arlight.realtime.prt_shading.prt_meshes`, cached on disk), the material table and
  the light state: read from ``light`` (a ``NearFieldLight`` JSON, ``arlight light atlas -o
  vals.json``) or, without it, made by the server pipeline
  (:class:`~arlight.nearfield.pipeline.NearFieldServer`) from a synthetic capture of the
  world's real part by the rig in ``cameras`` (default: an automatic rig of six fisheyes,
  :func:`~arlight.nearfield.cameras.auto_rig`).
* **render** (per frame, :mod:`arlight.nearfield.shading`): G-buffer; PRT indirect light on
  virtual samples (Eq. 8, :func:`arlight.realtime.prt_shading.shade_virtual`); shadow maps
  (two per VAL); direct light of the VALs with both visibilities; Eq. 14. Stages
  ``gbuffer``, ``indirect``, ``shadow_maps``, ``cull`` (8×8 tiles), ``direct``, ``assemble``.

A client with its own light state (e.g. from the light server) renders with
:func:`render_with_light` (or :class:`~arlight.nearfield.NearFieldClient`). See
``docs/methods/nearfield.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from types import SimpleNamespace

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.mitsuba_scene import SceneViews
from arlight.backend.object_space import ObjectSpaceScene
from arlight.methods.base import (
    BaseMethod,
    Layers,
    Prepared,
    RenderSettings,
    place_views,
    relight_views,
)
from arlight.methods.fragments import GBUFFER_OPTIONS
from arlight.methods.spec import Capabilities, Field, MethodSpec, Options
from arlight.nearfield.shading import (
    MaterialTable,
    PerObjectSH,
    ShadowMaps,
    direct_light,
    material_table,
    shadow_maps,
    tile_lanes,
)
from arlight.nearfield.split import DEFAULT_TAU
from arlight.nearfield.state import MAX_VALS, NearFieldLight
from arlight.realtime.gbuffer import assemble, render_gbuffer
from arlight.scene.model import FrameView, World
from arlight.timing import StageTimer

OPTIONS: dict[str, Field] = {
    "light": Field("str", None, "NearFieldLight JSON (`arlight light atlas`); empty: run the "
                   "server on a synthetic capture of the world"),
    "cameras": Field("str", None, "fisheye rig (cams.toml) of the synthetic capture; empty: "
                     "six fisheyes inside the proxy's bounds"),
    "capture_size": Field("int", 128, "side of the synthetic fisheye images", "px", min=16,
                          max=2048),
    "capture_spp": Field("int", 32, "paths per pixel of the synthetic capture", "", min=1,
                         max=4096),
    "tau": Field("float", DEFAULT_TAU, "direct share τ of the total radiant intensity (0.6: "
                 "best of 0.5–0.98 on cornell-near-field; see docs/methods/nearfield.md)", "",
                 min=0.0, max=1.0),
    "vals": Field("int", 16, "number of virtual area lights M", "", min=1, max=MAX_VALS),
    "atlas_resolution": Field("int", 256, "radiance atlas side", "texels", min=16,
                              max=2048),
    "shadows": Field("choice", "maps", "visibility: `maps` (two 128² maps per VAL, Rohmer) "
                     "or `rays` (exact shadow rays)", choices=("maps", "rays")),
    "shadow_map_size": Field("int", 128, "shadow map side", "texels", min=8, max=2048),
    "shadow_bias": Field("float", 2.0, "depth bias of the shadow maps", "texels", min=0.0,
                         max=64.0),
    "disc": Field("bool", True, "VALs as discs (r² + R² in Eq. 5); false: points"),
    "direct": Field("bool", True, "direct light of the VALs"),
    "indirect": Field("bool", True, "PRT indirect light of the SH blocks"),
    "metal_k": Field("rgb", [0.0, 0.0, 0.0], "extinction k of roughconductor materials "
                     "(their n follows from their reflectance)", "", min=0.0),
    "directions": Field("int", 512, "visibility rays per vertex of the PRT transfer", "",
                        min=16, max=16384),
    **GBUFFER_OPTIONS,
}

SPEC = MethodSpec(
    name="nearfield",
    description="Rohmer 2015: near-field light from HDR fisheyes as virtual area lights + "
                "per-object SH; PRT, two shadow maps per VAL, Eq. 14; real time.",
    options=OPTIONS,
    capabilities=Capabilities(interactive=True,
                              materials=frozenset({"diffuse", "phong", "roughconductor"}),
                              # per-vertex transfer: analytic spheres and disks have no
                              # vertices (realtime.prt_shading.object_mesh)
                              virtual_shapes=frozenset({"mesh", "box", "rectangle"})),
)


@dataclass
class NearFieldData:
    """What ``prepare_world`` keeps; ``light`` may be replaced per frame
    (``dataclasses.replace``), everything else is static."""

    world: World
    views: SceneViews
    proxy: mi.Scene
    occluder: ObjectSpaceScene | None
    """The virtual objects alone, each traced in object space through its pose
    (:mod:`arlight.backend.object_space`; the same loaded objects as the mixed view's): a
    pose moves no Mitsuba scene, for any number of objects and any affine pose."""
    prt: PerObjectSH | None
    materials: MaterialTable
    sphere: tuple[np.ndarray, float] | None
    light: NearFieldLight
    objects: list[str]
    server_stats: dict
    server: object = None
    """The NearFieldServer that made ``light`` in ``prepare`` (None for a given light): a
    posed world gets its SH probes re-traced at the moved objects (``pose``)."""
    map_cache: dict = field(default_factory=dict)
    """Shadow maps of the last light state (key: VAL geometry, map size): a client frame
    whose light did not change since the last frame reuses them (results are identical)."""


def _light_from_options(world: World, options: Options
                        ) -> tuple[NearFieldLight, dict, object]:
    from arlight.nearfield.cameras import default_rig, load_rig, seeing_cameras
    from arlight.nearfield.capture import capture_rig
    from arlight.nearfield.lightfile import load_light
    from arlight.nearfield.pipeline import NearFieldServer, NearFieldSettings

    if options.light:
        return load_light(options.light), {}, None
    rig = (load_rig(options.cameras) if options.cameras
           else default_rig(world, options.capture_size))
    server = NearFieldServer(world, rig, NearFieldSettings(
        atlas_resolution=options.atlas_resolution, tau=options.tau, vals=options.vals))
    if not options.cameras:  # the automatic rig: drop cameras that see nothing (open sides)
        server.cameras = seeing_cameras(rig, server.geometry, server.proxy_scene)
    images = capture_rig(world, server.cameras, options.capture_spp)
    light = server.update(images, timestamp=0.0)
    return light, dict(server.stats), server


def _occluder(views: SceneViews) -> ObjectSpaceScene | None:
    """The virtual objects of split views (:func:`~arlight.backend.object_space.
    build_split_views`) alone, as the shadow rays and maps test them (None without any)."""
    if not isinstance(views.mixed.scene, ObjectSpaceScene):
        return None
    return ObjectSpaceScene(None, views.mixed.scene.objects)


def prepare(world: World, options: Options, light: NearFieldLight | None = None,
            server=None) -> NearFieldData:
    """Everything but the frame (module docstring); ``light`` overrides the options
    (``server``: the server that made it, kept for ``pose``)."""
    from arlight.backend.object_space import build_split_views
    from arlight.cache import default_cache_dir
    from arlight.nearfield.atlas import proxy_mesh
    from arlight.nearfield.raytrace import mesh_scene
    from arlight.realtime.prt_shading import prt_meshes
    from arlight.realtime.prt_transfer import rotation_part

    views = build_split_views(world)  # the virtual objects in object space (issue #32)
    mesh = proxy_mesh(world)
    proxy = mesh_scene([(mesh.vertices, mesh.faces)])
    occluder = _occluder(views)
    stats: dict = {}
    if light is None:
        light, stats, server = _light_from_options(world, options)
    names = [s.name for s in world.virtual_shapes]
    pdata = None
    sphere = None
    if occluder is not None:
        # the objects are loaded at the identity pose: their object meshes are read there,
        # then each takes the rotation of its pose
        rest = replace(world, shapes=[replace(s, to_world=np.eye(4)) if s.is_virtual else s
                                      for s in world.shapes])
        d = prt_meshes(rest, views, default_cache_dir(), order=2,
                       directions=options.directions, bounces=0, shadowed=True)
        objects = [replace(o, rotation=rotation_part(world.shapes[o.shape].to_world))
                   for o in d.objects]
        pdata = PerObjectSH(views=views, objects=objects, face_offset=d.face_offset,
                            faces=d.faces, sog=None, env=None, sh=np.zeros((len(names), 9, 3)))
        sphere = occluder.bounding_sphere()
    return NearFieldData(world, views, proxy, occluder, pdata,
                         material_table(world, list(options.metal_k)), sphere, light, names,
                         stats, server)


def _server_light(server, world: World, light: NearFieldLight) -> NearFieldLight:
    """``light`` with its SH probes re-traced at ``world``'s virtual objects where
    ``server`` (a NearFieldServer, or None) made it; otherwise ``light`` itself."""
    from arlight.nearfield.indirect import IndirectProbes
    from arlight.nearfield.pipeline import virtual_objects

    if server is None or server.last is None:
        return light
    probes = IndirectProbes(server.mesh.vertices, server.mesh.faces, server.layout,
                            virtual_objects(world), server.settings.cube_resolution,
                            server.proxy_scene)
    v = server.last.vals
    sh = probes.coefficients(server.last.indirect_atlas, np.zeros_like(light.sh),
                             (v.positions, v.normals, v.intensity, v.area))
    return replace(light, sh=sh)


def _check_light(data: NearFieldData) -> None:
    from arlight.errors import InputError

    n = len(data.objects)
    if data.light.n_objects not in (0, n):
        raise InputError(f"the light state has {data.light.n_objects} SH blocks for {n} "
                         "virtual objects", field="light.sh")


def render_with_light(data: NearFieldData, view: FrameView, options: Options,
                      settings: RenderSettings, timer: StageTimer) -> Layers:
    """One frame with ``data.light`` (module docstring)."""
    frame = view.frame
    if data.occluder is None:  # no virtual object: the composite is the frame itself
        with timer.stage("assemble"):
            bg = np.asarray(frame, np.float32)
            z = np.zeros_like(bg)
            return Layers.assemble(bg, bg, z, z[..., 0], stats={"vals": float(
                data.light.count)})
    _check_light(data)
    light = data.light
    with timer.stage("gbuffer"):
        gb = render_gbuffer(data.views.mixed, view.camera, options.gbuffer_spp, settings.seed)
    width = dr.width(gb.position)
    mixed = dr.zeros(mi.Color3f, width)
    with timer.stage("indirect"):
        if options.indirect and data.prt is not None and light.n_objects:
            from arlight.realtime.prt_shading import shade_virtual

            pd = PerObjectSH(**{**vars(data.prt), "sh": light.sh})
            rad, lanes = shade_virtual(pd, gb, view, SimpleNamespace(order=2, glossy=False),
                                       settings.seed)
            if dr.width(lanes):
                dr.scatter(mixed, rad, lanes)
            dr.eval(mixed)
    delta = dr.zeros(mi.Color3f, width)
    maps: ShadowMaps | None = None
    if options.direct and light.count:
        with timer.stage("shadow_maps"):
            if options.shadows == "maps" and data.sphere is not None:
                key = (light.positions.tobytes(), light.normals.tobytes(),
                       options.shadow_map_size)
                maps = data.map_cache.get(key)
                if maps is None:
                    maps = shadow_maps(light, data.proxy, data.occluder, data.sphere,
                                       options.shadow_map_size)
                    data.map_cache.clear()
                    data.map_cache[key] = maps
        with timer.stage("cull"):
            lanes = None
            if data.sphere is not None:
                lanes = tile_lanes(light, np.array(gb.position).T,
                                   np.array(gb.valid, bool), np.array(gb.virtual, bool),
                                   gb.width, gb.height, gb.spp, data.sphere)
        with timer.stage("direct"):
            lit, lost = direct_light(light, gb.position, gb.normal, gb.albedo, gb.to_camera,
                                     gb.virtual, gb.valid, gb.shape, data.materials,
                                     data.proxy, data.occluder, maps, options.disc,
                                     options.shadow_bias, lanes)
            mixed = dr.select(gb.virtual, mixed + lit, mixed)
            delta = dr.select(gb.virtual | ~gb.valid, delta, -lost)
            dr.eval(mixed, delta)
    with timer.stage("assemble"):
        stats = {"vals": float(light.count), "sh_objects": float(light.n_objects),
                 "shadow_maps": float(0 if maps is None else 2 * int(np.sum(
                     maps.tan_half > 0)))}
        return assemble(gb, frame, mixed, delta, stats)


class NearFieldMethod(BaseMethod):
    """Rohmer et al. 2015 near-field AR illumination (module docstring)."""

    spec = SPEC

    def prepare_world(self, world: World, options: Options, settings: RenderSettings
                      ) -> NearFieldData:
        return prepare(world, options)

    incremental_pose = True

    def prepare_posed(self, state: Prepared, transforms: dict[str, np.ndarray],
                      settings: RenderSettings) -> NearFieldData:
        """The posed world prepared again (where :meth:`move` cannot: a real shape moved)
        with the state's light and server — not a capture of its own: the light
        of the last pose (``with_light`` sets it), its SH re-traced where the server made
        it."""
        data = state.last if state.last is not None else state.data
        world = state.world.posed(transforms)
        return prepare(world, state.options, _server_light(data.server, world, data.light),
                       data.server)

    def move(self, data: NearFieldData, world: World, transforms: dict[str, np.ndarray],
             options: Options) -> NearFieldData | None:
        """``data`` (prepared for ``world`` in any pose) moved in place to
        ``world.posed(transforms)`` (issue #32): the mixed view's objects and the virtual
        occluder, both traced in object space (:mod:`arlight.backend.object_space`), take
        the new frames — no Mitsuba scene is updated, no acceleration structure rebuilt;
        each object keeps its object-space PRT transfer and takes its new rotation, the
        bounding sphere is measured again and the shadow maps dropped (they see the
        occluder); the proxy, the material table and the VALs are kept. Where this state's
        own server made the light, the SH probes are re-traced at the moved objects (as a
        server does when it is told the new poses); a given light is kept as it is. Bitwise
        the data :func:`prepare` makes of the posed world with that light; None when a real
        shape moves (the proxy and the light would change)."""
        from arlight.realtime.prt_transfer import rotation_part

        posed = place_views(data.views, world, transforms)
        if posed is None:
            return None
        occluder = _occluder(data.views)
        sphere = None if occluder is None else occluder.bounding_sphere()
        prt = data.prt
        if prt is not None:
            prt = PerObjectSH(**{**vars(prt), "objects": [
                replace(o, rotation=rotation_part(posed.shapes[o.shape].to_world))
                for o in prt.objects]})
        return replace(data, world=posed, occluder=occluder, prt=prt, sphere=sphere,
                       light=_server_light(data.server, posed, data.light), map_cache={})

    def relit(self, data: NearFieldData, world: World, options: Options
              ) -> NearFieldData | None:
        """Light update (issue #32): the VALs and SH blocks come from the light state, not
        from the world's lights, so a given light is kept and only the views' emitters
        follow; a light this state's own server made from a synthetic capture of the world
        is made again (None: prepare again). A new light *state* goes through
        :func:`with_light` instead."""
        if data.server is not None:
            return None
        ok = relight_views(data.views, data.world.lights, world.lights)
        return replace(data, world=world) if ok else None

    def render_view(self, data: NearFieldData, view: FrameView, options: Options,
                    settings: RenderSettings, timer: StageTimer) -> Layers:
        layers = render_with_light(data, view, options, settings, timer)
        for k, v in data.server_stats.items():
            layers.stats[f"server_ms_{k}"] = float(v)
        return layers


def with_light(state: Prepared, light: NearFieldLight) -> Prepared:
    """A prepared state that renders with ``light`` (the original is not modified; both
    share the Mitsuba scenes, which follow the pose of the last frame rendered from
    either): the rest data and the last posed data both take ``light``."""
    last = None if state.last is None else replace(state.last, light=light)
    return replace(state, data=replace(state.data, light=light), last=last)


__all__ = ["OPTIONS", "SPEC", "NearFieldData", "NearFieldMethod", "prepare",
           "render_with_light", "with_light"]


def empty_light(n_objects: int = 0) -> NearFieldLight:
    """No VAL and zero SH for ``n_objects`` objects (a client before its first update)."""
    z = np.zeros((0, 3))
    return NearFieldLight(z, z, z, np.zeros(0), np.zeros((n_objects, 9, 3)))


class NearFieldClient:
    """Render frames of one world with light states from elsewhere (the light server).

        client = NearFieldClient(world, {"shadows": "maps"})
        layers = client.render(view, light)      # any NearFieldLight, per frame

    ``world`` is the proxy world with the virtual objects (SH blocks in the order of
    ``world.virtual_shapes``); ``options`` those of the ``nearfield`` method (``light``,
    ``cameras`` and the capture options are not used).
    """

    def __init__(self, world: World, options: dict | None = None,
                 settings: RenderSettings | None = None) -> None:
        import time

        self.method = NearFieldMethod()
        self.settings = replace(settings or RenderSettings(), options=dict(options or {}))
        opts = self.method.options(self.settings)
        self.method.check_supported(world)
        t0 = time.perf_counter()
        data = prepare(world, opts, empty_light(len(world.virtual_shapes)))
        self.state = Prepared(SPEC.name, world, opts, data, time.perf_counter() - t0)

    def render(self, view: FrameView, light: NearFieldLight) -> Layers:
        """Layers of ``view`` lit by ``light`` (Eq. 14)."""
        return self.method.render(with_light(self.state, light), view, self.settings)


__all__ += ["NearFieldClient", "empty_light"]
