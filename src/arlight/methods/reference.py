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

**Sampling** (options ``sampler``, ``replicas``). The default ``independent`` is the trusted
sampler the suite's 3-SE tests rest on (see below). With ``multijitter`` the
path's random numbers come from Mitsuba's ``multijitter`` sampler (Kensler's correlated
multi-jittered sampling, as in :mod:`arlight.synthetic`): the ``spp`` samples of a pixel form
``R`` *replicas* (``R`` = the largest divisor of ``spp`` not above ``replicas``,
:func:`arlight.backend.passes.effective_replicas`), each one stratified set of ``s = spp/R``
samples with its own randomisation. The pass engine's lanes are pixel-major and, within a
pixel, replica-major (lane ``l`` of a pass of ``n = m·R`` samples per pixel: pixel ``l // n``,
replica ``(l mod n) // m``), so Mitsuba's sequence of lane ``l`` — the block of
``samples_per_wavefront = m`` lanes it belongs to — is one (pixel, replica) pair. Every pass
has the same ``m`` (``m`` divides ``s``; :func:`ld_plan`), seeds the sampler with the same seed
and advances it by the pass index, so pass ``p`` draws points ``p·m … p·m + m − 1`` of each
replica's set (Mitsuba's own multi-pass scheme): after all passes each replica is one
complete stratified set of ``s`` points. The camera ray's pixel (and lens) position comes
from the sampler's first dimensions, as in Mitsuba's own renders, so replicas are
independent down to the pixel position (the pass engine's multi-jittered camera stratifies
across all ``spp`` samples, which would correlate the replicas and inflate their spread).
Where Mitsuba rounds ``s`` up (``multijitter``:
to ``⌊√s⌋·⌈s/⌊√s⌋⌉``, e.g. 5 → 6) the replica uses the first ``s`` points of the larger set
(every point is uniformly distributed, so the mean stays unbiased). The standard errors come
from the spread of the ``R`` replica means (``R − 1`` degrees of freedom, ``stats
["stderr_dof"]``; pass it to :func:`arlight.stats.agreement_fraction`), never from the
per-sample variance, which overstates the error of stratified samples. ``independent``: the
pass engine's multi-jittered camera rays (stratified over all ``spp``), Mitsuba's
``independent`` sampler seeded per pass, per-sample-variance standard errors (``replicas``
unused). ``multijitter`` lowers the MSE at equal spp to 0.45–0.75× (mixed 0.58, real 0.45,
delta and composite ~0.74 on the 32×24 test room at 64 spp) for ~10 % more time per sample,
but its replicas stratify the camera only within themselves (mask edges within ``1/s``, not
``1/spp``) and its 15-dof errors left agreement fractions at 0.987–0.991 against onepass
where the 3-SE rule asks 0.99: not yet the default for the ground-truth method.

The mixed and the real path of a lane read identical random sequences (each trace seeds
its own sampler identically), so the delta keeps its low variance.

Stages (``Layers.stats``, seconds): ``time_prepare`` (both Mitsuba scenes and their BVHs),
``time_setup`` (integrator, frame upload), ``time_trace`` (the sample passes, including the
per-pass per-pixel sums), ``time_assemble`` (moments to layers, standard errors, composite);
``time_pose`` when the view moves objects (the posed world's scenes are built again).
Stats: ``stderr_replicas`` and ``stderr_dof`` (the replicas behind the standard errors and
their degrees of freedom), ``ld_set_size`` (points per replica set, 0 with ``independent``),
``paths_traced``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from arlight.backend.camera_rays import rays_from_samples
from arlight.backend.mitsuba_scene import (
    ROLE_VIRTUAL,
    SceneView,
    sampler_count,
)
from arlight.backend.passes import effective_replicas, run_passes
from arlight.jit import MAX_LANES
from arlight.layers import differential_samples, layers_from_passes
from arlight.methods.base import (
    Layers,
    RenderSettings,
)
from arlight.methods.fragments import PathScenesMethod
from arlight.methods.spec import Capabilities, Field, MethodSpec, Options
from arlight.scene.model import FrameView
from arlight.timing import StageTimer
from arlight.tracing.scenes import PathScenes, frame_gather


def path_integrator(settings: RenderSettings) -> mi.SamplingIntegrator:
    """Mitsuba's ``path`` integrator with the depth settings of ``settings``."""
    return mi.load_dict({"type": "path", "max_depth": settings.max_depth,
                         "rr_depth": settings.rr_depth})


OPTIONS: dict[str, Field] = {
    "sampler": Field("choice", "independent", "`independent`: Mitsuba's independent sampler, "
                     "camera stratified over all spp, per-sample-variance standard errors (the "
                     "trusted default the suite's 3-SE tests rest on); `multijitter`: each "
                     "replica of a pixel one stratified set of Mitsuba's multi-jittered sampler "
                     "(MSE 0.45-0.75x at equal spp, ~10 % slower per sample, replica standard "
                     "errors with R - 1 dof)", choices=("independent", "multijitter")),
    "replicas": Field("int", 16, "independent randomisations per pixel whose spread gives the "
                      "standard errors (the largest divisor of spp not above it; "
                      "`multijitter` only)", min=1, max=4096),
}


@dataclass(frozen=True)
class LDPlan:
    """How a render of ``spp`` samples per pixel draws low-discrepancy sets (:func:`ld_plan`).

    Attributes:
        kind: Mitsuba sampler type.
        replicas: ``R``, independent sets per pixel.
        set_size: ``s = spp / R`` points of each set.
        sample_count: the sampler's count for sets of ``s`` (``s`` rounded up by Mitsuba).
        per_pass: ``m``, points of each set drawn per pass (divides ``s`` and
            ``sample_count``); a pass has ``m·R`` samples per pixel.
    """

    kind: str
    replicas: int
    set_size: int
    sample_count: int
    per_pass: int

    @property
    def spp_per_pass(self) -> int:
        return self.per_pass * self.replicas


def ld_plan(kind: str, spp: int, replicas: int, pixels: int,
            spp_per_pass: int | None = None, max_lanes: int = MAX_LANES) -> LDPlan:
    """Replicas, set size and pass size of a low-discrepancy render.

    ``m`` is the largest common divisor of ``s`` and the sampler's count with
    ``m·R ≤ spp_per_pass`` (default: as many samples per pixel as fit in ``max_lanes`` lanes;
    at least 1), so every pass has the same size and each replica's set is complete after the
    last pass.
    """
    r = effective_replicas(spp, replicas)
    s = spp // r
    count = sampler_count(kind, s)
    cap = spp_per_pass or max(1, max_lanes // max(pixels, 1))
    g = math.gcd(s, count)
    m = max(d for d in range(1, g + 1) if g % d == 0 and (d == 1 or d * r <= cap))
    return LDPlan(kind, r, s, count, m)


def pass_sampler(plan: LDPlan, seed: int, lanes: int, pass_index: int) -> mi.Sampler:
    """Mitsuba's sampler for pass ``pass_index`` of a render with ``plan``, seeded with
    ``seed`` (the same in every pass) over ``lanes`` lanes: its sequences are blocks of
    ``plan.per_pass`` lanes (one pixel's replica each) and it stands at point
    ``pass_index · per_pass`` of them."""
    sampler = mi.load_dict({"type": plan.kind, "sample_count": plan.sample_count})
    sampler.set_samples_per_wavefront(plan.per_pass)
    sampler.seed(seed, lanes)
    for _ in range(pass_index):
        sampler.advance()
    return sampler


def trace_radiance(integrator: mi.SamplingIntegrator, view: SceneView,
                   rays: mi.RayDifferential3f, seed: mi.UInt32, lanes: int,
                   sampler: mi.Sampler | None = None) -> mi.Color3f:
    """Per-lane radiance along ``rays`` (W·sr⁻¹·m⁻²).

    Without ``sampler``, Mitsuba's ``independent`` sampler seeded with ``seed``; else the
    given, already seeded sampler (:func:`pass_sampler`). Equal seeds (equally built
    samplers) give equal random sequences.
    """
    if sampler is None:
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(seed, lanes)
    spec, _, _ = integrator.sample(view.scene, sampler, rays)
    return mi.Color3f(spec)


def virtual_coverage(view: SceneView, rays: mi.RayDifferential3f) -> mi.Float:
    """1 where the ray's first hit is a virtual shape, else 0."""
    si = view.scene.ray_intersect(mi.Ray3f(rays))
    return dr.select(view.hit_role(si) == ROLE_VIRTUAL, mi.Float(1.0), mi.Float(0.0))


class ReferenceMethod(PathScenesMethod):
    """Two-pass differential path tracing with Mitsuba's path tracer (ground-truth method)."""

    spec = MethodSpec(
        name="reference",
        description="Two-pass differential path tracing with Mitsuba's path tracer "
                    "(ground-truth method).",
        options=OPTIONS,
        capabilities=Capabilities(progressive=True),
    )

    incremental_pose = True
    move = PathScenesMethod.move_in_place
    relit = PathScenesMethod.relit_in_place

    def render_view(self, data: PathScenes, view: FrameView, options: Options,
                    settings: RenderSettings, timer: StageTimer) -> Layers:
        frame, views, has_virtual = view.frame, data.views, data.world.has_virtual
        camera = view.camera
        with timer.stage("setup"):
            integrator = path_integrator(settings)
            background = frame_gather(frame)
            plan = None
            if options.sampler != "independent":
                plan = ld_plan(options.sampler, settings.spp, options.replicas,
                               camera.width * camera.height, settings.spp_per_pass)
        passes = [0]  # run_passes calls the kernel once per pass, in order

        def kernel(rays, pixel, seed, lanes):
            p = passes[0]
            passes[0] += 1

            def trace(v: SceneView):
                """Radiance in ``v`` and the camera rays; with a plan, a fresh, equally seeded
                sampler per view whose first dimensions place the camera ray (as in
                Mitsuba's own renders), so each replica is independent down to the pixel
                position."""
                if plan is None:
                    return trace_radiance(integrator, v, rays, seed, lanes), rays
                smp = pass_sampler(plan, settings.seed, lanes, p)
                off = smp.next_2d()
                lens = smp.next_2d() if camera.aperture_radius > 0 else None
                own = rays_from_samples(camera, pixel, off, lens)
                return trace_radiance(integrator, v, own, seed, lanes, smp), own

            real, rays = trace(views.real)
            if not has_virtual:  # µ = ρ: one path serves both, the delta is exactly 0
                return differential_samples(real, real, dr.zeros(mi.Float, lanes),
                                            background(pixel))
            mixed, _ = trace(views.mixed)  # the same rays and random sequences as `real`
            return differential_samples(mixed, real, virtual_coverage(views.mixed, rays),
                                        background(pixel))

        with timer.stage("trace"):
            res = run_passes(camera, settings.spp, kernel, seed=settings.seed,
                             spp_per_pass=(settings.spp_per_pass if plan is None
                                           else plan.spp_per_pass),
                             progress="reference" if settings.progress else None,
                             replicas=1 if plan is None else plan.replicas)
        with timer.stage("assemble"):
            paths = res.lanes * (2 if has_virtual else 1)
            mom = res.moments["mixed"]
            return layers_from_passes(frame, res, paths_traced=float(paths),
                                      stderr_replicas=float(mom.replicas),
                                      stderr_dof=float(mom.dof),
                                      ld_set_size=float(0 if plan is None else plan.set_size))
