"""Benchmark: error against samples per pixel of ``onepass`` with each sampler (issue #22).

For each suite scene (quick size unless ``--width``): a converged onepass composite
(``--gt-spp`` Sobol samples, its own squared standard error subtracted from every MSE below)
and, per configuration and ``spp`` in ``--spp``, the composite MSE over ``--seeds`` seeds:

* ``independent``: hashed uniform numbers and Mitsuba's light sampling (the sampler before
  issue 22; per-sample standard errors);
* ``sobol/scrambles``: shuffled Owen-scrambled Sobol, 16 independently scrambled replicas,
  Mitsuba's light sampling;
* ``sobol/scrambles+lights``: the same with lights chosen by power and rectangles sampled by
  solid angle (:mod:`arlight.sampling.lights`);
* ``sobol/blocks+lights``: one scrambled Sobol sequence per pixel (16 blocks for the
  errors) and the new light sampling.

``sobol`` is the default sampler (4D sets since the 4D commit; the first RESULTS table of
issue 22 was measured before it, i.e. with today's ``sobol2d``).

Reported: the slope of log RMSE against log spp (least squares over the ``spp`` list; plain
Monte Carlo is −0.5) and the per-sample MSE (MSE · spp) ratio independent / Sobol at 16 and
64 spp (> 1: Sobol better), plus the mean ``z²`` of each render against the converged image
(≈ 1 when the stated standard errors are honest; the converged image's error included).

    python benchmarks/bench_sampler.py --write
"""

from __future__ import annotations

import argparse

import numpy as np
from results import cpu_pressure, publish

from arlight.methods import RenderSettings, get_method

HEADING = "## Sampler: error against spp, Sobol vs independent (issue 22)"
CONFIGS = {"independent": {"sampler": "independent", "replicas": 1,
                           "light_sampling": "mitsuba"},
           "sobol/scrambles": {"sampler": "sobol", "replicas": 16,
                               "replica_mode": "scrambles", "light_sampling": "mitsuba"},
           "sobol/scrambles+lights": {"sampler": "sobol", "replicas": 16,
                                      "replica_mode": "scrambles",
                                      "light_sampling": "solid_angle"},
           "sobol/blocks+lights": {"sampler": "sobol", "replicas": 16,
                                   "replica_mode": "blocks", "light_sampling": "solid_angle"}}


def load(name: str, width: int | None, frame_spp: int):
    from arlight.evaluate.suite import get_scene

    sc = get_scene(name, quick=width is None)
    if width is not None:
        w, h = sc.resolution
        world = sc.world.resized(width, round(width * h / w))
        proxy = sc.proxy.resized(width, round(width * h / w))
    else:
        world, proxy = sc.world, sc.proxy
    from arlight.synthetic import synthesize

    photo = synthesize(world, spp=frame_spp, seed=1)
    return proxy.with_frame(photo.frame)


def render(scene, spp: int, seed: int, opts: dict, max_depth: int):
    return get_method("onepass")(scene, RenderSettings(spp=spp, seed=seed, max_depth=max_depth,
                                                       options={"reproject": False, **opts}))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["bunny-box", "cornell-near-field",
                                                     "red-paper", "outdoor-env"])
    ap.add_argument("--width", type=int, default=None)
    ap.add_argument("--spp", nargs="+", type=int, default=[16, 64, 256, 1024])
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--gt-spp", type=int, default=16384)
    ap.add_argument("--max-depth", type=int, default=8)
    ap.add_argument("--write", action="store_true")
    args = ap.parse_args()

    lines = [HEADING, "",
             f"`python benchmarks/bench_sampler.py` — onepass composite, suite scenes at "
             f"{'80 px' if args.width is None else f'{args.width} px'} wide, max_depth "
             f"{args.max_depth}, spp {args.spp}, {args.seeds} seeds each, converged image "
             f"{args.gt_spp} Sobol spp (its squared SE subtracted). CPU pressure at start: "
             f"{cpu_pressure() or 'n/a'} %.", "",
             "| scene | sampler | RMSE slope | MSE·spp at 16 | at 64 | gain ×16 | gain ×64 "
             "| mean z² |", "|---|---|---|---|---|---|---|---|"]
    for name in args.scenes:
        scene = load(name, args.width, 256)
        gt = render(scene, args.gt_spp, 99, CONFIGS["sobol/scrambles+lights"], args.max_depth)
        gt_img, gt_var = gt.composite.astype(np.float64), np.square(gt.stderr["composite"])
        mse: dict[str, dict[int, float]] = {}
        z2: dict[str, float] = {}
        for spp in args.spp:
            for label, opts in CONFIGS.items():
                vals, zs = [], []
                for seed in range(args.seeds):
                    lay = render(scene, spp, 1000 + seed, opts, args.max_depth)
                    d2 = np.square(lay.composite - gt_img)
                    vals.append(float(np.mean(d2 - gt_var)))
                    zs.append(float(np.mean(d2 / (np.square(lay.stderr["composite"])
                                                  + gt_var + 1e-12))))
                mse.setdefault(label, {})[spp] = float(np.mean(vals))
                z2[label] = float(np.mean(zs))
                print(name, label, spp, mse[label][spp], z2[label], flush=True)
        sp = np.array(args.spp, float)
        for label in CONFIGS:
            e = np.array([mse[label][s] for s in args.spp])
            slope = np.polyfit(np.log(sp), 0.5 * np.log(np.maximum(e, 1e-30)), 1)[0]
            ps = {s: mse[label].get(s, np.nan) * s for s in (16, 64)}
            gain = {s: mse["independent"].get(s, np.nan) / mse[label].get(s, np.nan)
                    for s in (16, 64)}
            lines.append(f"| {name} | {label} | {slope:.3f} | {ps[16]:.3g} | {ps[64]:.3g} | "
                         f"{gain[16]:.2f} | {gain[64]:.2f} | {z2[label]:.2f} |")
    publish("\n".join(lines), args.write)


if __name__ == "__main__":
    main()
