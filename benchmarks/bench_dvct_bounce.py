"""Benchmark: dvct's bounce radiometry options (issue #33) — the one-bounce ratios against
Mitsuba on the box scene and the options' effect on training worlds.

1. The ratios dvct / Mitsuba ``path`` (max_depth 3 − 2) of the cube's own bounce, the floor
   ring's loss of bounce light and the cube's red bounce on the floor
   (:func:`tests.methods.test_dvct_reference.ratios`) for the defaults and the options.
2. ``changed_psnr`` (dB) of dvct with each configuration on the training worlds it supports
   (seeds below 1 000 000, ``arlight.evaluate.worlds``), 160×120, ground truth Mitsuba
   256 spp (shared cache); the median of the per-world differences to the defaults.
   Training worlds only: these numbers choose the defaults.

Usage:

    python benchmarks/bench_dvct_bounce.py [--worlds training:12] [--write]
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
from results import cpu_pressure, publish

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

HEADING = "## dvct bounce radiometry (issue #33)"
NEW = {"anisotropic": True, "occluded_bounce": True, "directional_occupancy": True,
       "virtual_self_occlusion": False}
CONFIGS = {
    "defaults": {},
    "anisotropic": {"anisotropic": True},
    "anisotropic + occluded_bounce": {"anisotropic": True, "occluded_bounce": True},
    "all four options": NEW,
    "all four options, volume_scale 4": {**NEW, "volume_scale": 4.0},
    "defaults, volume_scale 4": {"volume_scale": 4.0},
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worlds", default="training:12", help="training worlds (SPLIT:N)")
    ap.add_argument("--write", action="store_true", help="store the section in RESULTS.md")
    args = ap.parse_args()
    from tests.methods.test_dvct_reference import ratios, reference_data

    from arlight.evaluate.harness import EvalConfig, run_evaluation
    from arlight.evaluate.worlds import parse_worlds, split_of

    seeds = parse_worlds(args.worlds)
    if any(split_of(s) != "training" for s in seeds):
        sys.exit("bench_dvct_bounce: --worlds must be training worlds (constants are chosen "
                 "there)")
    ref = reference_data()
    rat = {name: ratios(ref, **opts) for name, opts in CONFIGS.items()}
    psnr: dict[str, dict[str, float]] = {}
    for name, opts in CONFIGS.items():
        cfg = EvalConfig(methods=["dvct"], scenes=[], quick=False, spp=16, gt_spp=256,
                         repeats=1, worlds=seeds, world_width=160,
                         options={f"dvct.{k}": v for k, v in opts.items()})
        res = run_evaluation(cfg, log=lambda s: None)
        psnr[name] = {c.scene: c.metrics.get("changed_psnr", math.nan) for c in res.cells
                      if c.ok}
        print(name, rat[name].round(3), psnr[name], flush=True)
    base = psnr["defaults"]
    lines = [HEADING, "",
             f"`benchmarks/bench_dvct_bounce.py --worlds {args.worlds}`; CPU pressure "
             f"(PSI some avg60) at the end: {cpu_pressure()} %. One-bounce ratios dvct / "
             "Mitsuba `path` (depth 3 − 2) on the box scene of "
             "`tests/methods/test_dvct_reference.py`; Δ `changed_psnr` against the defaults "
             f"on the {len(base)} training worlds dvct supports among {args.worlds} "
             "(160×120, ground truth 256 spp). docs/methods/dvct.md, \"Radiometry of the "
             "bounce\", derives the options.", "",
             "| configuration | cube's own | ring's loss | red bounce | median Δ dB | mean Δ dB "
             "| worst Δ dB |", "|---|---|---|---|---|---|---|"]
    for name in CONFIGS:
        d = np.array([psnr[name][s] - base[s] for s in base if s in psnr[name]])
        r = rat[name]
        lines.append(f"| {name} | {r[0]:.2f} | {r[1]:.2f} | {r[2]:.2f} | "
                     f"{np.median(d):+.2f} | {d.mean():+.2f} | {d.min():+.2f} |")
    lines += ["", "Per world (defaults): " + ", ".join(f"{s} {v:.2f}" for s, v in
                                                       sorted(base.items())) + ".", "",
              "The defaults stay (isotropic cells, as Franke): none of the options gains on "
              "the training worlds, although the isotropic cells' red bounce is 4× the path "
              "tracer's. The ≥ 1 dB held-out target of issue #33 is not met for dvct; the "
              "held-out A/B is unchanged from the section above (defaults unchanged)."]
    publish("\n".join(lines), args.write)


if __name__ == "__main__":
    main()
