"""``onepass``: one-pass differential path tracing (Kán & Kaufmann; Kán thesis §3.3, §4.4).

``I_m``, ``I_r`` and the mask ``M`` come out of a single wavefront pass with Kán's four ray
types (mixed/real radiance, mixed/real shadow) and four hit rules: paths that never touch a
virtual object are traced once and serve both solutions; at a virtual hit a real-radiance
continuation ray supplies ``I_r``. See :mod:`arlight.methods.onepass_tracer` for the tracer
and ``docs/methods/onepass.md`` for the design.

Options (``RenderSettings.options``):

* ``env_mode``: ``"mis"`` (default; environment maps light-sampled with MIS) or
  ``"miss_only"`` (the thesis: map lookup on misses only).
* ``mirror_lower_hemisphere`` (bool, default False; needs ``miss_only``): below-horizon
  misses read the mirrored upper hemisphere (Kán §5.3, fisheye maps).
* ``reproject`` (bool, default True): camera-image reprojection through virtual specular
  objects (Kán §5.2).
* ``mode``: ``"onepass"`` (default) or ``"twopass"`` (the same tracer run separately on the
  mixed and the real view, with the same random numbers — the baseline of the equivalence
  test and of the ray counts).

Stats: ``seconds``, ``samples``, ``spp``, ``samples_per_second`` and ray counts per ray type
(``rays_mixed_radiance``, ``rays_real_radiance``, ``rays_mixed_shadow``,
``rays_real_shadow``, ``rays_reprojection`` — the camera-visibility tests of §5.2),
``rays_total`` and ``rays_per_sample``; in one-pass mode also ``forked_lanes`` /
``forked_fraction`` (samples whose path hit a virtual object and so were continued by the
tracer's second phase) and ``phase1_seconds`` / ``phase2_seconds`` (mixed/shared loop vs the
compacted real continuations, synchronised wall time).
"""

from __future__ import annotations

from typing import Any

import mitsuba as mi
import numpy as np

from arlight.backend.mitsuba_scene import build_views
from arlight.backend.passes import run_passes
from arlight.errors import InputError
from arlight.methods import register
from arlight.methods.base import (
    Layers,
    RenderSettings,
    differential_samples,
    layers_from_passes,
    require_frame,
)
from arlight.methods.onepass_tracer import RAY_TYPES, OnePassTracer, TracerOptions, lane_keys
from arlight.methods.reference import frame_gather
from arlight.scene.model import ARScene

OPTION_NAMES = ("env_mode", "mirror_lower_hemisphere", "reproject", "mode")


def _bool(value: Any, name: str) -> bool:
    if isinstance(value, bool):
        return value
    if isinstance(value, str) and value.lower() in ("1", "true", "yes", "on", "0", "false",
                                                    "no", "off"):
        return value.lower() in ("1", "true", "yes", "on")
    raise InputError(f"expected true or false, got {value!r}", field=f"options.{name}")


def tracer_options(settings: RenderSettings) -> tuple[TracerOptions, str]:
    """Validated tracer options and the mode from ``settings`` (errors name the option)."""
    opts = dict(settings.options)
    unknown = sorted(set(opts) - set(OPTION_NAMES))
    if unknown:
        raise InputError(f"unknown option for onepass; expected one of {', '.join(OPTION_NAMES)}",
                         field=f"options.{unknown[0]}")
    env_mode = opts.get("env_mode", "mis")
    if env_mode not in ("mis", "miss_only"):
        raise InputError(f"expected 'mis' or 'miss_only', got {env_mode!r}",
                         field="options.env_mode")
    mode = opts.get("mode", "onepass")
    if mode not in ("onepass", "twopass"):
        raise InputError(f"expected 'onepass' or 'twopass', got {mode!r}", field="options.mode")
    mirror = _bool(opts.get("mirror_lower_hemisphere", False), "mirror_lower_hemisphere")
    if mirror and env_mode != "miss_only":
        raise InputError("mirroring the lower hemisphere needs env_mode = 'miss_only'",
                         field="options.mirror_lower_hemisphere")
    return TracerOptions(max_depth=settings.max_depth, rr_depth=settings.rr_depth,
                         env_mode=env_mode, mirror_lower_hemisphere=mirror,
                         reproject=_bool(opts.get("reproject", True), "reproject")), mode


def ray_stats(counts: dict[str, int], samples: int) -> dict[str, float]:
    """Ray counts per type plus ``rays_total`` and ``rays_per_sample``."""
    out = {k: float(counts.get(k, 0)) for k in RAY_TYPES}
    out["rays_total"] = float(sum(counts.get(k, 0) for k in RAY_TYPES))
    out["rays_per_sample"] = out["rays_total"] / max(samples, 1)
    return out


@register("onepass")
def render_onepass(scene: ARScene, settings: RenderSettings) -> Layers:
    """One-pass differential path tracing with Kán's four ray types (fewer rays than two-pass)."""
    frame = require_frame(scene)
    opts, mode = tracer_options(settings)
    views = build_views(scene)
    tracer = OnePassTracer(views.mixed, views.real, opts, scene.camera, frame)
    background = frame_gather(frame)
    counts = dict.fromkeys(RAY_TYPES, 0)

    def kernel(rays, pixel, seed, lanes):
        key = lane_keys(lanes, seed)
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
        return differential_samples(lm, lr, m, background(pixel))

    res = run_passes(scene.camera, settings.spp, kernel, seed=settings.seed,
                     spp_per_pass=settings.spp_per_pass,
                     progress="onepass" if settings.progress else None)
    stats = ray_stats(counts, res.lanes)
    if mode == "onepass":
        prof = tracer.profile
        stats.update(forked_lanes=float(prof["forked_lanes"]),
                     forked_fraction=prof["forked_lanes"] / max(res.lanes, 1),
                     phase1_seconds=prof["phase1_seconds"], phase2_seconds=prof["phase2_seconds"])
    layers = layers_from_passes(frame, res, **stats)
    if not scene.has_virtual:
        # Every path is shared, so L_m == L_r per sample and delta is exactly zero.
        assert not np.any(layers.delta), "one-pass delta must vanish without virtual objects"
    return layers


__all__ = ["render_onepass", "ray_stats", "tracer_options"]
