"""A/B of methods on held-out worlds: this tree against an earlier commit, same run (issue #33).

Issue #33's acceptance compares each real-time method with *today's code as the A/B peer*:
on the held-out worlds, the median gain of PSNR on the pixels the insertion changes, and
whether the method beats ``onepass`` at its own frame time. This script runs both sides in
one invocation, world by world and side by side (so machine load drifts over both alike):

* the baseline from a git worktree of ``--baseline`` (created under
  ``$ARLIGHT_CACHE/ab-<rev>``, reused), imported through ``PYTHONPATH``;
* the current tree, with ``onepass``'s equal-time ladder (the baseline skips it: only its
  PSNR is compared).

Each side runs in its own process (``--worker``), so neither imports the other's modules;
cells are exchanged as JSON lines. The ground-truth photos come from the shared cache of
``arlight eval`` (identical worlds give identical photos on both sides).

    python benchmarks/bench_ab.py --baseline 2f93175 [--worlds heldout:24] [--width 160]
        [--methods dlpv,dir,dvct,ibl,prt] [--out ab-results] [--write]

``--out`` keeps ``base.jsonl`` / ``head.jsonl``; a second invocation resumes (worlds
already in both files are not run again).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

HEADING = "## Real-time methods against the previous code on held-out worlds (issue #33)"
METHODS = "dlpv,dir,dvct,ibl,prt"
FIELDS = ("psnr", "changed_psnr", "flip", "onepass_at_time_psnr",
          "onepass_at_time_changed_psnr", "onepass_at_time_spp")


def cache_root() -> Path:
    """``$ARLIGHT_CACHE`` or ``~/.cache/arlight`` (as the evaluation harness)."""
    return Path(os.environ.get("ARLIGHT_CACHE", Path.home() / ".cache" / "arlight"))


def baseline_tree(rev: str) -> Path:
    """A detached git worktree of ``rev`` (created once, reused); its ``src`` is the
    baseline's package."""
    repo = Path(__file__).resolve().parents[1]
    full = subprocess.run(["git", "-C", str(repo), "rev-parse", "--verify", f"{rev}^{{commit}}"],
                          capture_output=True, text=True)
    if full.returncode:
        sys.exit(f"bench_ab: --baseline {rev!r} is not a commit of {repo}")
    sha = full.stdout.strip()
    tree = cache_root() / f"ab-{sha[:12]}"
    if not (tree / "src" / "arlight").is_dir():
        subprocess.run(["git", "-C", str(repo), "worktree", "add", "--detach", str(tree), sha],
                       check=True, capture_output=True)
    return tree


def worker(args) -> None:
    """Evaluate one world with the package found on ``sys.path`` and append its cells to
    ``--cells`` as JSON lines."""
    from arlight.evaluate.harness import EvalConfig, run_evaluation

    cfg = EvalConfig(methods=args.methods.split(","), scenes=[], quick=False, spp=16,
                     gt_spp=args.gt_spp, repeats=args.repeats, worlds=[args.world],
                     world_width=args.width, equal_time=args.equal_time)
    res = run_evaluation(cfg, log=lambda s: print(s, flush=True))
    classes = res.world_classes()
    with open(args.cells, "a") as f:
        for c in res.cells:
            f.write(json.dumps({
                "scene": c.scene, "method": c.method, "class": classes.get(c.scene, ""),
                "ok": c.ok, "skipped": c.skipped, "error": c.error,
                "seconds": c.seconds,
                **{k: c.metrics.get(k, math.nan) for k in FIELDS}}) + "\n")


def read_cells(path: Path) -> dict[tuple[str, str], dict]:
    """(scene, method) → cell of a JSON-lines file (the last line wins)."""
    if not path.is_file():
        return {}
    cells = {}
    for line in path.read_text().splitlines():
        c = json.loads(line)
        cells[(c["scene"], c["method"])] = c
    return cells


def run_side(src: Path, seed: int, args, cells: Path, equal_time: bool) -> None:
    """One world on one side, in a fresh process importing the package from ``src``."""
    env = dict(os.environ, PYTHONPATH=str(src))
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", "--world", str(seed),
           "--methods", args.methods, "--width", str(args.width),
           "--repeats", str(args.repeats), "--gt-spp", str(args.gt_spp),
           "--cells", str(cells)]
    subprocess.run(cmd + (["--equal-time"] if equal_time else []), env=env, check=True)


def _median(xs: list[float]) -> float:
    xs = [x for x in xs if math.isfinite(x)]
    return statistics.median(xs) if xs else math.nan


def per_world_table(caption: str, head: dict, methods: list[str], scenes: list[str],
                    cell: Callable[[str, str], str]) -> str:
    """A Markdown table: ``caption``, then per world its class and ``cell(world, method)``
    per method."""
    lines = [caption, "", "| world | class | " + " | ".join(methods) + " |",
             "|---|---|" + "---|" * len(methods)]
    for s in scenes:
        cls = next((c["class"] for (sc, _), c in head.items() if sc == s), "")
        lines.append(f"| {s} | {cls} | " + " | ".join(cell(s, m) for m in methods) + " |")
    return "\n".join(lines)


def equal_time_cell(c: dict) -> str:
    """A head cell's PSNR (whole frame, dB) and frame time (ms), and the best ``onepass``
    frame at most that slow (its PSNR and spp; ``none`` when no onepass frame was that
    fast); bold when the method wins."""
    if not c.get("ok"):
        return "—"
    op = c["onepass_at_time_psnr"]
    one = "none" if math.isnan(op) else f"{op:.1f} dB, {c['onepass_at_time_spp']:.0f} spp"
    text = f"{c['psnr']:.1f} dB / {c['seconds'] * 1e3:.0f} ms → {one}"
    return f"**{text}**" if not c["psnr"] <= op else text


def section(base: dict, head: dict, args, pressure: str) -> str:
    """The RESULTS.md section: per method, the worlds both sides ran, the median and worst
    gain of changed-pixel PSNR, and head's wins against ``onepass`` at equal time."""
    methods = args.methods.split(",")
    scenes = sorted({s for s, _ in head})
    lines = [args.heading or HEADING, "",
             f"`benchmarks/bench_ab.py --baseline {args.baseline} --worlds {args.worlds} "
             f"--width {args.width} --repeats {args.repeats} --gt-spp {args.gt_spp}`: "
             + ("each method of this tree against the same method at "
                f"commit {args.baseline} (the code before this issue's changes), on "
                f"{len(scenes)} held-out worlds, both sides world by world. " if base else
                f"each method of this tree on {len(scenes)} held-out worlds against onepass "
                "at equal time (no baseline side in this run). ")
             +
             f"Ground truth {args.gt_spp} spp (Mitsuba, shared cache), methods at 16 spp "
             "where they sample. PSNR on display values; *changed* = the pixels the insertion "
             "changes "
             "(`arlight.evaluate.metrics.changed_region`). Wins vs onepass: the method's "
             "PSNR above the best `onepass` frame that took at most the method's frame time "
             "(or `onepass` had no frame that fast). CPU pressure (PSI some avg60) at the "
             f"end: {pressure} %."
             + (" The baseline side ran in an earlier invocation (`--sides base`, the machine "
                "then shared with other jobs): its frame times come from another load, so "
                "the time ratio is indicative only; PSNR does not depend on the load."
                if args.separate_runs else ""), "",
             "| method | worlds (both ran) | Δ PSNR changed, median / worst (dB) | Δ PSNR "
             "all, median (dB) | gains ≥ 1 dB changed | PSNR changed base → head, median "
             "(dB) | frame time head / base, median | wins vs onepass at equal time |",
             "|---|---|---|---|---|---|---|---|"]
    for m in methods:
        both = [s for s in scenes if head.get((s, m), {}).get("ok")
                and base.get((s, m), {}).get("ok")]
        dch = [head[(s, m)]["changed_psnr"] - base[(s, m)]["changed_psnr"] for s in both]
        dall = [head[(s, m)]["psnr"] - base[(s, m)]["psnr"] for s in both]
        ratio = [head[(s, m)]["seconds"] / base[(s, m)]["seconds"] for s in both]
        ran = [s for s in scenes if head.get((s, m), {}).get("ok")]
        wins = sum(not (head[(s, m)]["psnr"] <= head[(s, m)]["onepass_at_time_psnr"])
                   for s in ran)
        if not both:
            lines.append(f"| {m} | 0 | — | — | — | — | — | {wins}/{len(ran)} |")
            continue
        lines.append(
            f"| {m} | {len(both)} | {_median(dch):+.2f} / {min(dch):+.2f} | "
            f"{_median(dall):+.2f} | {sum(d >= 1 for d in dch)}/{len(both)} | "
            f"{_median([base[(s, m)]['changed_psnr'] for s in both]):.2f} → "
            f"{_median([head[(s, m)]['changed_psnr'] for s in both]):.2f} | "
            f"{_median(ratio):.2f} | {wins}/{len(ran)} |")
    if not base:  # a head-only run (`--sides head` into a fresh --out): equal time only
        lines += ["", per_world_table(
            "Per world: method PSNR / frame time → onepass at that time (PSNR, spp); "
            "**bold**: the method wins.", head, methods, scenes,
            lambda s, m: equal_time_cell(head.get((s, m), {})))]
    else:
        def delta(s: str, m: str) -> str:
            h, b = head.get((s, m), {}), base.get((s, m), {})
            return (f"{h['changed_psnr'] - b['changed_psnr']:+.2f}"
                    if h.get("ok") and b.get("ok") else "—")
        lines += ["", per_world_table("Per world (Δ changed-pixel PSNR, dB; `—`: not run on "
                                      "both sides):", head, methods, scenes, delta)]
    skipped = sorted({f"{m}: {c['skipped']}" for (s, m), c in head.items() if c["skipped"]})
    if skipped:
        lines += ["", "Skipped (the method does not support the world): "
                  + "; ".join(skipped) + "."]
    if args.note:
        lines += ["", args.note.read_text(encoding="utf-8").strip()]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", default="2f93175", help="commit of the A side (default "
                    "2f93175, the code before issue #33's method changes)")
    ap.add_argument("--worlds", default="heldout:24", help="worlds (as `arlight eval "
                    "--worlds`; default heldout:24)")
    ap.add_argument("--width", type=int, default=160, help="image width, px (4:3)")
    ap.add_argument("--methods", default=METHODS, help=f"comma-separated (default {METHODS})")
    ap.add_argument("--repeats", type=int, default=1, help="timed frames per cell")
    ap.add_argument("--gt-spp", type=int, default=256, help="samples per pixel of the ground "
                    "truth (its noise adds the same expected squared error to every method, "
                    "so which of two methods is closer is unbiased at any spp)")
    ap.add_argument("--out", type=Path, default=Path("ab-results"),
                    help="folder for base.jsonl / head.jsonl (resumed when present)")
    ap.add_argument("--sides", default="base,head", help="which sides to run now (default "
                    "both, interleaved per world; `base` alone fills the baseline's cells ahead "
                    "of time — its frame times are then not from the same run)")
    ap.add_argument("--separate-runs", action="store_true", help="say in the section that "
                    "the two sides' cells come from separate invocations (`--sides`)")
    ap.add_argument("--write", action="store_true", help="store the section in RESULTS.md")
    ap.add_argument("--heading", help="the section's `## ` heading (default: the shared "
                    "section of every method; give one to publish a method's run apart)")
    ap.add_argument("--note", type=Path, help="a file whose text ends the section")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--world", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--cells", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--equal-time", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        worker(args)
        return
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
    from results import cpu_pressure, publish

    from arlight.evaluate.worlds import parse_worlds

    base_src = baseline_tree(args.baseline) / "src"
    head_src = Path(__file__).resolve().parents[1] / "src"
    args.out.mkdir(parents=True, exist_ok=True)
    files = {"base": args.out / "base.jsonl", "head": args.out / "head.jsonl"}
    for seed in parse_worlds(args.worlds):
        name = f"world-{seed}"
        for side, src in (("base", base_src), ("head", head_src)):
            done = any(s == name for s, _ in read_cells(files[side]))
            if side not in args.sides.split(",") or done:
                continue
            print(f"== {name} ({side})", flush=True)
            run_side(src, seed, args, files[side], equal_time=side == "head")
    text = section(read_cells(files["base"]), read_cells(files["head"]), args,
                   cpu_pressure() or "n/a")
    publish(text, args.write)


if __name__ == "__main__":
    main()
