"""Benchmark: where onepass's time goes, per camera sample, next to Mitsuba's ``path``.

Each row is one kernel run through the same pass machinery (``run_passes``: multi-jittered
camera rays, per-pixel moments) at full resolution, so the numbers differ only by the
tracing work:

* ``mitsuba mixed`` / ``mitsuba real``: Mitsuba's ``path`` integrator on the mixed (ρ) and
  real-only (µ) views — the two halves of ``reference``;
* ``tracer mixed`` / ``tracer real``: onepass's own path tracer on one view (its two-pass
  mode);
* ``onepass``: both solutions in one pass (phase 1 + phase 2).

Microseconds per sample, minimum of ``--repeats`` interleaved warm runs. Usage:

    python benchmarks/bench_onepass_breakdown.py [--spp 16] [--repeats 3] [--write]
"""

from __future__ import annotations

import argparse
import os

import mitsuba as mi
from arlight.methods.onepass_tracer import OnePassTracer, lane_keys
from results import publish

from arlight.backend.mitsuba_scene import build_views
from arlight.backend.passes import run_passes
from arlight.demo import demo_world_path
from arlight.evaluate.suite import get_scene
from arlight.methods.base import RenderSettings
from arlight.methods.onepass import tracer_options
from arlight.methods.reference import path_integrator, trace_radiance
from arlight.scene.load import load_scene

HEADING = "## One-pass cost breakdown (issue 3)"


def kernels(scene) -> dict:
    views = build_views(scene)
    integrator = path_integrator(RenderSettings())
    opts, _ = tracer_options(RenderSettings(options={"reproject": False}))
    tracer = OnePassTracer(views.mixed, views.real, opts)

    def mitsuba(view):
        return lambda rays, pixel, seed, lanes: {
            "L": trace_radiance(integrator, view, rays, seed, lanes)}

    def tracer_view(view):
        return lambda rays, pixel, seed, lanes: {
            "L": tracer.trace_view(view, mi.Ray3f(rays), lane_keys(lanes, seed)).mixed}

    def onepass(rays, pixel, seed, lanes):
        res = tracer.trace_onepass(mi.Ray3f(rays), lane_keys(lanes, seed))
        return {"L": res.mixed, "R": res.real}

    return {"mitsuba mixed": mitsuba(views.mixed), "mitsuba real": mitsuba(views.real),
            "tracer mixed": tracer_view(views.mixed), "tracer real": tracer_view(views.real),
            "onepass": onepass}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--write", action="store_true", help="update benchmarks/RESULTS.md")
    args = ap.parse_args()
    scenes = {"demo": load_scene(demo_world_path()),
              "glass-ring": get_scene("glass-ring", quick=False).world}
    table = {}
    for name, scene in scenes.items():
        ks = kernels(scene)
        n = scene.camera.width * scene.camera.height * args.spp
        for k in ks.values():  # warm-up: compile every kernel
            run_passes(scene.camera, args.spp, k, seed=1)
        times = {label: [] for label in ks}
        for _ in range(args.repeats):
            for label, k in ks.items():
                times[label].append(run_passes(scene.camera, args.spp, k, seed=1).seconds)
        table[name] = {label: min(t) / n * 1e6 for label, t in times.items()}
        print(name, {k: round(v, 4) for k, v in table[name].items()})
    labels = list(next(iter(table.values())))
    lines = [HEADING, "",
             f"`python benchmarks/bench_onepass_breakdown.py --write` ({mi.variant()}, "
             f"{os.cpu_count()} CPU cores, {args.spp} spp at full resolution, minimum of "
             f"{args.repeats} interleaved warm runs): µs per camera sample.", "",
             "| kernel | " + " | ".join(table) + " |", "|---" * (len(table) + 1) + "|"]
    for label in labels:
        lines.append(f"| {label} | " + " | ".join(f"{table[s][label]:.4f}" for s in table)
                     + " |")
    lines += ["", "onepass over `tracer mixed` is the price of carrying the real solution "
              "along (real shadow rays where a virtual object blocks the mixed one, L_r, fork "
              "records, phase 2); `mitsuba mixed + mitsuba real` is what `reference` pays "
              "for the same two solutions."]
    text = "\n".join(lines)
    publish(text, args.write)


if __name__ == "__main__":
    main()
