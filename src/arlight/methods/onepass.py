"""``onepass``: one-pass differential path tracing (Kán & Kaufmann; Kán thesis §3.3, §4.4).

``I_m``, ``I_r`` and the mask ``M`` come out of a single wavefront pass with Kán's four ray
types (mixed/real radiance, mixed/real shadow) and four hit rules: paths that never touch a
virtual object are traced once and serve both solutions; at a virtual hit a real-radiance
continuation ray supplies ``I_r``. See :mod:`arlight.tracing.onepass` for the tracer
and ``docs/methods/onepass.md`` for the design.

Options (``RenderSettings.options``, declared in :data:`OPTIONS`; ``arlight methods onepass``
prints them): ``env_mode`` (``mis`` | ``miss_only``), ``mirror_lower_hemisphere``,
``reproject``, ``mode`` (``onepass`` | ``twopass``: the same tracer run separately on the mixed
and the real view, with the same random numbers — the baseline of the equivalence test and
of the ray counts), ``sampler`` (``sobol`` | ``independent``), ``replicas`` and
``replica_mode`` (the standard errors' independent randomisations), ``sample_offset``
(progressive frames continuing one sequence, :mod:`arlight.backend.passes`),
``light_sampling`` (``importance`` | ``solid_angle`` | ``mitsuba``,
:mod:`arlight.sampling.lights`), ``caustics``
(``none`` | ``photons``: differential caustic photon mapping, :mod:`arlight.tracing.photons`)
with ``photons``, ``photon_radius`` (m), ``ppm_iterations``, ``ppm_alpha``.

Stats: ``seconds``, ``samples``, ``spp``, ``samples_per_second`` and ray counts per ray type
(``rays_mixed_radiance``, ``rays_real_radiance``, ``rays_mixed_shadow``,
``rays_real_shadow``, ``rays_reprojection`` — the camera-visibility tests of §5.2),
``rays_total`` and ``rays_per_sample``; in one-pass mode also ``forked_lanes`` /
``forked_fraction`` (samples whose path hit a virtual object and so were continued by the
tracer's second phase) and ``phase1_seconds`` / ``phase2_seconds`` (mixed/shared loop vs the
compacted real continuations, synchronised wall time; both are parts of ``time_trace``).
Stages, seconds: ``time_prepare`` (Mitsuba scenes), ``time_setup`` (tracer, reprojection
table, frame upload), ``time_trace``, ``time_assemble``; ``time_pose`` when the view moves
objects; with caustics ``time_photons`` (t_p: shooting and tracing) and
``time_photon_index`` (t_b: hash grid build), the density estimation being part of
``time_trace`` (t_r), plus ``photons_emitted``, ``photons_stored``, ``photons_shared``,
``photons_mixed_only``, ``photons_real_only``, ``photon_radius``.
"""

from __future__ import annotations

import mitsuba as mi
import numpy as np

from arlight.backend.passes import run_passes
from arlight.errors import InputError
from arlight.layers import differential_samples, layers_from_passes
from arlight.methods.base import (
    Layers,
    RenderSettings,
)
from arlight.methods.fragments import SAMPLER_OPTIONS, PathScenesMethod
from arlight.methods.spec import Capabilities, Field, MethodSpec, Options
from arlight.scene.model import FrameView
from arlight.timing import StageTimer
from arlight.tracing.onepass import RAY_TYPES, OnePassTracer, TracerOptions
from arlight.tracing.photons import (
    PhotonMap,
    PhotonSettings,
    build_indices,
    build_photon_maps,
    gather_caustics,
)
from arlight.tracing.scenes import PathScenes, frame_gather

OPTIONS: dict[str, Field] = {
    "env_mode": Field("choice", "mis", "`mis`: environment maps are light-sampled with MIS; "
                      "`miss_only`: the thesis's IBL, map lookup on misses only",
                      choices=("mis", "miss_only")),
    "mirror_lower_hemisphere": Field("bool", False, "below-horizon misses read the mirrored "
                                     "upper hemisphere (Kán §5.3, fisheye maps; needs "
                                     "`env_mode = miss_only`)"),
    "reproject": Field("bool", True, "camera-image reprojection through virtual specular "
                       "objects (Kán §5.2)"),
    "mode": Field("choice", "onepass", "`onepass`: Kán's four ray types in one pass; "
                  "`twopass`: the same tracer on each view separately (baseline)",
                  choices=("onepass", "twopass")),
    **SAMPLER_OPTIONS,
    "sample_offset": Field("int", 0, "first sample index drawn in every pixel (a multiple of "
                           "the replicas): progressive frames with one seed and offsets n·spp "
                           "continue one Sobol sequence", min=0, max=2**31 - 1),
    "light_sampling": Field("choice", "importance", "`importance`: each light chosen with "
                            "its estimated contribution at the shading point (power, distance, "
                            "orientation; pbrt-v4's light-bounds importance, distant and "
                            "environment lights by their irradiance), rectangles by solid "
                            "angle, environments with the surface's cosine in mind; "
                            "`solid_angle`: lights chosen by one global power estimate "
                            "(rectangles by solid angle); `mitsuba`: the scene's own (uniform "
                            "choice, rectangles by area)",
                            choices=("importance", "solid_angle", "mitsuba")),
    "caustics": Field("choice", "none", "`photons`: caustic photon map from point/spot lights "
                      "through glass and mirrors, differential (Kán §4.1.2, "
                      "docs/methods/photons.md); `none`: path tracing only",
                      choices=("none", "photons")),
    "photons": Field("int", 200_000, "photons emitted per photon map (with `caustics = "
                     "photons`)", min=1, max=100_000_000),
    "photon_radius": Field("float", 0.01, "kernel radius h of the density estimate (Kán Eq. "
                           "4.4–4.5); first radius under PPM", "m", min=0.0, max=1.0e6,
                           exclusive_min=True),
    "ppm_iterations": Field("int", 1, "photon maps with shrinking radius (progressive photon "
                            "mapping; 1: Kán's fixed radius)", min=1, max=4096),
    "ppm_alpha": Field("float", 0.7, "Hachisuka's alpha: h_{i+1}^2 = h_i^2 (i + alpha)/(i + 1)",
                       min=0.0, max=1.0, exclusive_min=True),
}
OPTION_NAMES = tuple(OPTIONS)


def _check(opts: Options) -> None:
    if opts.mirror_lower_hemisphere and opts.env_mode != "miss_only":
        raise InputError("mirroring the lower hemisphere needs env_mode = 'miss_only'",
                         file="method 'onepass'", field="options.mirror_lower_hemisphere")
    if opts.ppm_alpha >= 1.0:
        raise InputError("must be < 1 (the radius would not shrink)", file="method 'onepass'",
                         field="options.ppm_alpha")


SPEC = MethodSpec(
    name="onepass",
    description="One-pass differential path tracing with Kán's four ray types (fewer rays "
                "than two-pass).",
    options=OPTIONS,
    capabilities=Capabilities(interactive=True, progressive=True),
    check=_check,
    frame_options=frozenset({"sample_offset"}),
)


def tracer_from_options(opts: Options, settings: RenderSettings) -> TracerOptions:
    """The tracer's options from validated method options and the depth settings."""
    return TracerOptions(max_depth=settings.max_depth, rr_depth=settings.rr_depth,
                         env_mode=opts.env_mode,
                         mirror_lower_hemisphere=opts.mirror_lower_hemisphere,
                         reproject=opts.reproject, light_sampling=opts.light_sampling)


def photon_settings(opts: Options, settings: RenderSettings) -> PhotonSettings:
    """The caustic photon map's settings from validated options and the render settings."""
    return PhotonSettings(photons=opts.photons, radius=opts.photon_radius,
                          ppm_iterations=opts.ppm_iterations, ppm_alpha=opts.ppm_alpha,
                          max_depth=settings.max_depth, seed=settings.seed)


def tracer_options(settings: RenderSettings) -> tuple[TracerOptions, str]:
    """Validated tracer options and the mode from ``settings`` (errors name the option)."""
    opts = SPEC.parse_options(settings.options)
    return tracer_from_options(opts, settings), opts.mode


def ray_stats(counts: dict[str, int], samples: int) -> dict[str, float]:
    """Ray counts per type plus ``rays_total`` and ``rays_per_sample``."""
    out = {k: float(counts.get(k, 0)) for k in RAY_TYPES}
    out["rays_total"] = float(sum(counts.get(k, 0) for k in RAY_TYPES))
    out["rays_per_sample"] = out["rays_total"] / max(samples, 1)
    return out


class OnePassMethod(PathScenesMethod):
    """One-pass differential path tracing with Kán's four ray types (fewer rays than
    two-pass)."""

    spec = SPEC

    incremental_pose = True
    move = PathScenesMethod.move_in_place
    relit = PathScenesMethod.relit_in_place

    def render_view(self, data: PathScenes, view: FrameView, options: Options,
                    settings: RenderSettings, timer: StageTimer) -> Layers:
        frame, views, mode = view.frame, data.views, options.mode
        with timer.stage("setup"):
            tracer = OnePassTracer(views.mixed, views.real,
                                   tracer_from_options(options, settings), view.camera, frame)
            background = frame_gather(frame)
        counts = dict.fromkeys(RAY_TYPES, 0)
        pmap: PhotonMap | None = None
        pmap_real: PhotonMap | None = None
        photon_stats: dict[str, float] = {}
        if options.caustics == "photons":
            ps = photon_settings(options, settings)
            with timer.stage("photons"):  # t_p: emission and tracing (Kán Table 5.2)
                maps, photon_stats = build_photon_maps(data.world, views, ps)
            with timer.stage("photon_index"):  # t_b: the hash grids
                pmap, pmap_real = build_indices(maps, ps.radii(), views)
            photon_stats["photon_radius"] = ps.radius

        def kernel(rays, pixel, seed, lanes, key):
            r = mi.Ray3f(rays)
            if mode == "onepass":
                res = tracer.trace_onepass(r, key)
                lm, lr, m = res.mixed, res.real, res.mask
                parts = [res.rays]
            else:
                res_m = tracer.trace_view(views.mixed, r, key)
                if views.mixed is views.real:
                    res_r = res_m
                    parts = [res_m.rays]
                else:
                    res_r = tracer.trace_view(views.real, r, key)
                    parts = [res_m.rays, res_r.rays]
                lm, lr, m = res_m.mixed, res_r.mixed, res_m.mask
            for p in parts:
                for k, v in p.items():
                    counts[k] += v
            if pmap is not None:  # caustics L S+ D: density estimation after the camera walk
                cm, cr = gather_caustics(views, pmap, r, key.sample_key(), settings.max_depth,
                                         tracer.reproj, pmap_real)
                lm, lr = lm + cm, lr + cr
            return differential_samples(lm, lr, m, background(pixel))

        with timer.stage("trace"):
            res = run_passes(view.camera, settings.spp, kernel, seed=settings.seed,
                             spp_per_pass=settings.spp_per_pass,
                             progress="onepass" if settings.progress else None,
                             sampler=options.sampler, replicas=options.replicas,
                             scramble_replicas=options.replica_mode == "scrambles",
                             sample_offset=options.sample_offset)
        with timer.stage("assemble"):
            stats = ray_stats(counts, res.lanes)
            stats["stderr_replicas"] = float(res.moments["mixed"].replicas)
            stats["stderr_dof"] = float(res.moments["mixed"].dof)
            stats.update(photon_stats)
            if mode == "onepass":
                prof = tracer.profile
                stats.update(forked_lanes=float(prof["forked_lanes"]),
                             forked_fraction=prof["forked_lanes"] / max(res.lanes, 1),
                             phase1_seconds=prof["phase1_seconds"],
                             phase2_seconds=prof["phase2_seconds"])
            layers = layers_from_passes(frame, res, **stats)
        if not data.world.has_virtual:
            # Every path is shared, so L_m == L_r per sample and delta is exactly zero.
            assert not np.any(layers.delta), "one-pass delta must vanish without virtual objects"
        return layers


__all__ = ["OPTIONS", "OnePassMethod", "SPEC", "ray_stats", "tracer_options"]
