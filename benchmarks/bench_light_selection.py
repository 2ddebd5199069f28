"""Benchmark: onepass's per-sample variance against ``reference``'s, per light selection, on
generated worlds (issue #35).

For each world (``--worlds``, held-out by default: nothing was tuned on them) at ``--width``:
``--seeds`` renders of 16 spp (``--spp``) of ``onepass`` with each ``light_sampling`` mode
(``importance``: per shading point, the default; ``solid_angle``: one global power
estimate, the selection before issue 35; ``mitsuba``: uniform) and of ``reference``
(Mitsuba's ``path`` integrator, uniform selection, independent sampler), all on the proxy
with the world's synthetic photograph. Per pixel the variance of the composite across seeds
(unbiased, ``seeds − 1`` degrees of freedom) times spp is the per-sample variance; the table
gives its mean over the image (directly seen lights left out: pixels brighter than 64× the
photograph's median luminance; and the firefly tail, ``TAIL``, whose variance few seeds
cannot estimate — the plain mean and the median pixel ratio are shown beside it) as a ratio
to ``reference``'s. *Mean vs ground truth*: the
pooled ``importance`` renders against an independent ``reference`` render at ``--gt-spp``:
the share of pixels within 3 standard errors (Student-t band for the seeds' few degrees of
freedom; ≥ 0.99 for unbiased estimators).

    python benchmarks/bench_light_selection.py --worlds heldout:24 --width 160 --write
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from results import cpu_pressure, publish

from arlight.evaluate.worlds import generate, parse_worlds
from arlight.methods import RenderSettings, get_method
from arlight.stats import agreement_fraction
from arlight.synthetic import synthesize

HEADING = ("## Light selection: onepass vs reference per-sample variance on held-out worlds "
           "(issue #35)")
MODES = ("importance", "solid_angle", "mitsuba")
TAIL = 0.005
"""Share of the pixels, per method, left out of the robust variance as its firefly tail."""


def luminance(img: np.ndarray) -> np.ndarray:
    return img @ np.array([0.2126, 0.7152, 0.0722])


def renders(method: str, scene, spp: int, seeds: int, max_depth: int, options: dict
            ) -> tuple[np.ndarray, float]:
    """(seeds, H, W, 3) composites and the mean seconds per render."""
    out, t = [], 0.0
    for s in range(seeds):
        t0 = time.perf_counter()
        lay = get_method(method)(scene, RenderSettings(spp=spp, seed=7 + 101 * s,
                                                       max_depth=max_depth, options=options))
        t += time.perf_counter() - t0
        out.append(lay.composite.astype(np.float64))
    return np.stack(out), t / seeds


def load_world(seed: int, width: int):
    """(generated world, its proxy with the synthetic photograph, the pixels measured: not
    directly seen lights, brighter than 64× the photograph's median luminance)."""
    gw = generate(seed)
    world, proxy = gw.scenes(width)
    photo = synthesize(world, spp=64, seed=1)
    lum = luminance(photo.frame)
    return gw, proxy.with_frame(photo.frame), lum <= 64 * max(float(np.median(lum)), 1e-6)


def per_sample_variance(stack: np.ndarray, spp: int) -> np.ndarray:
    """Per-pixel variance of one sample, (H, W): the variance across the renders of
    ``stack`` (seeds, H, W, 3), channel mean, times their spp."""
    return stack.var(axis=0, ddof=1).mean(axis=-1) * spp


def world_row(seed: int, args) -> dict:
    gw, scene, keep = load_world(seed, args.width)
    row: dict = {"world": gw.name, "describe": gw.describe(), "var": {}, "sec": {}}
    base = {"reproject": False}
    stacks = {}
    for mode in MODES:
        stacks[mode], row["sec"][mode] = renders("onepass", scene, args.spp, args.seeds,
                                                 args.max_depth, {**base, "light_sampling": mode})
    stacks["reference"], row["sec"]["reference"] = renders("reference", scene, args.spp,
                                                           args.seeds, args.max_depth, {})
    var = {name: per_sample_variance(st, args.spp) for name, st in stacks.items()}
    # the firefly tail: pixels among the top TAIL of any method's variance (a few caustic
    # paths, e.g. the sun through a mirror, that 4 seeds cannot estimate: one pixel can hold
    # 85-99 % of an image's summed variance and swing the mean ratio 100-fold between runs)
    tail = np.zeros_like(keep)
    for v in var.values():
        tail |= v >= np.quantile(v[keep], 1 - TAIL)
    body = keep & ~tail
    row["raw"] = {k: float(v[keep].mean()) for k, v in var.items()}
    row["var"] = {k: float(v[body].mean()) for k, v in var.items()}
    ref = np.maximum(var["reference"][keep], 1e-12)
    row["median_px"] = {k: float(np.median(v[keep] / ref)) for k, v in var.items()}
    gt = get_method("reference")(scene, RenderSettings(spp=args.gt_spp, seed=99991,
                                                       max_depth=args.max_depth))
    st = stacks["importance"]
    mean = st.mean(axis=0)
    se = st.std(axis=0, ddof=1) / np.sqrt(args.seeds)
    row["agree"] = agreement_fraction(mean[keep], se[keep], gt.composite[keep],
                                      gt.stderr["composite"][keep], dof_a=args.seeds - 1)
    row["lights_px"] = float(1 - keep.mean())
    return row


def table(rows: list[dict], args) -> list[str]:
    lines = ["| world | variance / reference's: importance | solid_angle (before) | mitsuba "
             "| importance: all pixels | importance: median pixel | before / importance | "
             "mean vs ground truth (3 SE) | s/render importance / reference |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        v, s, raw = r["var"], r["sec"], r["raw"]
        ref = max(v["reference"], 1e-30)
        lines.append(f"| {r['world']} | **{v['importance'] / ref:.2f}** | "
                     f"{v['solid_angle'] / ref:.2f} | {v['mitsuba'] / ref:.2f} | "
                     f"{raw['importance'] / max(raw['reference'], 1e-30):.2f} | "
                     f"{r['median_px']['importance']:.2f} | "
                     f"{v['solid_angle'] / max(v['importance'], 1e-30):.1f}× | "
                     f"{r['agree']:.3f} | {s['importance']:.2f} / {s['reference']:.2f} |")
    ratios = np.array([r["var"]["importance"] / max(r["var"]["reference"], 1e-30)
                       for r in rows])
    old = np.array([r["var"]["solid_angle"] / max(r["var"]["reference"], 1e-30) for r in rows])
    raw = np.array([r["raw"]["importance"] / max(r["raw"]["reference"], 1e-30) for r in rows])
    lines += ["", f"*Variance*: the per-pixel variance of the composite across the seeds × spp, "
              f"averaged over the pixels outside each method's top {100 * TAIL:g} % (its "
              "firefly tail, which few seeds cannot estimate); *all pixels* the plain mean "
              f"(median over worlds {np.median(raw):.2f}, worst {raw.max():.2f}); *median "
              "pixel* the median per-pixel ratio.", "",
              f"**Distribution over {len(rows)} worlds**, per-sample variance / "
              "reference's: importance median "
              f"{np.median(ratios):.2f}, worst {ratios.max():.2f} (worlds ≤ 1.2: "
              f"{int((ratios <= 1.2).sum())}/{len(rows)}); solid_angle (before) median "
              f"{np.median(old):.2f}, worst {old.max():.2f}. Mean agreement with the ground "
              f"truth: lowest {min(r['agree'] for r in rows):.3f}.", "", "Worlds:", ""]
    lines += [f"* {r['world']}: {r['describe']}" for r in rows]
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worlds", default="heldout:24",
                    help="SPLIT:N, SPLIT:N+START or seeds (default heldout:24)")
    ap.add_argument("--width", type=int, default=160, help="image width, pixels")
    ap.add_argument("--spp", type=int, default=16, help="samples per pixel per render")
    ap.add_argument("--seeds", type=int, default=4, help="renders per method (variance)")
    ap.add_argument("--gt-spp", type=int, default=512, help="spp of the reference ground truth")
    ap.add_argument("--max-depth", type=int, default=8)
    ap.add_argument("--write", action="store_true", help="write the section of RESULTS.md")
    args = ap.parse_args()
    pressure = cpu_pressure() or "n/a"
    rows = []
    for seed in parse_worlds(args.worlds):
        rows.append(world_row(seed, args))
        r = rows[-1]
        print(r["world"], {k: round(v / max(r["var"]["reference"], 1e-30), 3)
                           for k, v in r["var"].items()}, round(r["agree"], 3),
              round(r["raw"]["importance"] / max(r["raw"]["reference"], 1e-30), 3), flush=True)
    lines = [HEADING, "",
             f"`python benchmarks/bench_light_selection.py --worlds {args.worlds} --width "
             f"{args.width} --spp {args.spp} --seeds {args.seeds} --gt-spp {args.gt_spp}` — "
             f"max_depth {args.max_depth}, onepass without reprojection. CPU pressure (avg60) "
             f"before / after: {pressure} / {cpu_pressure() or 'n/a'} %.", ""]
    publish("\n".join(lines + table(rows, args)), args.write)


if __name__ == "__main__":
    main()
