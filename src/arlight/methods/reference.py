"""``reference``: two-pass differential path tracing (Debevec 1998; Kán Eq. 2.20).

``I_m`` is path traced in the mixed scene (ρ: proxy + virtual objects) and ``I_r`` in the
real-only scene (µ: proxy), with identical camera samples and identical per-lane random
sequences, so the two solutions are strongly correlated and their difference (the delta) has
low variance. Radiance comes from Mitsuba's own ``path`` integrator (unidirectional path
tracing with next-event estimation and MIS, environment importance sampling, Russian
roulette) — the trusted reference every faster method is measured against. The mask ``M`` is
the fraction of a pixel's camera samples whose first hit is a virtual shape.

The per-sample composite ``m·L_m + (1 − m)(I_c + L_m − L_r)`` is also accumulated, to give a
per-pixel standard error for the composite. With no virtual object only µ is traced and the
composite is the frame, bit for bit.

Stages (``Layers.stats``, seconds): ``time_prepare`` (both Mitsuba scenes and their BVHs),
``time_setup`` (integrator, frame upload), ``time_trace`` (the sample passes, including the
per-pass per-pixel sums), ``time_assemble`` (moments to layers, standard errors, composite);
``time_pose`` when the view moves objects (the posed world's scenes are built again).
Options: none.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.mitsuba_scene import ROLE_VIRTUAL, SceneView, SceneViews, build_views
from arlight.backend.passes import run_passes
from arlight.methods.base import (
    BaseMethod,
    Layers,
    RenderSettings,
    differential_samples,
    layers_from_passes,
)
from arlight.methods.spec import Capabilities, MethodSpec, Options
from arlight.scene.model import FrameView, World
from arlight.timing import StageTimer


def path_integrator(settings: RenderSettings) -> mi.SamplingIntegrator:
    """Mitsuba's ``path`` integrator with the depth settings of ``settings``."""
    return mi.load_dict({"type": "path", "max_depth": settings.max_depth,
                         "rr_depth": settings.rr_depth})


def trace_radiance(integrator: mi.SamplingIntegrator, view: SceneView,
                   rays: mi.RayDifferential3f, seed: mi.UInt32, lanes: int) -> mi.Color3f:
    """Per-lane radiance along ``rays``; equal seeds give equal random sequences."""
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(seed, lanes)
    spec, _, _ = integrator.sample(view.scene, sampler, rays)
    return mi.Color3f(spec)


def virtual_coverage(view: SceneView, rays: mi.RayDifferential3f) -> mi.Float:
    """1 where the ray's first hit is a virtual shape, else 0."""
    si = view.scene.ray_intersect(mi.Ray3f(rays))
    return dr.select(view.hit_role(si) == ROLE_VIRTUAL, mi.Float(1.0), mi.Float(0.0))


def frame_gather(frame: np.ndarray):
    """A function pixel-index -> frame radiance (Color3f) for use inside kernels."""
    flat = np.ascontiguousarray(frame.reshape(-1, 3), dtype=np.float32)
    table = mi.Color3f(flat[:, 0], flat[:, 1], flat[:, 2])
    return lambda pixel: dr.gather(mi.Color3f, table, pixel)


@dataclass
class PathScenes:
    """Prepared state of the path tracers: the world and its two Mitsuba views."""

    world: World
    views: SceneViews


def prepare_scenes(world: World) -> PathScenes:
    """Build the real-only (µ) and mixed (ρ) Mitsuba scenes of ``world``."""
    return PathScenes(world, build_views(world))


class PathScenesMethod(BaseMethod):
    """Base of the methods whose prepared state is :class:`PathScenes` (the path tracers and
    the irradiance cache built on them)."""

    def prepare_world(self, world: World, options: Options,
                      settings: RenderSettings) -> PathScenes:
        return prepare_scenes(world)


class ReferenceMethod(PathScenesMethod):
    """Two-pass differential path tracing with Mitsuba's path tracer (ground-truth method)."""

    spec = MethodSpec(
        name="reference",
        description="Two-pass differential path tracing with Mitsuba's path tracer "
                    "(ground-truth method).",
        capabilities=Capabilities(progressive=True),
    )

    def render_view(self, data: PathScenes, view: FrameView, options: Options,
                    settings: RenderSettings, timer: StageTimer) -> Layers:
        frame, views, has_virtual = view.frame, data.views, data.world.has_virtual
        with timer.stage("setup"):
            integrator = path_integrator(settings)
            background = frame_gather(frame)

        def kernel(rays, pixel, seed, lanes):
            real = trace_radiance(integrator, views.real, rays, seed, lanes)
            if not has_virtual:  # µ = ρ: one path serves both, the delta is exactly 0
                return differential_samples(real, real, dr.zeros(mi.Float, lanes),
                                            background(pixel))
            mixed = trace_radiance(integrator, views.mixed, rays, seed, lanes)
            return differential_samples(mixed, real, virtual_coverage(views.mixed, rays),
                                        background(pixel))

        with timer.stage("trace"):
            res = run_passes(view.camera, settings.spp, kernel, seed=settings.seed,
                             spp_per_pass=settings.spp_per_pass,
                             progress="reference" if settings.progress else None)
        with timer.stage("assemble"):
            paths = res.lanes * (2 if has_virtual else 1)
            return layers_from_passes(frame, res, paths_traced=float(paths))
