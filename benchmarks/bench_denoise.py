"""Denoised differential rendering on held-out worlds (issue #31).

**Equal time** (``--worlds``, default the first 8 held-out worlds whose materials are all
diffuse, ``tags["all_diffuse"]``): per world, the real-time methods (``dlpv``, ``dir``,
``dvct``, ``ibl``, ``prt``) are timed by the evaluation harness (one warm-up, ``--repeats``
timed frames, the world prepared once) and ``onepass`` is timed on a ladder of spp, raw,
with ``denoise = oidn`` (default options) and with ``denoise_quality = balanced``, up to the
first frame slower than the world's slowest real-time method. At ``t*`` = that slowest
method's frame time, the best ``onepass`` frame of each kind that took at most ``t*`` is
compared with every real-time method: PSNR (display, against Mitsuba's ground truth), and
the bias of :mod:`arlight.denoise.bias` (relative mean signed luminance error in the shadow,
on the object, at the silhouette) against the ground truth and — the denoiser's own bias,
proxy errors cancelled — against ``onepass`` at 256 spp.

**Variants** at ``--variant-spp`` (default 4): ``denoise_target = separate | delta``,
``denoise_aux = off``, ``denoise_quality = fast`` with aux off — PSNR and bias per world.

**640×480** (``--full N``): on the first ``N`` worlds at 640×480 (ground truth
``--full-gt-spp``), ``onepass`` raw, denoised and denoised at ``balanced`` quality at 1, 2,
4 spp: frame time and PSNR.

**Flicker** (``--flicker``): the synthetic bunny-box sequence (96×72, 8 frames) moving
(camera orbit 30°, bunny slides 6 cm, turns 60°; seed 0 every frame) and static (nothing
moves; a new seed per frame): ``onepass`` raw at 4 and 16 spp and denoised at 4 spp;
flicker = mean |e(t+1) − e(t)| (e = composite − GT), as in the sequence benchmark.

    python benchmarks/bench_denoise.py [--worlds heldout-diffuse:8] [--width 160] [--full 2]
        [--flicker] [--save r.pkl] [--write]
    python benchmarks/bench_denoise.py --load r.pkl --write

The machine is shared (2 cores): every comparison is within one run and one world; the CPU
pressure (PSI ``some avg60``) is printed at the start and the end.
"""

from __future__ import annotations

import argparse
import math
import pickle
import statistics
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from results import cpu_pressure, publish

from arlight.denoise.bias import region_bias
from arlight.evaluate.harness import (
    EvalConfig,
    changed_region,
    composite_metrics,
    eval_scene,
    evaluate_cell,
    scene_photo,
)
from arlight.evaluate.worlds import generate, parse_worlds
from arlight.methods import RenderSettings, get_method

HEADING = "## Denoised differential rendering: onepass + OIDN vs the real-time methods (#31)"
REAL_TIME = ("dlpv", "dir", "dvct", "ibl", "prt")
LADDER = (1, 2, 4, 8, 16, 32, 64, 128)
OIDN = {"denoise": "oidn"}
BALANCED = {**OIDN, "denoise_quality": "balanced"}
VARIANTS = {"delta": {**OIDN, "denoise_target": "delta"},
            "aux off": {**OIDN, "denoise_aux": "off"},
            "fast, aux off": {**OIDN, "denoise_quality": "fast", "denoise_aux": "off"}}
CONVERGED_SPP = 256
BIAS_REGIONS = ("shadow", "object", "silhouette")


@dataclass
class Point:
    """One timed onepass frame: spp, seconds, metrics (``psnr``, ``flip``,
    ``changed_psnr``) and region bias."""

    spp: int
    seconds: float
    metrics: dict[str, float]
    bias: dict[str, float]


@dataclass
class WorldRun:
    world: str
    cls: str
    realtime: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    """method -> (seconds, psnr, flip); skipped/failed methods are absent."""
    realtime_bias: dict[str, dict[str, float]] = field(default_factory=dict)
    raw: list[Point] = field(default_factory=list)
    oidn: list[Point] = field(default_factory=list)
    balanced: list[Point] = field(default_factory=list)
    own_bias: dict[str, dict[str, float]] = field(default_factory=dict)
    """'raw' / 'oidn' at t* -> region bias against onepass at CONVERGED_SPP (the
    denoiser's own bias, proxy errors cancelled)."""
    variants: dict[str, Point] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    @property
    def t_star(self) -> float:
        return max((v[0] for v in self.realtime.values()), default=math.nan)


def heldout_seeds(spec: str) -> list[int]:
    """``heldout-diffuse:N``: the first N held-out worlds whose materials are all diffuse;
    anything else as :func:`arlight.evaluate.worlds.parse_worlds`."""
    if spec.startswith("heldout-diffuse:"):
        n = int(spec.split(":")[1])
        out, seed = [], 1_000_000
        while len(out) < n:
            if generate(seed).tags.get("all_diffuse"):
                out.append(seed)
            seed += 1
        return out
    return parse_worlds(spec)


def ladder(scene, photo, cfg: EvalConfig, options: dict, max_seconds: float,
           spps=LADDER, keep: dict | None = None) -> list[Point]:
    """onepass on ``scene`` at each spp (world prepared once; per spp a warm-up and a timed
    frame), stopped after the first frame slower than ``max_seconds``; ``keep`` (if given)
    gets each spp's composite."""
    method = get_method("onepass")
    ar = scene.ar_scene(photo)
    state = method.prepare(ar.world, RenderSettings(spp=1, max_depth=cfg.max_depth))
    region, tr = changed_region(photo), scene.world.camera.transfer
    points = []
    for spp in spps:
        s = RenderSettings(spp=spp, max_depth=cfg.max_depth, seed=cfg.seed,
                           options=dict(options))
        method.render(state, ar.view, s)  # warm-up: kernels compile per spp
        t0 = time.perf_counter()
        out = method.render(state, ar.view, s)
        dt = time.perf_counter() - t0
        if keep is not None:
            keep[spp] = out.composite
        points.append(Point(spp, dt, composite_metrics(out.composite, photo, tr, region),
                            region_bias(out.composite, photo.ground_truth, photo.frame,
                                        photo.mask)))
        if dt > max_seconds:
            break
    return points


def best_within(points: list[Point], seconds: float) -> Point | None:
    """The best-PSNR point that took at most ``seconds`` (None if none did)."""
    ok = [p for p in points if p.seconds <= seconds]
    return max(ok, key=lambda p: p.metrics["psnr"]) if ok else None


def run_world(seed: int, cfg: EvalConfig, variant_spp: int) -> WorldRun:
    name = f"world-{seed}"
    scene = eval_scene(name, cfg)
    run = WorldRun(name, scene.paper_figure)
    photo = scene_photo(scene, cfg)
    for m in REAL_TIME:
        cell = evaluate_cell(m, scene, photo, cfg, {})
        if cell.ok:
            run.realtime[m] = (cell.seconds, cell.metrics["psnr"], cell.metrics["flip"])
            run.realtime_bias[m] = region_bias(cell.images["composite"], photo.ground_truth,
                                               photo.frame, photo.mask)
        else:
            run.notes.append(f"{m}: {cell.skipped or cell.error}")
        print(name, m, run.realtime.get(m), cell.skipped or cell.error, flush=True)
    limit = run.t_star if run.realtime else 5.0
    comps: dict[str, dict[int, np.ndarray]] = {"raw": {}, "oidn": {}}
    run.raw = ladder(scene, photo, cfg, {}, limit, keep=comps["raw"])
    run.oidn = ladder(scene, photo, cfg, OIDN, limit, keep=comps["oidn"])
    run.balanced = ladder(scene, photo, cfg, BALANCED, limit)
    default = next((p for p in run.oidn if p.spp == variant_spp), None)
    run.variants["separate (default)"] = default or ladder(
        scene, photo, cfg, OIDN, math.inf, (variant_spp,))[0]
    for label, opts in VARIANTS.items():
        run.variants[label] = ladder(scene, photo, cfg, opts, math.inf, (variant_spp,))[0]
    ar = scene.ar_scene(photo)  # the converged proxy render: one untimed frame
    conv = {CONVERGED_SPP: get_method("onepass")(ar, RenderSettings(
        spp=CONVERGED_SPP, max_depth=cfg.max_depth, seed=cfg.seed + 1)).composite}
    for kind, pts in (("raw", run.raw), ("oidn", run.oidn)):
        p = best_within(pts, run.t_star)
        if p is not None:
            run.own_bias[kind] = region_bias(comps[kind][p.spp], conv[CONVERGED_SPP],
                                             photo.frame, photo.mask)
    print(name, "t*", run.t_star, "raw", [(p.spp, round(p.seconds, 3),
                                           round(p.metrics["psnr"], 2)) for p in run.raw],
          "oidn", [(p.spp, round(p.seconds, 3), round(p.metrics["psnr"], 2))
                   for p in run.oidn], flush=True)
    return run


def full_res(seed: int, cfg: EvalConfig, gt_spp: int) -> list[tuple[int, float, float, str]]:
    """Denoised onepass at 640×480 on world ``seed``: (spp, seconds, psnr, kind)."""
    from dataclasses import replace

    fcfg = replace(cfg, world_width=640, gt_spp=gt_spp)
    scene = eval_scene(f"world-{seed}", fcfg)
    photo = scene_photo(scene, fcfg)
    out = []
    for kind, opts in (("raw", {}), ("oidn", OIDN), ("oidn balanced", BALANCED)):
        for p in ladder(scene, photo, fcfg, opts, math.inf, (1, 2, 4)):
            out.append((p.spp, p.seconds, p.metrics["psnr"], kind))
            print(seed, kind, p.spp, round(p.seconds, 3), round(p.metrics["psnr"], 2),
                  flush=True)
    return out


def flicker(n_frames: int = 8) -> dict[str, list[tuple[str, float, float, float]]]:
    """Per sequence kind: (label, psnr mean, flicker radiance, ms/frame). The moving
    sequence renders every frame with seed 0 (Kán's fixed random sequence); the static one
    with a new seed per frame (with one seed its frames would be identical, flicker 0 with
    or without the denoiser): a live camera on a still scene."""
    from bench_sequence import render_frames

    from arlight.sequence.job import _PREPARED
    from arlight.sequence.synthetic_video import (
        sequence_job,
        sequence_metrics,
        synthetic_sequence,
    )

    kinds = {"moving (seed 0 every frame)": ({}, False),
             "static (new seed per frame)": (dict(arc_deg=0.0, slide=(0.0, 0.0, 0.0),
                                                  turn_deg=0.0), True)}
    runs = [("raw", s, {}) for s in (4, 16)] + [("oidn", 4, OIDN)]
    out = {}
    for kind, (kw, vary) in kinds.items():
        seq = synthetic_sequence("bunny-box", n_frames=n_frames, width=96, spp=128, **kw)
        rows = []
        for label, spp, opts in runs:
            job = sequence_job(seq, "onepass", RenderSettings(spp=spp, seed=0,
                                                              options=dict(opts)),
                               vary_seed=vary)
            _PREPARED.clear()
            comps, times, _ = render_frames(job, seq)
            m = sequence_metrics(comps, seq)
            rows.append((f"{label} {spp} spp", m["psnr"], m["flicker"],
                         statistics.median(times[1:]) * 1e3))
            print(kind, rows[-1], flush=True)
        out[kind] = rows
    return out


def _f(x: float, fmt: str = "{:.2f}") -> str:
    return "—" if x is None or not math.isfinite(x) else fmt.format(x)


def _cell(p: Point | None) -> str:
    return f"{p.metrics['psnr']:.2f} ({p.spp})" if p else "no frame"


def _bias(b: dict[str, float]) -> str:
    return " / ".join(_f(100 * b[k], "{:+.1f}") for k in BIAS_REGIONS)


def section(data: dict) -> str:
    runs: list[WorldRun] = data["runs"]
    cfg = data["config"]
    lines = [HEADING, "",
             f"`benchmarks/bench_denoise.py` ({data['command']}). {len(runs)} held-out worlds "
             f"({', '.join(r.world.removeprefix('world-') for r in runs)}; "
             f"{data['selection']}), {cfg['width']}×{cfg['width'] * 3 // 4}, ground truth "
             f"{cfg['gt_spp']} spp (Mitsuba). 2 CPU cores shared with other jobs: CPU "
             f"pressure (PSI some avg60) {data['pressure_start']} % at the start, "
             f"{data['pressure_end']} % at the end; every comparison is within one world of "
             "one run. Real-time methods: harness frame time (median of "
             f"{cfg['repeats']} warm frame(s)); onepass: one warm-up and one timed frame per "
             "spp. t* = the world's slowest real-time method's frame time; onepass columns: "
             "the best frame that took ≤ t* (spp in brackets). PSNR on display values (dB).",
             "", "### Equal time: PSNR at t*", "",
             "| world | t* (ms) | " + " | ".join(REAL_TIME)
             + " | onepass raw | onepass + OIDN | + OIDN balanced | OIDN best? |",
             "|---|---|" + "---|" * (len(REAL_TIME) + 4)]
    wins, compared, oidn_at, raw_at, bal_at, rt_wins, bal_wins = 0, 0, [], [], [], 0, 0
    for r in runs:
        t = r.t_star
        rt = [r.realtime.get(m) for m in REAL_TIME]
        raw, dn, bal = (best_within(r.raw, t), best_within(r.oidn, t),
                        best_within(r.balanced, t))
        best_rt = max((v[1] for v in rt if v), default=math.nan)
        rt_wins += dn is not None and all(dn.metrics["psnr"] > v[1] for v in rt if v)
        bal_wins += bal is not None and all(bal.metrics["psnr"] > v[1] for v in rt if v) and (
            raw is None or bal.metrics["psnr"] >= raw.metrics["psnr"])
        bal_at.append(bal.metrics["psnr"] if bal else math.nan)
        win = dn is not None and all(dn.metrics["psnr"] > v[1] for v in rt if v) and (
            raw is None or dn.metrics["psnr"] >= raw.metrics["psnr"])
        if rt and any(rt):
            compared += 1
            wins += win
        oidn_at.append(dn.metrics["psnr"] if dn else math.nan)
        raw_at.append(raw.metrics["psnr"] if raw else math.nan)
        lines.append(f"| {r.world} | {_f(t * 1e3, '{:.0f}')} | "
                     + " | ".join(_f(v[1]) if v else "skip" for v in rt)
                     + f" | {_cell(raw)} | {_cell(dn)} | {_cell(bal)} | "
                     + ("yes" if win else f"no (best real-time {best_rt:.2f})") + " |")
    lines += ["", f"**Denoised onepass (default options: `high`, aux on, separate) has the "
              f"highest PSNR at t* — above every real-time method and raw onepass — on "
              f"{wins} of {compared} worlds** ({100 * wins / max(compared, 1):.0f} %; "
              f"target ≥ 75 %); above every real-time method on {rt_wins}. With "
              f"`denoise_quality = balanced` (reported, not chosen beforehand): {bal_wins} of "
              f"{compared}. Median PSNR at t*: onepass + OIDN {_f(np.nanmedian(oidn_at))} dB, "
              f"balanced {_f(np.nanmedian(bal_at))} dB, raw onepass "
              f"{_f(np.nanmedian(raw_at))} dB. 'no frame': even 1 spp + OIDN took longer "
              "than t*.", ""]
    lines += ["### Bias at t* (relative mean signed luminance error, %: shadow / object / "
              "silhouette)", "",
              "Against the ground truth, regions from the ground truth "
              "(`arlight.denoise.bias`); `—`: the region is empty.", "",
              "| world | onepass raw | onepass + OIDN | best real-time method |",
              "|---|---|---|---|"]
    for r in runs:
        raw, dn = best_within(r.raw, r.t_star), best_within(r.oidn, r.t_star)
        best = max(r.realtime, key=lambda m: r.realtime[m][1], default=None)
        lines.append(f"| {r.world} | {_bias(raw.bias) if raw else '—'} | "
                     f"{_bias(dn.bias) if dn else '—'} | "
                     + (f"{best}: {_bias(r.realtime_bias[best])}" if best else "—") + " |")
    lines += ["", "The shadow bias of every column (raw onepass too) is mostly the proxy "
              "(coarser than the world that made the photograph). **The denoiser's own "
              f"bias** — the same frames against onepass at {CONVERGED_SPP} spp on the proxy, "
              "so proxy errors cancel (%: shadow / object / silhouette):", "",
              "| world | onepass raw at t* | onepass + OIDN at t* |", "|---|---|---|"]
    for r in runs:
        lines.append(f"| {r.world} | " + " | ".join(
            _bias(r.own_bias[k]) if k in r.own_bias else "—" for k in ("raw", "oidn"))
            + " |")
    for k in BIAS_REGIONS:
        vals = [r.own_bias["oidn"][k] for r in runs if "oidn" in r.own_bias]
        vals = [v for v in vals if math.isfinite(v)]
        if vals:
            lines.append("")
            lines.append(f"Denoiser's own bias, {k}: median {100 * statistics.median(vals):+.1f}"
                         f" %, largest |bias| {100 * max(vals, key=abs):+.1f} % ({len(vals)} "
                         "worlds).")
    vspp = data["variant_spp"]
    names = list(runs[0].variants)
    lines += ["", f"### Variants at {vspp} spp (PSNR dB, bias % shadow / object / "
              "silhouette, ms)", "",
              "| world | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    for r in runs:
        lines.append(f"| {r.world} | " + " | ".join(
            f"{p.metrics['psnr']:.2f}, {_bias(p.bias)}, {p.seconds * 1e3:.0f}"
            for p in (r.variants[v] for v in names)) + " |")
    med = {v: statistics.median(r.variants[v].metrics["psnr"] for r in runs) for v in names}
    lines += ["", "Median PSNR: " + ", ".join(f"{v} {x:.2f} dB" for v, x in med.items())
              + ".", ""]
    if data.get("full"):
        lines += ["### 640×480 frames", "",
                  f"Ground truth {data['full_gt_spp']} spp (its own noise caps the PSNR). "
                  "Frame time includes the auxiliary buffers and OIDN (`high`).", "",
                  "| world | kind | spp | ms/frame | PSNR (dB) |", "|---|---|---|---|---|"]
        for seed, rows in data["full"].items():
            for spp, s, p, kind in rows:
                lines.append(f"| world-{seed} | {kind} | {spp} | {s * 1e3:.0f} | {p:.2f} |")
        lines.append("")
    if data.get("flicker"):
        lines += ["### Flicker (sequences)", "",
                  "Synthetic bunny-box sequence, 96×72, 8 frames, ground truth 128 spp; "
                  "moving: camera orbit 30°, bunny slides 6 cm and turns 60°, onepass with "
                  "seed 0 every frame (Kán's fixed sequence); static: nothing moves, a new "
                  "seed per frame (with one seed the frames are identical and the flicker 0 "
                  "either way). Flicker = mean over t of mean |e(t+1) − e(t)|, e = composite "
                  "− GT (radiance). The moving frames' time is mostly the posed world's "
                  "Mitsuba scenes, built again every frame.", "",
                  "| sequence | onepass | PSNR mean (dB) | flicker | ms/frame |",
                  "|---|---|---|---|---|"]
        for kind, rows in data["flicker"].items():
            for label, p, fl, ms in rows:
                lines.append(f"| {kind} | {label} | {p:.2f} | {fl:.5f} | {ms:.0f} |")
        lines.append("")
    if any(r.notes for r in runs):
        lines += ["Skipped cells: " + "; ".join(f"{r.world} {n}" for r in runs
                                                  for n in r.notes) + "."]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worlds", default="heldout-diffuse:8")
    ap.add_argument("--width", type=int, default=160)
    ap.add_argument("--gt-spp", type=int, default=256)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--variant-spp", type=int, default=4)
    ap.add_argument("--full", type=int, default=0, help="worlds timed at 640×480")
    ap.add_argument("--full-gt-spp", type=int, default=64)
    ap.add_argument("--flicker", action="store_true")
    ap.add_argument("--parts", default="equal,full,flicker", help="comma-separated parts to "
                    "run: equal (equal time, bias, variants), full (640×480), flicker")
    ap.add_argument("--load", type=Path, action="append", default=[], help="pickled results "
                    "of earlier runs (repeatable: their parts are merged)")
    ap.add_argument("--save", type=Path)
    ap.add_argument("--write", action="store_true")
    args = ap.parse_args()
    if args.load:
        data = None
        for path in args.load:
            with open(path, "rb") as f:
                part = pickle.load(f)
            if data is None:
                data = part
                continue
            data["runs"] = data["runs"] or part["runs"]
            for key in ("full", "flicker"):
                data[key] = data.get(key) or part.get(key)
            data["command"] += "; " + part["command"]
            data["pressure_end"] += f" (other part: {part['pressure_start']} → " \
                                    f"{part['pressure_end']})"
    else:
        import sys

        seeds = heldout_seeds(args.worlds)
        cfg = EvalConfig(methods=list(REAL_TIME), scenes=[], quick=False, spp=16,
                         gt_spp=args.gt_spp, repeats=args.repeats, worlds=seeds,
                         world_width=args.width)
        data = {"command": "python benchmarks/bench_denoise.py " + " ".join(sys.argv[1:]),
                "selection": ("the first held-out seeds with tags['all_diffuse']"
                              if args.worlds.startswith("heldout-diffuse") else args.worlds),
                "config": {"width": args.width, "gt_spp": args.gt_spp,
                           "repeats": args.repeats},
                "pressure_start": cpu_pressure(), "variant_spp": args.variant_spp,
                "runs": [], "full": {}, "full_gt_spp": args.full_gt_spp}
        parts = set(args.parts.split(","))
        for seed in seeds if "equal" in parts else []:
            data["runs"].append(run_world(seed, cfg, args.variant_spp))
            if args.save:
                with open(args.save, "wb") as f:
                    pickle.dump(data, f)
        for seed in seeds[:args.full] if "full" in parts else []:
            data["full"][seed] = full_res(seed, cfg, args.full_gt_spp)
        if args.flicker and "flicker" in parts:
            data["flicker"] = flicker()
        data["pressure_end"] = cpu_pressure()
        if args.save:
            with open(args.save, "wb") as f:
                pickle.dump(data, f)
    if not data["runs"]:  # a part without the equal-time worlds: merge it with --load
        print("full:", data.get("full"), "\nflicker:", data.get("flicker"))
        return
    publish(section(data), args.write)


if __name__ == "__main__":
    main()
