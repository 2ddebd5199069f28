"""Choose the light selection's two constants on **training** worlds (issue #35).

``UNIFORM_MIX`` (the uniform share of the importance selection) and ``ENV_COSINE`` (the
cosine-weighted share of an environment map's samples), :mod:`arlight.sampling.lights`, are
tried on a grid; for each, ``onepass``'s per-sample variance of the composite (``--seeds``
renders of ``--spp``, as ``bench_light_selection.py``) relative to ``reference``'s is
measured on each training world (seeds < 1 000 000: never the held-out ones the results
are reported on) and summarised by its geometric mean and worst world. The constants are
set in the module before each render (the sampler reads them when built).

    python benchmarks/tune_light_selection.py --worlds training:8 --width 96 --write
"""

from __future__ import annotations

import argparse
import itertools

import numpy as np
from bench_light_selection import load_world, per_sample_variance, renders
from results import cpu_pressure, publish

import arlight.sampling.lights as lights
from arlight.evaluate.worlds import parse_worlds, split_of

HEADING = "## Light selection constants chosen on training worlds (issue #35)"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worlds", default="training:8", help="training worlds (SPLIT:N or seeds)")
    ap.add_argument("--width", type=int, default=96, help="image width, pixels")
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--mix", type=float, nargs="+", default=[0.1, 0.3])
    ap.add_argument("--env-cosine", type=float, nargs="+", default=[0.0, 0.25, 0.5])
    ap.add_argument("--write", action="store_true")
    args = ap.parse_args()
    seeds = parse_worlds(args.worlds)
    if any(split_of(s) != "training" for s in seeds):
        ap.error("constants are chosen on training worlds only (seeds < 1 000 000)")
    grid = list(itertools.product(args.mix, args.env_cosine))
    pressure = cpu_pressure() or "n/a"
    ratios: dict[tuple[float, float], list[float]] = {g: [] for g in grid}
    names = []
    for seed in seeds:
        gw, scene, keep = load_world(seed, args.width)
        ref, _ = renders("reference", scene, args.spp, args.seeds, 8, {})
        v_ref = float(per_sample_variance(ref, args.spp)[keep].mean())
        names.append(f"{gw.name}: {gw.describe()}")
        for mix, cos in grid:
            lights.UNIFORM_MIX, lights.ENV_COSINE = mix, cos
            st, _ = renders("onepass", scene, args.spp, args.seeds, 8, {"reproject": False})
            v = float(per_sample_variance(st, args.spp)[keep].mean())
            ratios[(mix, cos)].append(v / max(v_ref, 1e-30))
            print(gw.name, mix, cos, round(ratios[(mix, cos)][-1], 3), flush=True)
    lines = [HEADING, "",
             f"`python benchmarks/tune_light_selection.py --worlds {args.worlds} --width "
             f"{args.width} --spp {args.spp} --seeds {args.seeds}` — onepass's per-sample "
             "variance of the composite / reference's, per training world; geometric mean "
             f"and worst. CPU pressure (avg60): {pressure} / {cpu_pressure() or 'n/a'} %.", "",
             "| UNIFORM_MIX | ENV_COSINE | geometric mean | worst | per world |",
             "|---|---|---|---|---|"]
    best = min(grid, key=lambda g: float(np.exp(np.mean(np.log(ratios[g])))))
    for g in grid:
        r = np.array(ratios[g])
        mark = " **(lowest)**" if g == best else ""
        lines.append(f"| {g[0]:g} | {g[1]:g} | {np.exp(np.mean(np.log(r))):.3f}{mark} | "
                     f"{r.max():.3f} | {', '.join(f'{x:.2f}' for x in r)} |")
    lines += ["", "Worlds:", "", *(f"* {n}" for n in names)]
    publish("\n".join(lines), args.write)


if __name__ == "__main__":
    main()
