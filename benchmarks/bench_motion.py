"""Benchmark: frame time of the interactive methods while the virtual object moves rigidly
every frame, or the lamp moves every frame, vs while nothing moves (issue #32, incremental
pose and light updates).

On the demo scene at 640×480 each method (dlpv, dir, dvct, ibl, prt, probeless, nearfield
and onepass at 1 spp),
in a process of its own started by this run (no other method's scenes or kernels alive),
prepares the world once, renders warm-up frames of both kinds (kernels compiled), then
``--rounds`` interleaved pairs: a moving frame (the bunny a further 1 cm along a circle on
the table and turned 5° about +y, a transform no frame used before) and a still frame (that
pose again: nothing moved). Then ``--rounds`` frames with the lamp moving: the area lamp
1 cm further along +x and its radiance 1 % warmer each frame (``BaseMethod.relight`` then a
render; the time is both). Reported per method: the median wall time of each kind
(``Layers.stats["seconds"]``, pose included), their ratio (target ≤ 1.3), the moving
frames' mean wall time and median ``time_pose``, the lamp frames' median and their ratio to
still; with the machine's ``uptime`` load and CPU pressure at the end of the run. The
bitwise equality of moved and relit frames to a fresh preparation is tested in
tests/methods/test_pose_incremental.py and tests/methods/test_relight.py, not here.

    .venv/bin/python benchmarks/bench_motion.py [--rounds 9] [--methods dlpv,dir] [--write]
        [--merge]

``--merge`` keeps the other methods' rows of the section in RESULTS.md (from an earlier run,
its load line quoted) when ``--methods`` measures a few. ``--write`` keeps the notes written
below the section's generated part (after its load line) by earlier runs.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from results import RESULTS, cpu_pressure, publish

from arlight.demo import DEMO_DIR
from arlight.methods import RenderSettings, get_method
from arlight.scene.load import load_scene

HEADING = "## Interactive methods while the virtual object moves (issue #32)"
HERE = Path(__file__).resolve().parent
METHODS = ["dlpv", "dir", "dvct", "ibl", "prt", "probeless", "nearfield", "onepass"]
NO_LIGHT_ROW = {"nearfield": "its VALs come from its own light server's capture of the world: "
                "a new lamp prepares again (a server update goes through with_light)"}
"""Methods without the lamp row, and why."""
STEP_M = 0.01
"""Distance the bunny moves along its circle per moving frame, metres."""
TURN_DEG = 5.0
"""Rotation of the bunny about +y per moving frame, degrees."""
RADIUS_M = 0.05
"""Radius of the bunny's circle on the table, metres."""
BEFORE = "dlpv 3.9×, dir 1.1×, dvct 5.5×, ibl 6.9×, prt 6.4×, onepass 1.3×"
"""Moving/still ratios measured when issue #32 was filed (every pose prepared again)."""


def motion(i: int) -> np.ndarray:
    """World-space transform of the ``i``-th moving frame (4×4): the rest pose turned by
    ``i · TURN_DEG`` about +y and moved to point ``i`` of a circle through the rest position
    (``i · STEP_M`` of arc)."""
    phi = i * STEP_M / RADIUS_M
    a = math.radians(i * TURN_DEG)
    m = np.eye(4)
    m[[0, 0, 2, 2], [0, 2, 0, 2]] = [math.cos(a), math.sin(a), -math.sin(a), math.cos(a)]
    m[:3, 3] = [RADIUS_M * math.sin(phi), 0.0, RADIUS_M * (1.0 - math.cos(phi))]
    return m


def lamp(lights, i: int):
    """The demo's lights with the area lamp ``i`` cm further along +x and ``i`` % warmer."""
    out = []
    for lt in lights:
        if lt.type == "area":
            m = np.array(lt.params["to_world"], np.float64)
            m[0, 3] += i * STEP_M
            rad = [c * (1.0 + 0.01 * i) for c in lt.params["radiance"]]
            lt = replace(lt, params={**lt.params, "to_world": m, "radiance": rad})
        out.append(lt)
    return out


def settings_for(method: str) -> RenderSettings:
    """1 spp for onepass (its interactive setting), the method's defaults otherwise."""
    return RenderSettings(spp=1, seed=3) if method == "onepass" else RenderSettings(seed=3)


def measure(method: str, rounds: int, warmup: int) -> dict[str, float | dict]:
    """Still and moving frame times of one method (seconds), interleaved, and under
    ``stages`` the per-stage medians of both kinds (ms; printed, not tabled)."""
    scene = load_scene(DEMO_DIR / "scene.toml")
    m, s = get_method(method), settings_for(method)
    state = m.prepare(scene.world, s)
    still, moving, pose = [], [], []
    stages: dict[str, list[dict]] = {"moving": [], "still": []}
    frame = 0
    for i in range(warmup + rounds):
        frame += 1
        view = replace(scene.view, object_transforms={"bunny": motion(frame)})
        lay_m = m.render(state, view, s)  # the bunny moved since the last frame
        lay_s = m.render(state, view, s)  # the same pose again: nothing moved
        if i >= warmup:
            still.append(lay_s.stats["seconds"])
            moving.append(lay_m.stats["seconds"])
            pose.append(lay_m.stats.get("time_pose", 0.0))
            stages["moving"].append(lay_m.stats)
            stages["still"].append(lay_s.stats)
    lit = []
    if method not in NO_LIGHT_ROW:
        for i in range(warmup + rounds):
            t0 = time.perf_counter()
            m.relight(state, lamp(scene.world.lights, i + 1), s)
            relight = time.perf_counter() - t0
            lay = m.render(state, view, s)
            if i >= warmup:
                lit.append(relight + lay.stats["seconds"])
    return {"still": statistics.median(still), "moving": statistics.median(moving),
            "moving_mean": statistics.fmean(moving), "pose": statistics.median(pose),
            "incremental": float(getattr(m, "incremental_pose", False)),
            "lamp": statistics.median(lit) if lit else math.nan,
            # per-stage medians (ms) of both kinds: where a moving frame's extra time goes
            "stages": {kind: {k[5:]: round(statistics.median(st.get(k, 0.0) for st in rows)
                                           * 1e3, 1)
                              for k in sorted({k for st in rows for k in st
                                               if k.startswith("time_")})}
                       for kind, rows in stages.items()}}


def table(results: dict[str, dict[str, float]], rounds: int, load: str, psi: str) -> str:
    lines = [HEADING, "",
             f"Demo scene, 640×480, one run, a process per method; {rounds} moving/still pairs "
             f"interleaved after warm-up, median wall time per frame (pose included). Moving: "
             f"the bunny {STEP_M * 100:.0f} cm further along a {RADIUS_M * 100:.0f} cm circle "
             f"and {TURN_DEG:.0f}° further turned every moving frame; still: that pose again. "
             f"Target: moving ≤ 1.3× still.",
             "", "| method | incremental pose | still (ms) | moving (ms) | ratio | moving mean "
             "(ms) | pose (ms, median) | lamp moving (ms) | lamp ratio |",
             "|---|---|---|---|---|---|---|---|---|"]
    for name, r in results.items():
        lamp_ms = "n/a" if math.isnan(r["lamp"]) else f"{r['lamp'] * 1e3:.0f}"
        lamp_ratio = "n/a" if math.isnan(r["lamp"]) else f"{r['lamp'] / r['still']:.2f}"
        lines.append(f"| {name}{' (1 spp)' if name == 'onepass' else ''} | "
                     f"{'yes' if r['incremental'] else 'no'} | {r['still'] * 1e3:.0f} | "
                     f"{r['moving'] * 1e3:.0f} | {r['moving'] / r['still']:.2f} | "
                     f"{r['moving_mean'] * 1e3:.0f} | {r['pose'] * 1e3:.1f} | {lamp_ms} | "
                     f"{lamp_ratio} |")
    met = [n for n, r in results.items() if r["moving"] <= 1.3 * r["still"]]
    lines += ["", f"Target met by {len(met)} of {len(results)}: {', '.join(met) or 'none'}. "
              f"Before incremental pose (issue #32's table: the frame after a 1 cm move vs a "
              f"still frame, pose re-prepared): {BEFORE}."]
    lines += ["", "Lamp moving: every frame the area lamp 1 cm further along +x and 1 % warmer "
              "(`BaseMethod.relight`, then the frame; both timed), the bunny still. "
              + " ".join(f"{n}: n/a — {why}." for n, why in NO_LIGHT_ROW.items()
                         if n in results)]
    lines += ["", f"Load at the end of the run (`uptime`): {load}"
              + (f"; CPU pressure (PSI some avg60): {psi} %" if psi else "") + "."]
    return "\n".join(lines)


def merged(text: str, old: str, measured: list[str]) -> str:
    """``text`` (this run's section) with the table rows of the methods it did not measure
    taken from ``old`` (the section as RESULTS.md holds it), in :data:`METHODS` order, and
    the earlier run's load line kept beside this one's (``--merge``)."""
    section = section_of(old)
    if not section:
        return text

    def rows(sec: str) -> dict[str, str]:
        return {line.split("|")[1].strip().split(" ")[0]: line for line in sec.splitlines()
                if line.startswith("| ") and not line.startswith(("| method", "|---"))}
    kept = {n: r for n, r in rows(section).items() if n not in measured}
    if not kept:
        return text
    now = rows(text)
    order = [n for n in METHODS if n in now or n in kept]
    lines = text.splitlines()
    first = next(i for i, line in enumerate(lines) if line.startswith("| ") and
                 not line.startswith(("| method", "|---")))
    last = max(i for i, line in enumerate(lines) if line.startswith("| "))
    table_rows = [now.get(n) or kept[n] for n in order]
    earlier = next((line for line in section.splitlines()
                    if line.startswith("Load at the end of the run")), "")
    met = [n for n, r in zip(order, table_rows, strict=True) if _met(r)]
    rest = []
    for line in lines[last + 1:]:
        if line.startswith("Target met by"):  # counted over every row of the table
            line = (f"Target met by {len(met)} of {len(order)}: {', '.join(met) or 'none'}."
                    + line[line.index(". Before") + 1:])
        elif line.startswith("Lamp moving:"):
            line = line.rstrip() + "".join(f" {n}: n/a — {NO_LIGHT_ROW[n]}." for n in kept
                                           if n in NO_LIGHT_ROW)
        rest.append(line)
    note = (f"Rows of {', '.join(measured)} from this run; {', '.join(kept)} kept from an "
            f"earlier run of this benchmark (`--merge`)."
            + (f" That run's {earlier[0].lower()}{earlier[1:]}" if earlier else ""))
    return "\n".join(lines[:first] + table_rows + rest + ["", note])


NOTES_HEAD = "Notes from earlier runs (kept by `--write`):"
"""The line that opens the kept notes (:func:`earlier_notes`)."""


def section_of(results_md: str) -> str:
    """This benchmark's section of RESULTS.md's text ('' where there is none)."""
    start = results_md.find(HEADING)
    if start < 0:
        return ""
    nxt = results_md.find("\n## ", start + len(HEADING))
    return results_md[start:] if nxt < 0 else results_md[start:nxt]


def earlier_notes(section: str) -> str:
    """The free-text notes of ``section`` (RESULTS.md's section as an earlier run left it):
    its paragraphs after the generated load line, without the generated ``--merge`` note,
    opened by :data:`NOTES_HEAD` ('' where there are none)."""
    paras = [p.strip() for p in section.split("\n\n") if p.strip()]
    at = next((i for i, p in enumerate(paras) if p.startswith("Load at the end of the run")),
              None)
    if at is None:
        return ""
    notes = [p for p in paras[at + 1:]
             if not p.startswith(("Rows of ", "Load at the end of the run", NOTES_HEAD))]
    return "\n\n".join([NOTES_HEAD, *notes]) if notes else ""


def _met(row: str) -> bool:
    """Whether a table row's ratio (5th column) meets the 1.3 target."""
    try:
        return float(row.split("|")[5]) <= 1.3
    except (IndexError, ValueError):
        return False


def child(name: str, rounds: int, warmup: int) -> dict[str, float]:
    """:func:`measure` in a fresh process (no other method's scenes or kernels alive)."""
    # OpenBLAS as the arlight command loads it (this script imports NumPy before arlight)
    env = {**os.environ, "OPENBLAS_NUM_THREADS": os.environ.get("OPENBLAS_NUM_THREADS", "1")}
    out = subprocess.run([sys.executable, __file__, "--child", name, "--rounds", str(rounds),
                          "--warmup", str(warmup)], capture_output=True, text=True,
                         check=True, cwd=str(HERE), env=env).stdout
    line = next(x for x in out.splitlines() if x.startswith("RESULT"))
    return json.loads(line[len("RESULT"):])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--rounds", type=int, default=9)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--write", action="store_true", help="store the table in RESULTS.md")
    ap.add_argument("--merge", action="store_true",
                    help="keep the rows of methods not measured now from RESULTS.md's section")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print("RESULT" + json.dumps(measure(args.child, args.rounds, args.warmup)))
        return
    results = {}
    for name in args.methods.split(","):
        t0 = time.perf_counter()
        results[name] = child(name, args.rounds, args.warmup)
        print(f"{name}: {results[name]} ({time.perf_counter() - t0:.0f} s)", flush=True)
    load = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    text = table(results, args.rounds, load, cpu_pressure())
    old = RESULTS.read_text(encoding="utf-8") if RESULTS.exists() else ""
    if args.merge:
        text = merged(text, old, list(results))
    notes = earlier_notes(section_of(old))
    publish(text + (f"\n\n{notes}" if notes else ""), args.write)


if __name__ == "__main__":
    main()
