"""Benchmark: throughput of ``reference`` next to Mitsuba's own ``path`` integrator.

Both render the demo scene at its resolution (640×480) in the same process; we report
samples per second (a "sample" = one camera sample per pixel, for ``reference`` that is a
mixed path + a real path + a mask ray) and their ratio. Warm runs only (the first run of
each compiles the LLVM kernels). Usage:

    python benchmarks/bench_reference.py [--spp 16] [--repeats 3] [--write]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import drjit as dr
import mitsuba as mi
from results import publish

from arlight.backend.mitsuba_scene import build_views, mitsuba_sensor
from arlight.demo import demo_scene_path
from arlight.methods import RenderSettings, get_method
from arlight.scene.load import load_scene

HEADING = "## Reference method throughput (issue 2)"


def time_mitsuba_path(scene, spp: int, max_depth: int) -> float:
    views = build_views(scene)
    sensor = mitsuba_sensor(scene.camera, spp)
    integrator = mi.load_dict({"type": "path", "max_depth": max_depth})
    t = time.perf_counter()
    img = mi.render(views.mixed.scene, sensor=sensor, integrator=integrator, spp=spp, seed=1)
    dr.eval(img)
    dr.sync_thread()
    return time.perf_counter() - t


def time_reference(scene, spp: int, max_depth: int) -> float:
    layers = get_method("reference")(scene, RenderSettings(spp=spp, max_depth=max_depth,
                                                           seed=1))
    return layers.stats["seconds"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--max-depth", type=int, default=8)
    ap.add_argument("--write", action="store_true", help="update benchmarks/RESULTS.md")
    args = ap.parse_args()
    scene = load_scene(demo_scene_path())
    n = scene.camera.width * scene.camera.height * args.spp
    time_reference(scene, args.spp, args.max_depth)  # warm-up (kernel compilation)
    time_mitsuba_path(scene, args.spp, args.max_depth)
    ref, path = [], []
    for _ in range(args.repeats):  # interleaved so machine load affects both alike
        ref.append(time_reference(scene, args.spp, args.max_depth))
        path.append(time_mitsuba_path(scene, args.spp, args.max_depth))
    t_ref, t_path = statistics.median(ref), statistics.median(path)
    rows = [
        f"Demo scene {scene.camera.width}×{scene.camera.height}, {args.spp} spp, max_depth "
        f"{args.max_depth}, median of {args.repeats} warm runs, Mitsuba variant "
        f"{mi.variant()}, {os.cpu_count()} CPU cores, "
        "`python benchmarks/bench_reference.py --write`.",
        "",
        "| renderer | seconds | Msamples/s | Mpaths/s |",
        "|---|---|---|---|",
        f"| reference (mixed + real path + mask ray per sample) | {t_ref:.2f} | "
        f"{n / t_ref / 1e6:.3f} | {2 * n / t_ref / 1e6:.3f} |",
        f"| Mitsuba `path`, mixed scene only | {t_path:.2f} | {n / t_path / 1e6:.3f} | "
        f"{n / t_path / 1e6:.3f} |",
        "",
        f"Ratio reference / path samples per second: **{t_path / t_ref:.3f}** (paths per "
        f"second: {2 * t_path / t_ref:.3f}). `reference` traces two solutions per sample, so "
        "0.5 would be the cost of the two path tracings alone; the rest is its mask ray and "
        "the per-pixel moments (sum and sum of squares) of five layers for standard errors.",
    ]
    text = "\n".join([HEADING, "", *rows])
    publish(text, args.write)


if __name__ == "__main__":
    main()
