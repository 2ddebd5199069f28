"""Benchmark: the per-frame cost of ``onepass`` beside ``reference``'s, stage by stage, before
and after a change of the code (issue #35, item 3: nothing per frame that depends only on the
world).

For each generated world (``--worlds``) at ``--width`` and each method, a child process
prepares the world once and renders ``--frames`` frames of ``--spp`` spp from that state
(as ``sequence`` and the studio do), then renders the scene once more one-shot (prepare +
render, as ``eval`` and the Cycles benchmark do). Reported per frame: the first (it compiles
the kernels), the median of the others, and the one-shot render after them (a kernel-cache
hit unless something about a newly built scene changes the kernels), with onepass's stages
(``time_setup``: tracer and light tables; ``time_trace``). ``--before PATH`` runs the same
children on another checkout's ``src`` (e.g. ``git worktree add /tmp/before <commit>``),
interleaved with this one, so the two are measured under the same load.

    python benchmarks/bench_frame_overhead.py --worlds 1000004,1000007,1000008 \\
        --before /tmp/before --write
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from results import cpu_pressure, publish

HEADING = "## onepass per-frame overhead, before and after (issue #35)"
HERE = Path(__file__).resolve().parent
SRC = HERE.parent / "src"

CHILD = r"""
import json, statistics, sys, time
from arlight.evaluate.worlds import generate
from arlight.methods import RenderSettings, get_method
from arlight.synthetic import synthesize
seed, width, spp, frames, method = (int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]),
                                    int(sys.argv[4]), sys.argv[5])
world, proxy = generate(seed).scenes(width)
photo = synthesize(world, spp=16, seed=1)
scene = proxy.with_frame(photo.frame)
m = get_method(method)
settings = RenderSettings(spp=spp, seed=3, max_depth=8,
                          options={"reproject": False} if method == "onepass" else {})
t0 = time.perf_counter()
state = m.prepare(scene.world, settings)
prep = time.perf_counter() - t0
out = []
for i in range(frames):
    t0 = time.perf_counter()
    lay = m.render(state, scene.view, settings)
    out.append({"seconds": time.perf_counter() - t0,
                **{k: v for k, v in lay.stats.items() if k.startswith("time_")}})
t0 = time.perf_counter()
m(scene, settings)
print("RESULT" + json.dumps({"prepare": prep, "frames": out,
                             "oneshot": time.perf_counter() - t0}))
"""


def child(src: Path, seed: int, args, method: str) -> dict:
    env = {**os.environ, "PYTHONPATH": str(src)}
    cmd = [sys.executable, "-c", CHILD, str(seed), str(args.width), str(args.spp),
           str(args.frames), method]
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True,
                         cwd=str(src.parent)).stdout
    line = next(x for x in out.splitlines() if "RESULT" in x)
    return json.loads(line.split("RESULT", 1)[1])


def summary(r: dict) -> dict:
    rest = r["frames"][1:] or r["frames"]
    med = lambda k: float(np.median([f.get(k, np.nan) for f in rest]))  # noqa: E731
    return {"first": r["frames"][0]["seconds"], "steady": med("seconds"),
            "setup": med("time_setup"), "trace": med("time_trace"), "oneshot": r["oneshot"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worlds", default="1000004,1000007,1000008",
                    help="generated world seeds (default: three held-out worlds)")
    ap.add_argument("--width", type=int, default=640, help="image width, pixels")
    ap.add_argument("--spp", type=int, default=1, help="samples per pixel per frame")
    ap.add_argument("--frames", type=int, default=4, help="frames per prepared state")
    ap.add_argument("--before", type=Path, default=None,
                    help="another checkout whose src/ is measured as 'before'")
    ap.add_argument("--write", action="store_true", help="write the section of RESULTS.md")
    args = ap.parse_args()
    from arlight.evaluate.worlds import generate, parse_worlds

    versions = {"after": SRC}
    if args.before is not None:
        versions = {"before": args.before / "src", **versions}
    pressure = cpu_pressure() or "n/a"
    rows = []
    for seed in parse_worlds(args.worlds):
        for method in ("onepass", "reference"):
            for label, src in versions.items():
                if method == "reference" and label == "before":
                    continue  # reference did not change
                s = summary(child(src, seed, args, method))
                rows.append((f"world-{seed}", method, label, s))
                print(rows[-1], flush=True)
    lines = [HEADING, "",
             f"`python benchmarks/bench_frame_overhead.py --worlds {args.worlds} --width "
             f"{args.width} --spp {args.spp} --frames {args.frames}"
             f"{' --before ' + str(args.before) if args.before else ''}` — one child process "
             "per (world, method, code), prepared once; seconds. *first*: the first frame "
             "(kernels compiled); *steady*: median of the later frames of the prepared state, "
             "with onepass's stages *setup* (tracer, light tables) and *trace*; *one-shot*: "
             "prepare + render of the same scene once more (as eval and the Cycles benchmark "
             "render), a kernel-cache hit unless a newly built scene changes the kernels. "
             f"CPU pressure (avg60) before / after: {pressure} / {cpu_pressure() or 'n/a'} %.",
             "", "| world | method | code | first | steady | setup | trace | one-shot |",
             "|---|---|---|---|---|---|---|---|"]
    for world, method, label, s in rows:
        lines.append(f"| {world} | {method} | {label} | {s['first']:.2f} | {s['steady']:.3f} "
                     f"| {s['setup']:.3f} | {s['trace']:.3f} | {s['oneshot']:.2f} |")
    lines += ["", "Worlds:", ""]
    lines += [f"* world-{seed}: {generate(seed).describe()}"
              for seed in parse_worlds(args.worlds)]
    publish("\n".join(lines), args.write)


if __name__ == "__main__":
    main()
