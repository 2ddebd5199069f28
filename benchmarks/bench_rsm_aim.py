"""Aimed light maps and VPL selection by importance for ``dir`` (issue #33): tuning and A/B.

* ``--tune``: on training worlds (seeds < 1 000 000) every configuration of :data:`CONFIGS`
  (RSM aims and VPL importance) of this tree, same run, one ground truth per world; prints
  the median changed-pixel PSNR per configuration (the defaults of ``dir`` are chosen from
  this table).
* default: A/B of ``dir`` on held-out worlds, this tree (defaults) against the baseline
  commit (a git worktree, its ``src`` on ``PYTHONPATH``), each side in its own process,
  world by world in the same run; the RESULTS.md section "Aimed light maps (issue #33)".

    python benchmarks/bench_rsm_aim.py --tune [--worlds training:4] [--width 80]
    python benchmarks/bench_rsm_aim.py --baseline-src /tmp/base-rsm/src \\
        [--worlds heldout:8] [--width 160] [--write]

PSNR on display values over the pixels the insertion changes
(``arlight.evaluate.metrics.changed_region``); ground truth 256 spp from the shared cache.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
from pathlib import Path

HEADING = "## Aimed light maps (issue #33)"

CONFIGS: dict[str, dict] = {
    "unaimed, by flux": {"aim_object": 0.0, "aim_view": 0.0, "vpl_importance": 0.0},
    "object 1, β 0": {"aim_object": 1.0, "aim_view": 0.0, "vpl_importance": 0.0},
    "object 1, view 0.25, β 4": {"aim_object": 1.0, "aim_view": 0.25, "vpl_importance": 4.0},
    "object 1, view 0.25, β 16": {"aim_object": 1.0, "aim_view": 0.25,
                                  "vpl_importance": 16.0},
    "object 4, view 0.25, β 4": {"aim_object": 4.0, "aim_view": 0.25, "vpl_importance": 4.0},
}
"""Configurations compared by ``--tune`` (options of ``dir``)."""


def worker(args) -> None:
    """Evaluate ``dir`` on one world with the package on ``sys.path``, once per
    configuration of ``--configs`` (JSON: name → options); append JSON lines to ``--cells``."""
    from arlight.evaluate.harness import EvalConfig, run_evaluation

    configs = json.loads(args.configs)
    with open(args.cells, "a") as f:
        for name, opts in configs.items():
            cfg = EvalConfig(methods=["dir"], scenes=[], quick=False, spp=16, gt_spp=256,
                             repeats=args.repeats, worlds=[args.world],
                             world_width=args.width,
                             options={f"dir.{k}": v for k, v in opts.items()})
            res = run_evaluation(cfg, log=lambda s: print(s, flush=True))
            for c in res.cells:
                f.write(json.dumps({
                    "scene": c.scene, "config": name, "ok": c.ok, "error": c.error,
                    "seconds": c.seconds, "vpls_on_object": c.stats.get("vpls_on_object",
                                                                        math.nan),
                    "changed_psnr": c.metrics.get("changed_psnr", math.nan),
                    "psnr": c.metrics.get("psnr", math.nan)}) + "\n")


def run_side(src: Path, seed: int, args, configs: dict, cells: Path) -> None:
    """One world in a fresh process importing the package from ``src``."""
    env = dict(os.environ, PYTHONPATH=str(src))
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", "--world", str(seed),
           "--width", str(args.width), "--repeats", str(args.repeats), "--cells", str(cells),
           "--configs", json.dumps(configs)]
    subprocess.run(cmd, env=env, check=True)


def read(path: Path) -> list[dict]:
    return [json.loads(x) for x in path.read_text().splitlines()] if path.is_file() else []


def _median(xs: list[float]) -> float:
    xs = [x for x in xs if math.isfinite(x)]
    return statistics.median(xs) if xs else math.nan


def tune_table(cells: list[dict]) -> str:
    """Median changed-pixel PSNR per configuration and its median gain over the first."""
    by = {(c["scene"], c["config"]): c for c in cells if c["ok"]}
    scenes = sorted({s for s, _ in by})
    first = next(iter(CONFIGS))
    lines = ["| configuration | worlds | PSNR changed, median (dB) | Δ vs unaimed, median / "
             "worst (dB) | VPLs on the object, median | frame time, median (s) |",
             "|---|---|---|---|---|---|"]
    for name in CONFIGS:
        got = [s for s in scenes if (s, name) in by and (s, first) in by]
        d = [by[(s, name)]["changed_psnr"] - by[(s, first)]["changed_psnr"] for s in got]
        lines.append(f"| {name} | {len(got)} | "
                     f"{_median([by[(s, name)]['changed_psnr'] for s in got]):.2f} | "
                     f"{_median(d):+.2f} / {min(d, default=math.nan):+.2f} | "
                     f"{_median([by[(s, name)]['vpls_on_object'] for s in got]):.0f} | "
                     f"{_median([by[(s, name)]['seconds'] for s in got]):.3f} |")
    return "\n".join(lines)


def ab_section(base: list[dict], head: list[dict], args, pressure: str, tune: str) -> str:
    """The RESULTS.md section: per world, ``dir``'s changed-pixel PSNR base → head."""
    b = {c["scene"]: c for c in base if c["ok"]}
    h = {c["scene"]: c for c in head if c["ok"]}
    both = sorted(set(b) & set(h))
    d = [h[s]["changed_psnr"] - b[s]["changed_psnr"] for s in both]
    dall = [h[s]["psnr"] - b[s]["psnr"] for s in both]
    ratio = [h[s]["seconds"] / b[s]["seconds"] for s in both]
    lines = [HEADING, "",
             f"`benchmarks/bench_rsm_aim.py --worlds {args.worlds} --width {args.width}`: "
             "`dir` with aimed RSMs (texels on the virtual objects' sphere and on the part of "
             "the scene the camera sees, flux per texel from the mixture density) and VPLs "
             "picked by importance (flux × (1 + β·proximity), weights 1/π) against `dir` at "
             f"the baseline commit {args.baseline}, both at their defaults, each side in its "
             f"own process, world by world in one run; {len(both)} held-out worlds. Ground "
             "truth 256 spp (shared cache). PSNR on display values over the pixels the "
             f"insertion changes. CPU pressure (PSI some avg60) at the end: {pressure} %.", "",
             "| worlds | Δ PSNR changed, median / worst (dB) | Δ PSNR all, median (dB) | "
             "PSNR changed base → head, median (dB) | frame time head / base, median | "
             "VPLs on the object (head), median |",
             "|---|---|---|---|---|---|",
             f"| {len(both)} | {_median(d):+.2f} / {min(d, default=math.nan):+.2f} | "
             f"{_median(dall):+.2f} | {_median([b[s]['changed_psnr'] for s in both]):.2f} → "
             f"{_median([h[s]['changed_psnr'] for s in both]):.2f} | {_median(ratio):.2f} | "
             f"{_median([h[s]['vpls_on_object'] for s in both]):.0f} |", "",
             "| world | PSNR changed base (dB) | head (dB) | Δ (dB) | VPLs on the object |",
             "|---|---|---|---|---|"]
    for s in both:
        lines.append(f"| {s} | {b[s]['changed_psnr']:.2f} | {h[s]['changed_psnr']:.2f} | "
                     f"{h[s]['changed_psnr'] - b[s]['changed_psnr']:+.2f} | "
                     f"{h[s]['vpls_on_object']:.0f} |")
    if tune:
        lines += ["", "Constants chosen on training worlds (`--tune`, same run per world):",
                  "", tune]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tune", action="store_true", help="compare CONFIGS on training worlds")
    ap.add_argument("--baseline", default="2f93175", help="baseline commit (for the text)")
    ap.add_argument("--baseline-src", type=Path, default=Path("/tmp/base-rsm/src"),
                    help="the baseline's src folder (a git worktree of --baseline)")
    ap.add_argument("--worlds", default=None, help="default training:4 (--tune), heldout:8")
    ap.add_argument("--width", type=int, default=160, help="image width, px (4:3)")
    ap.add_argument("--repeats", type=int, default=1, help="timed frames per cell")
    ap.add_argument("--out", type=Path, default=Path("rsm-aim-results"),
                    help="folder for the JSON lines (resumed when present)")
    ap.add_argument("--tune-table", type=Path, default=None,
                    help="a saved --tune table (markdown) to append to the section")
    ap.add_argument("--write", action="store_true", help="store the section in RESULTS.md")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--world", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--cells", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--configs", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        worker(args)
        return
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
    from results import cpu_pressure, publish

    from arlight.evaluate.worlds import parse_worlds

    head_src = Path(__file__).resolve().parents[1] / "src"
    args.worlds = args.worlds or ("training:4" if args.tune else "heldout:8")
    seeds = parse_worlds(args.worlds)
    args.out.mkdir(parents=True, exist_ok=True)
    if args.tune:
        if any(s >= 1_000_000 for s in seeds):
            sys.exit("bench_rsm_aim: --tune runs on training worlds only (seeds < 1 000 000)")
        path = args.out / "tune.jsonl"
        for seed in seeds:
            if not any(c["scene"] == f"world-{seed}" for c in read(path)):
                run_side(head_src, seed, args, CONFIGS, path)
        table = tune_table(read(path))
        print(table + f"\n\nCPU pressure (PSI some avg60): {cpu_pressure() or 'n/a'} %")
        (args.out / "tune.md").write_text(table + "\n")
        return
    files = {"base": args.out / "base.jsonl", "head": args.out / "head.jsonl"}
    for seed in seeds:
        for side, src in (("base", args.baseline_src), ("head", head_src)):
            if not any(c["scene"] == f"world-{seed}" for c in read(files[side])):
                run_side(src, seed, args, {"default": {}}, files[side])
    tune = args.tune_table.read_text().strip() if args.tune_table else ""
    publish(ab_section(read(files["base"]), read(files["head"]), args,
                       cpu_pressure() or "n/a", tune), args.write)


if __name__ == "__main__":
    main()
