"""Pieces several method plug-ins share, so that no plug-in imports another.

Part of the method contract tier (with :mod:`~arlight.methods.spec` and
:mod:`~arlight.methods.base`):

* :data:`GBUFFER_OPTIONS` — the G-buffer option (``gbuffer_spp``) of the rasterisation-class
  methods (``dlpv``, ``dir``, ``dvct``, ``ibl``, ``prt``, ``nearfield``).
* :data:`REDUCTION_OPTIONS` — the light-reduction options
  (:mod:`arlight.realtime.light_reduction`).
* :data:`SAMPLER_OPTIONS` — how the path tracers' camera paths draw their numbers
  (``onepass``, ``dic``: the same Sobol sets, so dic's direct light is onepass's).
* :class:`PathScenesMethod` — base of the methods whose prepared state is
  :class:`~arlight.tracing.scenes.PathScenes` (``reference``, ``onepass``, ``dic``).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from arlight.methods.base import BaseMethod, RenderSettings, place_views, relight_views
from arlight.methods.spec import Field, Options
from arlight.realtime.light_reduction import OPTIONS as REDUCTION_OPTIONS
from arlight.realtime.oof import move_occluder
from arlight.realtime.sh_volume import Grid
from arlight.realtime.shading import virtual_bounds
from arlight.scene.model import World
from arlight.tracing.scenes import PathScenes, prepare_scenes

SAMPLER_OPTIONS: dict[str, Field] = {
    "sampler": Field("choice", "sobol", "`sobol`: shuffled Owen-scrambled Sobol points "
                     "(Burley 2020) for the pixel, lens, light, BSDF and roulette dimensions, "
                     "4D sets pairing each BSDF direction with the next light sample; "
                     "`sobol2d`: 2D sets only; `independent`: hashed uniform numbers "
                     "(docs/methods/onepass.md#sampling)",
                     choices=("sobol", "sobol2d", "independent")),
    "replicas": Field("int", 16, "independent randomisations whose spread gives the standard "
                      "errors (the largest divisor of spp not above it; 1: per-sample "
                      "variance, which overstates the error of Sobol samples)", min=1,
                      max=4096),
    "replica_mode": Field("choice", "blocks", "`blocks`: the replicas are blocks of one "
                          "scrambled sequence per pixel (the lowest error: at 16 spp the "
                          "pixel is one 16-point net, not 16 one-point ones; standard errors "
                          "conservative, mean z² ≈ 0.8); `scrambles`: each replica its own "
                          "Sobol scrambling (unbiased errors)", choices=("blocks", "scrambles")),
}
"""The sample-drawing options of ``onepass`` and ``dic``'s camera walk (issue #33: with
``independent`` numbers dic's direct light had 3–4× onepass's variance at equal spp)."""

GBUFFER_OPTIONS: dict[str, Field] = {
    "gbuffer_spp": Field("int", 1, "G-buffer samples per pixel (stratified AA)", "", min=1,
                         max=64),
}
"""``gbuffer_spp``: primary samples per pixel of :func:`arlight.realtime.gbuffer.
render_gbuffer` (1: the rasteriser's G-buffer)."""

GBUFFER_FRAME_OPTIONS = frozenset(GBUFFER_OPTIONS)
"""The G-buffer option as a :attr:`~arlight.methods.spec.MethodSpec.frame_options` entry of
methods whose preparation does not read it (``dir``, ``dlpv``, ``dvct``): one prepared state
renders any ``gbuffer_spp`` (the studio's one-sample preview at rest uses it)."""


AA_GBUFFER_SPP = 4
"""``dir``'s and ``dlpv``'s default ``gbuffer_spp`` (issue #33): the ground truth is
antialiased, a 1-sample G-buffer aliases the objects' and the shadows' edges; on 12 training
worlds 2 / 4 / 9 / 16 samples gave dir +1.04 / +2.29 / +2.59 / +2.68 dB median changed PSNR
over 1 (dlpv +1.02 / +2.13 / +2.41 / +2.49), and at 4 both still beat onepass at their own
frame time on 8 training worlds (dir 8/8, dlpv 7/8). Their reduced-size frames take one
(:func:`drag_gbuffer_spp`)."""


def gbuffer_options(spp: int) -> dict[str, Field]:
    """:data:`GBUFFER_OPTIONS` with ``spp`` G-buffer samples per pixel by default."""
    return {k: replace(f, default=spp) for k, f in GBUFFER_OPTIONS.items()}


def drag_gbuffer_spp(options: Options, factor: int) -> dict[str, int]:
    """``gbuffer_spp`` of a frame rendered at 1/``factor`` of its size and upsampled (studio
    drag frames, ``arlight live --render-scale``): one sample when ``factor`` > 1 — the
    upsampling filters wider than the AA samples would, and on the demo at 320×240 the 4
    samples cost half the frame (dlpv 58 → 28 ms, dir 85 → 47 ms; ``arlight live`` at render
    scale 1/2 fell from 12.4 / 11.3 to 9.5 / 8.3 frames/s)."""
    return {"gbuffer_spp": options.gbuffer_spp if factor <= 1 else 1}


class PathScenesMethod(BaseMethod):
    """Base of the methods whose prepared state is :class:`PathScenes` (the path tracers and
    the irradiance cache built on them)."""

    def prepare_world(self, world: World, options: Options,
                      settings: RenderSettings) -> PathScenes:
        return prepare_scenes(world)

    def aux_view(self, data: PathScenes):
        """The mixed view: the denoiser's albedo and normal buffers are traced there."""
        return data.views.mixed

    def move_in_place(self, data: PathScenes, world: World,
                      transforms: dict[str, np.ndarray], options: Options) -> PathScenes | None:
        """The incremental pose of a path tracer (issue #32; a subclass with
        ``incremental_pose = True`` uses it as its ``move``): the shapes move in place in
        both Mitsuba views (:meth:`~arlight.backend.mitsuba_scene.SceneViews.place`, real
        shapes too), nothing else is prepared. Not ``move`` itself: ``dic`` keeps its own
        pose."""
        posed = place_views(data.views, world, transforms, real_moves=True)
        return None if posed is None else PathScenes(posed, data.views)

    def relit_in_place(self, data: PathScenes, world: World, options: Options
                       ) -> PathScenes | None:
        """The light update of a path tracer (issue #32; ``relit`` of ``onepass`` and
        ``reference``): the emitters change in place in both Mitsuba views
        (:func:`~arlight.methods.base.relight_views`), nothing else is prepared; None when
        the lights differ in number or type. Not ``relit`` itself: ``dic``'s cache depends
        on the light."""
        ok = relight_views(data.views, data.world.lights, world.lights)
        return PathScenes(world, data.views) if ok else None



def place_occluded(views, occluder, world: World, before: World,
                   transforms: dict[str, np.ndarray]):
    """``views`` and the AR-OOF ``occluder`` (:func:`~arlight.realtime.oof.move_occluder`)
    moved in place from ``before`` to ``world.posed(transforms)`` (ibl and prt): ``(posed
    world, occluder)``, or None when a real shape moved or the occluder cannot follow."""
    posed = place_views(views, world, transforms)
    if posed is None:
        return None
    ok, moved = move_occluder(occluder, before, posed)
    return (posed, moved) if ok else None


def volume_grid(bounds: tuple[np.ndarray, np.ndarray], options: Options) -> Grid:
    """The volume of dlpv and dvct around the virtual objects' bounds: Franke's cube
    (``volume_scale`` × the largest edge, world-axis aligned) on the fixed world lattice of
    :meth:`~arlight.realtime.sh_volume.Grid.on_lattice` (issue #32: it moves in steps of a
    quarter of its edge), or centred on the cell lattice as Franke
    (:meth:`~arlight.realtime.sh_volume.Grid.around`) with ``fixed_lattice`` off."""
    if getattr(options, "fixed_lattice", True):
        return Grid.on_lattice(*bounds, n=options.volume_size, scale=options.volume_scale)
    return Grid.around(*bounds, n=options.volume_size, scale=options.volume_scale)


def follow_volume(views, grid, world: World, transforms: dict[str, np.ndarray],
                  options: Options):
    """``views`` moved in place to ``world.posed(transforms)`` and the volume placed again
    around the virtual objects' new bounds (dlpv and dvct, :func:`volume_grid`): ``(posed
    world, new grid, bounds)`` — grid and bounds None when the data has no volume (``grid``
    None) — or None when a real shape moved."""
    posed = place_views(views, world, transforms)
    if posed is None:
        return None
    if grid is None:
        return posed, None, None
    bounds = virtual_bounds(posed, views.mixed)
    return posed, volume_grid(bounds, options), bounds


LATTICE_OPTIONS: dict[str, Field] = {
    "fixed_lattice": Field("bool", True, "place the volume on a fixed world lattice (moves in "
                           "steps of a quarter of its edge, so a moving object keeps the real "
                           "voxels and RSMs; issue #32); off: centred on the object as Franke"),
}
"""``fixed_lattice``: the placement of :func:`volume_grid` (dlpv and dvct)."""


__all__ = ["GBUFFER_OPTIONS", "LATTICE_OPTIONS", "PathScenesMethod", "REDUCTION_OPTIONS",
           "drag_gbuffer_spp", "follow_volume", "gbuffer_options", "AA_GBUFFER_SPP",
           "GBUFFER_FRAME_OPTIONS",
           "place_occluded", "volume_grid"]
