"""Every method on held-out generated worlds: the claims of RESULTS.md restated as
distributions (issue #30).

Runs ``arlight.evaluate.harness.run_evaluation`` on ``--worlds`` (default ``heldout:24``) at
``--width`` (default 160 px, 4:3) with every registered method, the ground truth at 256 spp
(the cache is shared with ``arlight eval``), and the equal-time ladder of ``onepass``; writes
the full report (``--report``, default ``heldout-report/``, not committed) and the
RESULTS.md section:

* the grand comparison as distributions (median / 10th-percentile world / worst) per method,
  over all worlds and per world class, with the equal-time comparison against ``onepass``;
* ``onepass`` against ``reference`` at equal error: per world, the time ``onepass`` needs to
  reach the PSNR of ``reference``'s frame (log-linear interpolation on its ladder), as a
  ratio of ``reference``'s frame time;
* ``dic`` against ``onepass`` at equal time (the Δ PSNR row of ``dic``).

    python benchmarks/bench_heldout.py [--worlds heldout:24] [--width 160] [--write]
    python benchmarks/bench_heldout.py --load results.pkl --write   # section from a saved run

The machine is shared: every time is a same-run measurement, the CPU pressure is printed
with the section, and frame times are medians over ``--repeats`` warm frames.
"""

from __future__ import annotations

import argparse
import math
import pickle
import statistics
from dataclasses import replace
from pathlib import Path

import numpy as np
from results import cpu_pressure, publish

from arlight.evaluate.distribution import method_rows, spread
from arlight.evaluate.harness import EvalConfig, EvalResults, run_evaluation
from arlight.evaluate.report import WORLD_HEADER, world_table, write_report
from arlight.evaluate.worlds import GENERATOR_VERSION, parse_worlds
from arlight.methods import available_methods
from arlight.methods.spec import parse_option_pairs

HEADING = "## Held-out worlds: every method, distributions and equal time (issue #30)"
REAL_TIME = ("dlpv", "dir", "dvct", "ibl", "prt", "probeless", "nearfield")


def onepass_time_to(ladder, psnr: float) -> float:
    """Seconds ``onepass`` needs to reach ``psnr`` on its ladder: the first rung at or above
    it, interpolated log-linearly in time from the rung below (NaN when the ladder never
    gets there; the first rung's time when it starts above)."""
    pts = sorted(ladder, key=lambda p: p.spp)
    for i, p in enumerate(pts):
        if p.metrics["psnr"] >= psnr:
            if i == 0:
                return p.seconds
            q = pts[i - 1]
            f = (psnr - q.metrics["psnr"]) / (p.metrics["psnr"] - q.metrics["psnr"])
            return math.exp(math.log(q.seconds) + f * (math.log(p.seconds)
                                                       - math.log(q.seconds)))
    return math.nan


def reference_ratio(results: EvalResults) -> list[tuple[str, float, float, float]]:
    """Per world: (world, reference's frame time, onepass's time to its PSNR, ratio
    reference / onepass; > 1: onepass is faster at equal error)."""
    out = []
    for c in results.cells:
        if c.method != "reference" or not c.ok or c.scene not in results.ladders:
            continue
        t = onepass_time_to(results.ladders[c.scene], c.metrics["psnr"])
        out.append((c.scene, c.seconds, t, c.seconds / t if t == t else math.nan))
    return out


def _fmt3(sp, fmt="{:.2f}") -> str:
    return " / ".join(fmt.format(v) for v in (sp.median, sp.p10, sp.worst)) if sp.n else "—"


def section(results: EvalResults, pressure: str, excluded: dict[str, str] | None = None,
            generator: str | None = None) -> str:
    """The RESULTS.md section; ``excluded`` maps world names left out of every table to
    the reason (stated in the section)."""
    cfg = results.config
    excluded = excluded or {}
    if excluded:
        results = EvalResults(config=cfg, seconds_total=results.seconds_total,
                              cells=[c for c in results.cells if c.scene not in excluded],
                              scenes={k: v for k, v in results.scenes.items()
                                      if k not in excluded},
                              ladders={k: v for k, v in results.ladders.items()
                                       if k not in excluded})
    classes = results.world_classes()
    generator = generator or next(iter(results.scenes.values())).get(
        "generator", str(GENERATOR_VERSION))
    seeds = [int(s.removeprefix("world-")) for s in classes]
    rows = method_rows(results.cells, classes)
    splits = "/".join(sorted({results.scenes[s]["split"] for s in classes}))
    lines = [HEADING, "",
             f"{len(seeds)} {splits} worlds (seeds {min(seeds)}–{max(seeds)}, generator "
             f"v{generator}; held-out worlds are never tuned on — constants are "
             f"chosen on training seeds < 1 000 000, docs/testing.md#tuned-constants): "
             + ", ".join(f"{k} {list(classes.values()).count(k)}"
                         for k in sorted(set(classes.values())))
             + f". {results.scenes[next(iter(classes))]['resolution']}, ground truth "
             f"{cfg.gt_spp} spp (Mitsuba), methods at {cfg.spp} spp where they sample, frame "
             f"time = median of {cfg.repeats} warm frame(s) after a warm-up, world prepared "
             f"once. CPU pressure (PSI some avg60) at the end: {pressure or 'n/a'} % — the "
             "machine was shared with other jobs, so absolute times are inflated; the "
             "equal-time comparisons are per world, same run.", "",
             "Each entry: median / 10th-percentile world / worst world. Δ vs onepass = the "
             "method's PSNR minus that of the best onepass frame of the same world that took "
             "at most the method's frame time (docs/evaluation.md).", ""]
    lines += [f"Left out: {name} — {why}." for name, why in excluded.items()]
    lines += [""] if excluded else []
    for group in dict.fromkeys(r.group for r in rows):
        mine = [r for r in rows if r.group == group]
        lines += [f"### {group} worlds", "", "| " + " | ".join(WORLD_HEADER) + " |",
                  "|" + "---|" * len(WORLD_HEADER)]
        lines += ["| " + " | ".join(r) + " |" for r in world_table(mine)]
        lines.append("")
    ref = reference_ratio(results)
    if ref:
        ratios = [r[3] for r in ref]
        sp = spread(ratios)
        lines += ["### onepass vs reference at equal error", "",
                  "Per world: reference's frame time over the time onepass needs to reach "
                  "reference's PSNR (its ladder, log-linear interpolation; > 1: onepass is "
                  f"faster). Median / 10th percentile / worst: {_fmt3(sp)} over {sp.n} "
                  f"worlds; onepass faster on {sum(r > 1 for r in ratios if r == r)} of "
                  f"{len(ratios)} (never reached reference's PSNR on its ladder: "
                  f"{sum(r != r for r in ratios)}).", "",
                  "| world | reference frame | onepass to equal PSNR | ratio |",
                  "|---|---|---|---|"]
        lines += [f"| {w} | {a * 1e3:.0f} ms | {b * 1e3:.0f} ms | {r:.2f} |"
                  for w, a, b, r in ref]
        lines.append("")
    dic = next((r for r in rows if r.method == "dic" and r.group == "all"), None)
    if dic and dic.compared:
        lines += ["### dic vs onepass at equal time", "",
                  f"dic beats onepass at its own frame time on {dic.wins} of {dic.compared} "
                  f"held-out worlds; Δ PSNR median / 10th percentile / worst "
                  f"{_fmt3(dic.equal_time_delta, '{:+.2f}')} dB (changed pixels: "
                  f"{_fmt3(dic.equal_time_changed_delta, '{:+.2f}')} dB).", ""]
    rt = [r for r in rows if r.group == "all" and r.method in REAL_TIME and r.ran]
    if rt:
        order = sorted(rt, key=lambda r: -r.psnr.median)
        lines += ["### The real-time methods (grand comparison)", "",
                  "Ordered by median PSNR: " + ", ".join(
                      f"{r.method} {r.psnr.median:.2f} dB ({r.ran} worlds, "
                      f"{r.seconds.median * 1e3:.0f} ms)" for r in order) + ".", ""]
    return "\n".join(lines)


def run_worlds(args) -> EvalResults:
    """Evaluate world by world, pickling the results so far after each (``--save``), so an
    interrupted run keeps what it measured and ``--resume`` continues it."""
    seeds = parse_worlds(args.worlds)
    cfg = EvalConfig(methods=args.methods.split(","), scenes=[], quick=False, spp=16,
                     gt_spp=256, repeats=args.repeats, worlds=seeds, world_width=args.width,
                     equal_time=True,
                     options=parse_option_pairs(args.option, "[method.]key=value"))
    results = EvalResults(config=cfg, cells=[])
    if args.resume and args.load and args.load.is_file():
        with open(args.load, "rb") as f:
            results = pickle.load(f)
        results.config = cfg
    for seed in seeds:
        if f"world-{seed}" in results.scenes:
            continue
        one = run_evaluation(replace(cfg, worlds=[seed]), log=print)
        for c in one.cells:
            c.images = {}
        results.cells += one.cells
        results.scenes.update(one.scenes)
        results.ladders.update(one.ladders)
        results.seconds_total += one.seconds_total
        if args.save:
            with open(args.save, "wb") as f:
                pickle.dump(results, f)
    return results


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worlds", default="heldout:24")
    ap.add_argument("--width", type=int, default=160)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--methods", default=",".join(available_methods()))
    ap.add_argument("--report", type=Path, default=Path("heldout-report"))
    ap.add_argument("--option", action="append", default=[], help="method option "
                    "METHOD.KEY=VALUE, as `arlight eval --option` (repeatable)")
    ap.add_argument("--load", type=Path, help="a pickled EvalResults of an earlier run")
    ap.add_argument("--save", type=Path, help="pickle the EvalResults here")
    ap.add_argument("--resume", action="store_true", help="with --load and --save: run only "
                    "the worlds the saved run lacks")
    ap.add_argument("--exclude", action="append", default=[], metavar="SEED=REASON",
                    help="leave a world out of the tables, with the reason stated")
    ap.add_argument("--generator", help="generator version of a loaded run (default: as "
                    "recorded, else the current one)")
    ap.add_argument("--write", action="store_true", help="store the section in RESULTS.md")
    args = ap.parse_args()
    if args.load and not args.resume:
        with open(args.load, "rb") as f:
            results = pickle.load(f)
    else:
        results = run_worlds(args)
    write_report(results, args.report)
    excluded = dict(x.split("=", 1) for x in args.exclude)
    excluded = {f"world-{k}": v for k, v in excluded.items()}
    publish(section(results, cpu_pressure(), excluded, args.generator), args.write)
    times = [c.seconds for c in results.cells if c.ok]
    print(f"{len(results.cells)} cells, median frame {statistics.median(times) * 1e3:.0f} ms, "
          f"{np.isfinite(times).sum()} timed")


if __name__ == "__main__":
    main()
