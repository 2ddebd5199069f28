"""The photo-consistent change of the path tracers, ``delta = additive | ratio`` (issue #31).

Differential rendering's additive change ``B + (I_m − I_r)`` is only as right as the proxy;
the ratio form ``B + s (I_m − I_r)``, ``s = clip(B / I_r, 0, 1/ρ)``
(:func:`arlight.layers.photo_scale`), changes a real pixel in proportion to what the
photograph shows. Per world (default the first 8 *training* worlds whose materials are all
diffuse, ``training-diffuse:8``: the default is chosen here), against Mitsuba's ground truth
(256 spp, seed 1, max depth 8: the shared photo cache), ``changed_psnr`` and ``psnr``:

* **ceiling** (``--parts ceiling``): ``onepass`` at ``--converged-spp`` (64), additive vs
  ratio, at each ``--widths`` (160, 320): the proxy's ceiling, which no denoiser can pass.
* **raw** (``--parts raw``): ``onepass`` at ``--spp`` undenoised, additive vs ratio (``s``
  from the noisy ``I_r``: what the option does without a denoiser).
* **denoised** (``--parts denoised``): ``onepass`` at ``--spp`` (1, 2, 4) with OIDN
  (``fast``, aux on, separate): additive; ratio with ``s`` from the denoised ``I_r`` (the
  option); ratio with ``s`` from the raw ``I_r`` (the ratio of the noisy estimate,
  ``E[1/X] > 1/E[X]``: a diagnostic, not an option).

Every variant of a world is composed from one render (the option's own code:
:meth:`arlight.methods.base.BaseMethod.ratio` on the additive layers), so the comparison
has no noise between variants.

    python benchmarks/bench_denoise_ratio.py [--worlds training-diffuse:8] [--widths 160,320]
        [--parts ceiling,denoised] [--write]
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_denoise import heldout_seeds  # noqa: E402
from results import cpu_pressure, publish  # noqa: E402
from tune_realtime import GT, scores  # noqa: E402

from arlight.evaluate.worlds import generate  # noqa: E402
from arlight.methods import RenderSettings, get_method  # noqa: E402
from arlight.timing import StageTimer  # noqa: E402

HEADING = "## Photo-consistent change of the path tracers: delta = additive | ratio (#31)"
MAX_DEPTH = GT["max_depth"]
GT_SPP = GT["spp"]
DENOISED = {"denoise": "oidn", "denoise_quality": "fast"}


def variants(method, state, view, layers) -> dict[str, np.ndarray]:
    """Composites of one render: ``additive`` (as rendered), ``ratio`` (the option's code on
    these layers) and, for denoised layers, ``ratio, raw I_r`` (``s`` from the undenoised
    real render)."""
    opts = method.spec.parse_options({**DENOISED, "delta": "ratio"})
    ratio = method.ratio(layers, state.data, view, opts, StageTimer(), {}, state.world)
    out = {"additive": layers.composite, "ratio": ratio.composite}
    noisy = getattr(layers, "noisy", None)
    if noisy is not None:
        raw_real = dataclasses.replace(layers, real=noisy.real)
        out["ratio, raw I_r"] = method.ratio(raw_real, state.data, view, opts, StageTimer(),
                                             {}, state.world).composite
    return out


def run_world(seed: int, width: int, parts: list[str], converged_spp: int,
              spps: list[int]) -> dict[tuple[str, int, str], dict[str, float]]:
    """``(part, spp, variant) -> scores`` of one world at ``width``."""
    scene = generate(seed).suite_scene(width)
    photo = scene.photo(**{**GT, "spp": GT_SPP})
    ar = scene.ar_scene(photo)
    method = get_method("onepass")
    state = method.prepare(ar.world, RenderSettings(spp=1, max_depth=MAX_DEPTH))
    out = {}
    runs = ([("ceiling", converged_spp, {})] if "ceiling" in parts else []) + \
        ([("denoised", s, DENOISED) for s in spps] if "denoised" in parts else []) + \
        ([("raw", s, {}) for s in spps] if "raw" in parts else [])
    for part, spp, opts in runs:
        layers = method.render(state, ar.view, RenderSettings(
            spp=spp, max_depth=MAX_DEPTH, seed=1 if part == "ceiling" else 0,
            options={**opts, "delta": "additive"}))  # the variants are composed from it
        for name, comp in variants(method, state, ar.view, layers).items():
            out[part, spp, name] = scores(comp, scene, photo)
    print(f"world-{seed} {width}", {f"{k[0]} {k[1]} {k[2]}": round(v["changed_psnr"], 2)
                                    for k, v in out.items()}, flush=True)
    return out


def section(results: dict, seeds: list[int], pressure: tuple[str, str], selection: str
            ) -> str:
    """The RESULTS section: medians per (width, part, spp, variant), per-world gains."""
    lines = [HEADING, "", f"Worlds: {selection} ({len(seeds)}: "
             f"{', '.join(str(s) for s in seeds)}); ground truth Mitsuba {GT_SPP} spp; "
             f"CPU pressure (PSI some avg60) {pressure[0]} % at the start, {pressure[1]} % at "
             "the end. `changed_psnr`: PSNR (dB) of the display image on the pixels the "
             "insertion changes; gain: ratio − additive per world.", "",
             "| width | onepass | variant | median changed_psnr | median psnr | "
             "median gain | worlds gaining | worst gain |", "|---|---|---|---|---|---|---|---|"]
    for width, res in results.items():
        keys = sorted({k for r in res.values() for k in r},
                      key=lambda k: (k[0], k[1], k[2] != "additive", k[2]))
        for part, spp, name in keys:
            rows = [r[part, spp, name] for r in res.values() if (part, spp, name) in r]
            base = [r[part, spp, "additive"] for r in res.values() if (part, spp, name) in r]
            gains = [a["changed_psnr"] - b["changed_psnr"] for a, b in zip(rows, base,
                                                                          strict=True)]
            label = f"{spp} spp" + {"denoised": " + OIDN fast", "raw": " raw"}.get(part, "")
            g = (f"{statistics.median(gains):+.2f} | {sum(x > 0 for x in gains)}/{len(gains)}"
                 f" | {min(gains):+.2f}") if name != "additive" else "— | — | —"
            lines.append(f"| {width} | {label} | {name} | "
                         f"{statistics.median(r['changed_psnr'] for r in rows):.2f} | "
                         f"{statistics.median(r['psnr'] for r in rows):.2f} | {g} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worlds", default="training-diffuse:8")
    ap.add_argument("--widths", default="160,320")
    ap.add_argument("--parts", default="ceiling,denoised")
    ap.add_argument("--converged-spp", type=int, default=64)
    ap.add_argument("--spp", default="1,2,4")
    ap.add_argument("--gt-spp", type=int, default=GT["spp"], help="ground truth spp (64: "
                    "the cached 640×480 truths of bench_denoise.py's 640×480 part)")
    ap.add_argument("--write", action="store_true")
    a = ap.parse_args()
    global GT_SPP
    GT_SPP = a.gt_spp
    seeds = heldout_seeds(a.worlds)
    parts = a.parts.split(",")
    p0 = cpu_pressure()
    print("CPU pressure", p0, flush=True)
    results = {}
    for width in (int(w) for w in a.widths.split(",")):
        results[width] = {s: run_world(s, width, parts if width == int(a.widths.split(",")[0])
                                       else ["ceiling"], a.converged_spp,
                                       [int(x) for x in a.spp.split(",")]) for s in seeds}
    publish(section(results, seeds, (p0, cpu_pressure()), a.worlds), a.write)


if __name__ == "__main__":
    main()
