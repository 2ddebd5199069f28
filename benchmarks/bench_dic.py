"""Benchmark: differential irradiance caching (``dic``) against ``onepass`` at equal time.

1. PSNR vs wall time on bunny-box at 640×480 (the suite's world, its 256-spp Mitsuba ground
   truth): a ladder of ``dic`` settings (rays per record, camera samples) and of ``onepass``
   sample counts, each rendered from its prepared state after a warm-up frame, the methods
   interleaved round by round on the shared machine; medians over the repeats. ``dic`` rows
   carry the record count, miss-detection iterations and stage times.
2. Flicker (``arlight.evaluate.metrics.temporal_flicker``) on a short sequence at 160×120 in
   which the virtual object moves a little every frame: ``dic`` through
   :class:`arlight.methods.dic.DicSequence` (records kept, dropped near the object, aged)
   against ``onepass`` with a fresh seed per frame at about the same time per frame; errors
   against a 256-spp ``onepass`` render of each frame.

3. ``--heldout A.pkl B.pkl ... --labels ...``: the section "dic: validated lookups and equal
   time on held-out worlds (issue #33)" from saved ``bench_heldout.py --methods dic,onepass
   --save`` runs of successive code states, per world: dic's PSNR minus the best onepass
   ladder frame that took at most dic's frame time (same run), over the worlds every run
   measured, by world class.

Usage:

    python benchmarks/bench_dic.py [--repeats 3] [--write] [--flicker-only]
    python benchmarks/bench_dic.py --heldout a.pkl b.pkl --labels 'a: ...' 'b: ...' [--write]
"""

from __future__ import annotations

import argparse
import statistics
from dataclasses import replace

import numpy as np
from results import cpu_pressure, publish

from arlight.evaluate import metrics as M
from arlight.evaluate.suite import get_scene
from arlight.methods import RenderSettings, get_method
from arlight.methods.dic import DicSequence
from arlight.scene.model import ARScene

HEADING = "## Differential irradiance caching: dic vs onepass at equal time (issue 14)"
DIC_LADDER = [  # (rays per record, camera spp)
    (32, 2), (64, 8), (128, 16), (256, 32),
]
ONEPASS_LADDER = [2, 4, 8, 16, 32, 64]
FLICKER_SPP = 16
FLICKER_OPTIONS = {"rays": 128, "invalidate_distance": 0.1}
STAGES = ("setup", "update", "records", "splat", "miss", "trace", "assemble")


def psnr(layers, gt, transfer) -> float:
    return M.image_metrics(layers.composite, gt, transfer)["psnr"]


def equal_time(scene, gt, repeats: int) -> tuple[list[dict], list[dict]]:
    tr = scene.camera.transfer
    configs = [("dic", RenderSettings(spp=spp, options={"rays": rays}), f"rays {rays}, spp {spp}")
               for rays, spp in DIC_LADDER]
    configs += [("onepass", RenderSettings(spp=spp), f"spp {spp}") for spp in ONEPASS_LADDER]
    states = {}
    runs: dict[int, list] = {i: [] for i in range(len(configs))}
    for i, (name, s, _) in enumerate(configs):
        m = get_method(name)
        states[i] = m.prepare(scene.world, s)
        m.render(states[i], scene.view, s)  # warm-up (kernel compilation)
    for r in range(repeats):
        for i, (name, s, _) in enumerate(configs):
            s_r = replace(s, seed=17 + r)
            layers = get_method(name).render(states[i], scene.view, s_r)
            runs[i].append((layers.stats["seconds"], psnr(layers, gt, tr), layers.stats))
    rows = []
    for i, (name, _, label) in enumerate(configs):
        secs = statistics.median(x[0] for x in runs[i])
        db = statistics.median(x[1] for x in runs[i])
        st = runs[i][-1][2]
        row = {"method": name, "setting": label, "seconds": secs, "psnr": db}
        if name == "dic":
            row.update(records=st["records"], iterations=st["iterations"],
                       stages={k: statistics.median(x[2].get(f"time_{k}", 0.0) for x in runs[i])
                               for k in STAGES})
        rows.append(row)
    return [r for r in rows if r["method"] == "dic"], [r for r in rows if r["method"] != "dic"]


def onepass_at(rows: list[dict], seconds: float) -> float:
    """onepass PSNR interpolated (in log time) at ``seconds``; nan outside the ladder."""
    t = np.log([r["seconds"] for r in rows])
    p = [r["psnr"] for r in rows]
    x = np.log(seconds)
    if x < t.min() or x > t.max():
        return float("nan")
    order = np.argsort(t)
    return float(np.interp(x, t[order], np.asarray(p)[order]))


def flicker(frames: int = 5) -> dict[str, float]:
    s = get_scene("bunny-box", quick=False)
    base = s.ar_scene(s.photo(spp=256)).resized(160, 120)
    name = next(sh.name for sh in base.world.shapes if sh.is_virtual)
    views = []
    for k in range(frames):
        move = np.eye(4)
        move[:3, 3] = [0.01 * k, 0.0, 0.0]  # 1 cm per frame
        views.append(replace(base.view, object_transforms={name: move}))
    refs = [get_method("onepass")(ARScene.compose(base.world, v), RenderSettings(spp=256)).composite
            for v in views]
    seq = DicSequence(base.world, RenderSettings(spp=FLICKER_SPP, options=FLICKER_OPTIONS))
    dic = [seq.render(v) for v in views]
    t_dic = statistics.median(x.stats["seconds"] for x in dic[1:])
    one = get_method("onepass")
    state = one.prepare(base.world, RenderSettings(spp=1))
    one.render(state, views[0], RenderSettings(spp=8))  # warm-up (kernel compilation)
    per_spp = statistics.median(one.render(state, views[0], RenderSettings(spp=8)).stats[
        "seconds"] for _ in range(3)) / 8
    spp = max(1, int(round(t_dic / per_spp)))
    for _ in range(2):  # a render has a fixed cost too: correct the sample count twice
        t = one.render(state, views[0], RenderSettings(spp=spp)).stats["seconds"]
        spp = max(1, int(round(spp * t_dic / t)))
    ops = [one.render(state, v, RenderSettings(spp=spp, seed=1000 + k))
           for k, v in enumerate(views)]
    return {"frames": frames, "dic_seconds": t_dic, "onepass_spp": spp,
            "onepass_seconds": statistics.median(x.stats["seconds"] for x in ops[1:]),
            "dic": M.temporal_flicker([x.composite for x in dic], refs),
            "onepass": M.temporal_flicker([x.composite for x in ops], refs),
            "records_dropped": statistics.median(x.stats["records_dropped"] for x in dic[1:]),
            "records_new": statistics.median(x.stats["records_new"] for x in dic[1:])}


def report(dic_rows, one_rows, fl, repeats: int, pressure: str) -> str:
    lines = [HEADING, "",
             f"`python benchmarks/bench_dic.py --repeats {repeats}`; bunny-box world at 640×480 "
             "(its area light and constant sky), 256-spp Mitsuba ground truth, PSNR on the "
             "display image (R = 1); llvm_ad_rgb, 2 shared CPU cores (CPU pressure avg60 "
             f"{pressure or 'n/a'} % at the end); medians of {repeats} interleaved rounds, "
             "each frame from the prepared state after a warm-up frame. "
             "`onepass @ same time`: onepass's PSNR interpolated at dic's time (log time).", "",
             "| method | setting | time | PSNR | onepass @ same time | records | iterations |",
             "|---|---|---|---|---|---|---|"]
    for r in dic_rows:
        at = onepass_at(one_rows, r["seconds"])
        at_s = "—" if np.isnan(at) else f"{at:.2f} dB"
        lines.append(f"| dic | {r['setting']} | {r['seconds']:.2f} s | {r['psnr']:.2f} dB | "
                     f"{at_s} | {r['records']:.0f} | {r['iterations']:.0f} |")
    for r in one_rows:
        lines.append(f"| onepass | {r['setting']} | {r['seconds']:.2f} s | {r['psnr']:.2f} dB "
                     "| | | |")
    lines += ["", "dic stage times (s, medians): " + "; ".join(
        f"{r['setting']}: " + ", ".join(f"{k} {v:.2f}" for k, v in r["stages"].items() if v)
        for r in dic_rows), ""]
    lines += [f"Flicker, 160×120, the bunny moving 1 cm per frame over {fl['frames']} frames "
              f"(`temporal_flicker` against 256-spp onepass per frame): dic (DicSequence, "
              f"{FLICKER_OPTIONS}, {FLICKER_SPP} spp, {fl['dic_seconds']:.2f} s per frame, median "
              f"{fl['records_dropped']:.0f} records dropped and {fl['records_new']:.0f} new per "
              f"frame) **{fl['dic']:.4f}**; onepass with a fresh seed per frame at "
              f"{fl['onepass_spp']} spp ({fl['onepass_seconds']:.2f} s per frame) "
              f"**{fl['onepass']:.4f}**."]
    return "\n".join(lines)


HELDOUT_HEADING = "## dic: validated lookups and equal time on held-out worlds (issue #33)"


def equal_time_delta(results, world: str) -> tuple[float, float, float]:
    """``(dic seconds, dic PSNR, Δ PSNR)`` of ``world``: Δ = dic's PSNR minus that of the
    best ``onepass`` ladder frame that took at most dic's time (NaN when none did)."""
    cell = next(c for c in results.cells if c.method == "dic" and c.scene == world)
    fast = [p.metrics["psnr"] for p in results.ladders.get(world, [])
            if p.seconds <= cell.seconds]
    best = max(fast) if fast else float("nan")
    return cell.seconds, cell.metrics["psnr"], cell.metrics["psnr"] - best


def heldout_section(runs: list, labels: list[str], pressure: str, note: str = "") -> str:
    """The issue-#33 section from saved held-out runs (see the module docstring): per world
    and run, dic's PSNR, frame time and Δ vs onepass at equal time (same run), over the
    worlds every run measured; medians overall and per world class."""
    classes = runs[-1].world_classes()
    worlds = [w for w in classes if all(
        any(c.method == "dic" and c.scene == w for c in r.cells) and w in r.ladders
        for r in runs)]
    lines = [HELDOUT_HEADING, "",
             "`python benchmarks/bench_heldout.py --methods dic,onepass --worlds heldout:8 "
             "--width 160 --save X.pkl`, once per code state, then `python benchmarks/"
             "bench_dic.py --heldout X.pkl ... --labels ...`. 160×120, 16 spp, defaults, "
             "ground truth 256 spp; Δ = dic's PSNR minus the best onepass frame of the same "
             "world and run that took at most dic's frame time. Runs: "
             + "; ".join(labels) + f". CPU pressure (PSI some avg60) at the end: "
             f"{pressure or 'n/a'} % (2 cores shared with other helpers all along: absolute "
             f"times inflated and varying between runs; Δ is same-run). {note}", "",
             "| world | class | " + " | ".join(f"dic {k} | Δ {k}" for k in
                                              (lab.split(":")[0] for lab in labels)) + " |",
             "|---|---|" + "---|---|" * len(runs)]
    deltas: dict[str, list[list[float]]] = {}
    for w in worlds:
        row = [equal_time_delta(r, w) for r in runs]
        deltas.setdefault(classes[w], []).append([d for _, _, d in row])
        lines.append(f"| {w} | {classes[w]} | " + " | ".join(
            f"{p:.2f} dB, {t * 1e3:.0f} ms | {d:+.2f} dB" for t, p, d in row) + " |")
    lines.append("")
    every = [d for v in deltas.values() for d in v]
    names = [lab.split(":")[0] for lab in labels]
    if every:
        def med(i, xs):
            return statistics.median(x[i] for x in xs)
        lines.append(
            f"Median Δ over {len(every)} worlds: " + ", ".join(
                f"{k} {med(i, every):+.2f} dB (ahead on {sum(d[i] > 0 for d in every)})"
                for i, k in enumerate(names)) + ". By class: " + "; ".join(
                f"{c} ({len(v)}): " + " → ".join(f"{med(i, v):+.2f}" for i in range(len(runs)))
                + " dB" for c, v in sorted(deltas.items())) + ".")
    return "\n".join(lines)


MOTION_WIDTH = 160
MOTION_SPP = 4


def motion_line(rounds: int = 3, warmup: int = 1) -> str:
    """dic while the demo's bunny moves 1 cm (and turns 2°) every frame vs still (#32), at
    160×120, 4 spp, interleaved frames, medians: ``DicMethod`` (cache rebuilt per frame;
    shapes moved in place) and :class:`DicSequence` (records kept, dropped near the old and
    new bounds)."""
    import math
    import time

    from arlight.demo import DEMO_DIR
    from arlight.scene.load import load_scene

    scene = load_scene(DEMO_DIR / "scene.toml").resized(MOTION_WIDTH, MOTION_WIDTH * 3 // 4)
    s = RenderSettings(spp=MOTION_SPP, seed=3)

    def move(i: int) -> np.ndarray:
        a = math.radians(2.0 * i)
        m = np.eye(4)
        m[[0, 0, 2, 2], [0, 2, 0, 2]] = [math.cos(a), math.sin(a), -math.sin(a), math.cos(a)]
        m[0, 3] = 0.01 * i
        return m

    m = get_method("dic")
    state = m.prepare(scene.world, s)
    seq = DicSequence(scene.world, s)
    times: dict[str, list[float]] = {k: [] for k in ("still", "moving", "seq_still",
                                                     "seq_moving", "pose")}
    dropped, kept = [], []
    for i in range(1, warmup + rounds + 1):
        view = replace(scene.view, object_transforms={"bunny": move(i)})
        lm = m.render(state, view, s)
        ls = m.render(state, view, s)
        t0 = time.perf_counter()
        qm = seq.render(view)
        t1 = time.perf_counter()
        seq.render(view)
        t2 = time.perf_counter()
        if i > warmup:
            times["moving"].append(lm.stats["seconds"])
            times["still"].append(ls.stats["seconds"])
            times["pose"].append(lm.stats.get("time_pose", 0.0))
            times["seq_moving"].append(t1 - t0)
            times["seq_still"].append(t2 - t1)
            dropped.append(qm.stats["records_dropped"])
            kept.append(qm.stats["records"] - qm.stats["records_new"])
    med = {k: statistics.median(v) for k, v in times.items()}
    return (f"Incremental pose (#32), demo scene at {MOTION_WIDTH}×{MOTION_WIDTH * 3 // 4}, "
            f"{MOTION_SPP} spp, the bunny moving 1 cm and turning 2° per frame, medians of "
            f"{rounds} interleaved frames: DicMethod still {med['still'] * 1e3:.0f} ms, moving "
            f"{med['moving'] * 1e3:.0f} ms (ratio {med['moving'] / med['still']:.2f}; pose "
            f"{med['pose'] * 1e3:.0f} ms); DicSequence still {med['seq_still'] * 1e3:.0f} ms, "
            f"moving {med['seq_moving'] * 1e3:.0f} ms (ratio "
            f"{med['seq_moving'] / med['seq_still']:.2f}; {statistics.median(dropped):.0f} "
            f"records dropped, {statistics.median(kept):.0f} kept per moving frame).")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--write", action="store_true", help="store the section in RESULTS.md")
    ap.add_argument("--flicker-only", action="store_true", help="print the flicker line only")
    ap.add_argument("--heldout", nargs="+", metavar="PKL",
                    help="the issue-#33 section from pickled bench_heldout runs (in order)")
    ap.add_argument("--labels", nargs="+", help="one 'name: what the code did' per run")
    ap.add_argument("--note", default="", help="a sentence appended to the section's header")
    ap.add_argument("--motion", action="store_true", help="with --heldout: measure dic's "
                    "moving vs still frame time (#32) and add it to the section")
    args = ap.parse_args()
    if args.heldout:
        import pickle

        runs = []
        for path in args.heldout:
            with open(path, "rb") as f:
                runs.append(pickle.load(f))
        labels = args.labels or [f"run{i}" for i in range(len(runs))]
        text = heldout_section(runs, labels, cpu_pressure(), args.note)
        if args.motion:
            text += "\n\n" + motion_line() + f" CPU pressure {cpu_pressure()} %."
        publish(text, args.write)
        return
    if args.flicker_only:
        print(flicker())
        return
    s = get_scene("bunny-box", quick=False)
    photo = s.photo(spp=256)
    scene = s.ar_scene(photo)
    fl = flicker()
    print(fl, flush=True)
    dic_rows, one_rows = equal_time(scene, photo.ground_truth, args.repeats)
    publish(report(dic_rows, one_rows, fl, args.repeats, cpu_pressure()), args.write)


if __name__ == "__main__":
    main()
