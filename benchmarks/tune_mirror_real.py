"""Sweep dvct's ``mirror_alpha_real`` on training worlds with real glossy surfaces (issue #33).

dvct traces one reflection ray instead of the specular cone on REAL lanes whose GGX α is at
most ``mirror_alpha_real`` (:mod:`arlight.realtime.mirror_rays`). This script renders each
world once per candidate limit in one process (the candidates rendered interleaved, each
from its own prepared state, so machine load drifts over all alike) and prints per world and
limit the PSNR on the pixels the insertion changes, the PSNR on all pixels and dvct's frame
time (median of ``--frames`` renders after one warm-up render that compiles the kernels),
then the median over worlds of each limit's change against the first limit.

    python benchmarks/tune_mirror_real.py [--worlds 1,14,43,...] [--alphas 0,0.05,0.1,0.15,0.2]
        [--width 160] [--gt-spp 256] [--frames 3] [--out results.json]

The default worlds (:data:`WORLDS`) are *training* worlds (seeds below 1 000 000) whose real
surfaces include a rough conductor with α ≤ 0.3 or a mirror and where dvct runs; the ground
truth comes from the harness's shared cache (rendered and cached when missing). Run one
world per process (``--worlds 53``) where a world may abort it. Worlds whose changed region
is empty (world-43, world-178 at 160 px: the objects out of view) print ``nan``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

WORLDS: dict[int, str] = {
    # large real glossy surfaces (ground, floor, walls, back wall)
    14: "tabletop, ground roughconductor α 0.219 (+ mirror box); virtual diffuse",
    37: "tabletop, back wall roughconductor α 0.250; virtual diffuse",
    43: "room, floor roughconductor α 0.193; virtual diffuse",
    53: "outdoor, ground roughconductor α 0.064; two virtual diffuse",
    78: "outdoor, ground roughconductor α 0.118; virtual roughconductor α 0.150",
    105: "tabletop, back wall roughconductor α 0.174; virtual diffuse",
    153: "outdoor, ground roughconductor α 0.121 (+ prop α 0.101); virtual diffuse",
    163: "room, ceiling and walls roughconductor α 0.136 (+ box α 0.132); two virtual phong",
    178: "room, ceiling and walls roughconductor α 0.086 (+ mirror box); virtual diffuse",
    196: "tabletop, ground roughconductor α 0.065, mirror back wall and box; virtual diffuse "
         "and roughconductor α 0.314",
    243: "outdoor, ground roughconductor α 0.097; virtual diffuse",
    261: "room, ceiling and walls roughconductor α 0.069; virtual diffuse",
    276: "room, floor roughconductor α 0.070; virtual mirror and diffuse",
    284: "tabletop, ground roughconductor α 0.114 (+ sphere α 0.144); virtual phong and "
         "roughconductor α 0.051",
    297: "tabletop, back wall roughconductor α 0.159; virtual diffuse",
    307: "outdoor, ground roughconductor α 0.085; two virtual phong",
    348: "tabletop, back wall roughconductor α 0.073; virtual roughconductor α 0.094",
    380: "room, floor roughconductor α 0.248; virtual mirror",
    387: "room, floor roughconductor α 0.167; virtual mirror and phong",
    # real glossy props only
    1: "room, prop roughconductor α 0.162; two virtual diffuse",
    187: "room, props roughconductor α 0.195 and 0.060 (sphere); virtual diffuse",
    211: "tabletop, mirror sphere and box; two virtual diffuse",
}
"""Training worlds with real glossy surfaces where dvct runs (found by scanning seeds 0–399
with :func:`arlight.evaluate.worlds.generate`: a real ``roughconductor`` of α ≤ 0.3 or a
real ``mirror``, and no glass or sphere light)."""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--worlds", default=",".join(map(str, WORLDS)),
                    help="comma-separated training seeds (default: WORLDS)")
    ap.add_argument("--alphas", default="0,0.05,0.1,0.15,0.2",
                    help="candidate mirror_alpha_real values; the first is the reference")
    ap.add_argument("--width", type=int, default=160, help="image width (px)")
    ap.add_argument("--gt-spp", type=int, default=256, help="ground-truth samples per pixel")
    ap.add_argument("--frames", type=int, default=3, help="timed renders per candidate")
    ap.add_argument("--options", default="{}", help="JSON: further dvct options, all candidates")
    ap.add_argument("--out", default="", help="write the per-world results as JSON here (a "
                    "new file: an existing one is never overwritten)")
    args = ap.parse_args()
    if args.out and Path(args.out).exists():  # before the sweep, not after an hour of it
        ap.error(f"--out {args.out} exists; choose a new file")

    from arlight.evaluate.harness import (
        EvalConfig,
        changed_region,
        eval_scene,
        scene_photo,
        skip_reason,
    )
    from arlight.evaluate.metrics import display, psnr
    from arlight.evaluate.worlds import HELDOUT_BASE
    from arlight.methods import RenderSettings, get_method

    seeds = [int(x) for x in args.worlds.split(",") if x]
    if any(s >= HELDOUT_BASE for s in seeds):
        ap.error(f"tune on training worlds only (seeds below {HELDOUT_BASE})")
    alphas = [float(x) for x in args.alphas.split(",")]
    extra = json.loads(args.options)
    res: dict[int, dict[float, dict[str, float]]] = {}
    for seed in seeds:
        cfg = EvalConfig(methods=["dvct"], scenes=[], quick=False, spp=16, gt_spp=args.gt_spp,
                         repeats=1, worlds=[seed], world_width=args.width)
        scene = eval_scene(f"world-{seed}", cfg)
        why = skip_reason("dvct", scene)
        if why:
            print(seed, "skip:", why[:70], flush=True)
            continue
        photo = scene_photo(scene, cfg)
        ar = scene.ar_scene(photo)
        method = get_method("dvct")
        settings = {a: RenderSettings(spp=16, max_depth=8, seed=0,
                                      options={**extra, "mirror_alpha_real": a})
                    for a in alphas}
        # every dvct option is a preparation option: one state per candidate
        states = {a: method.prepare(ar.world, settings[a]) for a in alphas}
        times: dict[float, list[float]] = {a: [] for a in alphas}
        outs = {}
        for frame in range(args.frames + 1):
            for a in alphas:
                t0 = time.perf_counter()
                outs[a] = method.render(states[a], ar.view, settings[a])
                if frame:  # the first render compiles
                    times[a].append(time.perf_counter() - t0)
        region = changed_region(photo)
        row = res.setdefault(seed, {})
        tf = scene.world.camera.transfer
        ref = display(photo.ground_truth, tf)
        for a in alphas:
            # the harness's display PSNRs (composite_metrics' ``psnr``, ``changed_psnr``)
            # without its FLIP, whose HDR variant aborts the process on world-43
            test = display(outs[a].composite, tf)
            row[a] = {"changed_psnr": psnr(test, ref, peak=1.0, region=region),
                      "psnr": psnr(test, ref, peak=1.0),
                      "seconds": statistics.median(times[a])}
        print(seed, " ".join(f"{a:g}: {row[a]['changed_psnr']:.2f}/{row[a]['psnr']:.2f}"
                             f"/{row[a]['seconds'] * 1e3:.0f}ms" for a in alphas), flush=True)
    if not res:
        return
    base = alphas[0]
    print(f"median over {len(res)} worlds, against mirror_alpha_real {base:g} "
          "(changed PSNR Δ dB, all-pixel PSNR Δ dB, time ratio, worlds gained/lost > 0.05 dB)")
    for a in alphas:
        dc = [r[a]["changed_psnr"] - r[base]["changed_psnr"] for r in res.values()]
        dp = [r[a]["psnr"] - r[base]["psnr"] for r in res.values()]
        tr = [r[a]["seconds"] / r[base]["seconds"] for r in res.values()]
        print(f"  {a:g}: changed {statistics.median(dc):+.3f} (min {min(dc):+.2f}, max "
              f"{max(dc):+.2f}), all {statistics.median(dp):+.3f}, time ×"
              f"{statistics.median(tr):.3f}, gained {sum(x > 0.05 for x in dc)}, lost "
              f"{sum(x < -0.05 for x in dc)}")
    if args.out:  # exclusive create: a file made meanwhile is not overwritten either
        with open(args.out, "x") as f:
            json.dump({str(s): {str(a): v for a, v in r.items()} for s, r in res.items()}, f,
                      indent=1)


if __name__ == "__main__":
    main()
