"""Denoised differential rendering on held-out worlds (issue #31).

**Equal time** (``--worlds``, default the first 8 held-out worlds whose materials are all
diffuse, ``tags["all_diffuse"]``; ``training-diffuse:N`` for the training worlds defaults
are chosen on): per world, the real-time methods (``dlpv``, ``dir``, ``dvct``, ``ibl``,
``prt``) are timed by the evaluation harness (one warm-up, ``--repeats`` timed frames, the
world prepared once) and ``onepass`` is timed on a ladder of spp, raw and with ``denoise =
oidn`` at each OIDN quality of ``--qualities`` (aux on, separate; per spp a warm-up and
the median of ``--repeats`` timed frames, default 3), up to the first spp slower than the
world's slowest real-time method (worlds no real-time method renders are not counted;
ties within :data:`TIE_DB` are counted as losses and named). At ``t*`` = that slowest
method's frame time, the best ``onepass`` frame of each kind that took at most
``t*`` is compared with every real-time method: PSNR (display, against Mitsuba's ground
truth), and the bias of :mod:`arlight.denoise.bias` (relative mean signed luminance error
in the shadow, on the object, at the silhouette) against the ground truth and — the
denoiser's own bias, proxy errors cancelled — against ``onepass`` at 256 spp.

**Variants** at ``--variant-spp`` (default 4): ``denoise_target = separate | delta``,
``denoise_aux = off``, ``denoise_quality = fast`` with aux off — PSNR and bias per world.

**640×480** (``--full N``, worlds ``--full-worlds``): ``onepass`` in each configuration of
:data:`FULL_CONFIGS` (``--configs``) at 1 and 2 spp: frame time, stage times, its ratio to
the raw 1-spp frame of the same run, PSNR against the ground truth (``--full-gt-spp``),
against the noise-free truth (the ground truth's own noise, from its standard error,
subtracted: :func:`gt_noise_mse`) and against converged onepass, and the proxy ceiling.

**Flicker** (``--flicker``): the synthetic bunny-box sequence (96×72, 8 frames) moving
(camera orbit 30°, bunny slides 6 cm, turns 60°; seed 0 every frame) and static (nothing
moves; a new seed per frame): ``onepass`` raw at 4 and 16 spp and denoised at 4 spp;
flicker = mean |e(t+1) − e(t)| (e = composite − GT), as in the sequence benchmark.

    python benchmarks/bench_denoise.py [--worlds heldout-diffuse:8] [--width 160] [--full 2]
        [--flicker] [--save r.pkl] [--write]
    python benchmarks/bench_denoise.py --load a.pkl --load b.pkl --write   # parts merged

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
from arlight.denoise.options import OPTIONS as DENOISE_OPTIONS
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
from arlight.timing import StageTimer

HEADING = "## Denoised differential rendering: onepass + OIDN vs the real-time methods (#31)"
REAL_TIME = ("dlpv", "dir", "dvct", "ibl", "prt")
LADDER = (1, 2, 4, 8, 16, 32, 64, 128)
OIDN = {"denoise": "oidn"}
DEFAULT_QUALITY = DENOISE_OPTIONS["denoise_quality"].default
BALANCED = {**OIDN, "denoise_quality": "balanced"}
QUALITIES = ("fast", "balanced", "high")
"""OIDN qualities laddered at equal time (aux on, separate; ``--qualities``)."""
VARIANTS = {"delta": {**OIDN, "denoise_target": "delta"},
            "aux off": {**OIDN, "denoise_aux": "off"},
            "fast, aux off": {**OIDN, "denoise_quality": "fast", "denoise_aux": "off"}}
CONVERGED_SPP = 256
BIAS_REGIONS = ("shadow", "object", "silhouette")
TIE_DB = 0.05
"""PSNR difference (dB) under which every method ties on a world."""
DENOISED_EXTRA: dict[str, str] = {}
"""Options given to every *denoised* ladder frame of ``onepass`` (``--delta``: the real
pixels' change, docs/methods/denoising.md); raw onepass keeps the options' defaults, so the
comparison is denoised onepass as configured against onepass as shipped."""


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
    denoised: dict[str, list[Point]] = field(default_factory=dict)
    """OIDN quality -> ladder of onepass + OIDN (aux on, separate)."""
    own_bias: dict[str, dict[str, float]] = field(default_factory=dict)
    """'raw' / 'oidn' at t* -> region bias against onepass at CONVERGED_SPP (the
    denoiser's own bias, proxy errors cancelled)."""
    variants: dict[str, Point] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    @property
    def oidn(self) -> list[Point]:
        """The ladder at the default quality."""
        return self.denoised.get(DEFAULT_QUALITY, [])

    @property
    def t_star(self) -> float:
        return max((v[0] for v in self.realtime.values()), default=math.nan)


def heldout_seeds(spec: str) -> list[int]:
    """``heldout-diffuse:N`` / ``training-diffuse:N``: the first N held-out (training)
    worlds whose materials are all diffuse; anything else as
    :func:`arlight.evaluate.worlds.parse_worlds`."""
    split, _, count = spec.partition("-diffuse:")
    if count and split in ("heldout", "training"):
        n = int(count)
        out, seed = [], 1_000_000 if split == "heldout" else 0
        while len(out) < n:
            if generate(seed).tags.get("all_diffuse"):
                out.append(seed)
            seed += 1
        return out
    return parse_worlds(spec)


def ladder(scene, photo, cfg: EvalConfig, options: dict, max_seconds: float,
           spps=LADDER, keep: dict | None = None) -> list[Point]:
    """onepass on ``scene`` at each spp (world prepared once; per spp a warm-up and
    ``cfg.repeats`` timed frames, their median time — as the real-time methods' cells and
    the harness's ladder are timed, so one load spike does not decide an equal-time
    comparison), stopped after the first spp slower than ``max_seconds``; ``keep`` (if
    given) gets each spp's composite."""
    method = get_method("onepass")
    ar = scene.ar_scene(photo)
    state = method.prepare(ar.world, RenderSettings(spp=1, max_depth=cfg.max_depth))
    region, tr = changed_region(photo), scene.world.camera.transfer
    points = []
    for spp in spps:
        s = RenderSettings(spp=spp, max_depth=cfg.max_depth, seed=cfg.seed,
                           options=dict(options))
        method.render(state, ar.view, s)  # warm-up: kernels compile per spp
        times = []
        for _ in range(max(cfg.repeats, 1)):
            t0 = time.perf_counter()
            out = method.render(state, ar.view, s)
            times.append(time.perf_counter() - t0)
        dt = statistics.median(times)
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


def run_world(seed: int, cfg: EvalConfig, variant_spp: int, variants: bool = True,
              qualities: tuple[str, ...] = QUALITIES) -> WorldRun:
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
    for q in qualities:
        opts = {**OIDN, **DENOISED_EXTRA, "denoise_quality": q}
        run.denoised[q] = ladder(scene, photo, cfg, opts, limit,
                                 keep=comps["oidn"] if q == DEFAULT_QUALITY else None)
    for label, opts in (VARIANTS.items() if variants else ()):
        run.variants[label] = ladder(scene, photo, cfg, opts, math.inf, (variant_spp,))[0]
    if variants:
        default = next((p for p in run.oidn if p.spp == variant_spp), None)
        run.variants = {"separate (default)": default or ladder(
            scene, photo, cfg, OIDN, math.inf, (variant_spp,))[0], **run.variants}
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


FULL_SPP = (1, 2)
FULL_CONFIGS = {
    "raw": {},
    "high": {**OIDN, "denoise_quality": "high"},
    "balanced": BALANCED,
    "fast": {**OIDN, "denoise_quality": "fast"},
    "balanced, aux off": {**BALANCED, "denoise_aux": "off"},
    "fast, aux off": {**OIDN, "denoise_quality": "fast", "denoise_aux": "off"},
    "balanced, aux 1 spp": {**BALANCED, "denoise_aux_spp": 1},
    "raw, ratio": {"delta": "ratio"},
    "fast, ratio": {**OIDN, "denoise_quality": "fast", "delta": "ratio"},
}
"""The 640×480 configurations (onepass options), each at every spp of FULL_SPP."""
FULL_CONVERGED_SPP = 64
ONE_SECOND_CONFIG = "fast"
"""The configuration held to "≥ 35 dB in ≤ 1 s" (chosen on training worlds)."""
STAGES = ("time_trace", "time_assemble", "time_denoise_aux", "time_denoise")


@dataclass
class FullRun:
    """onepass at 640×480 on one world.

    ``rows``: (config, spp, seconds, PSNR vs GT, PSNR vs the GT's noise-free truth
    (estimated), PSNR vs onepass at FULL_CONVERGED_SPP, stage seconds, region bias).
    ``gt_ceiling``: the PSNR (dB) of the ground truth itself against the noise-free image,
    from its standard error; ``converged``: PSNR of onepass at FULL_CONVERGED_SPP vs GT
    (the proxy's ceiling: what no amount of samples or denoising can exceed)."""

    world: str
    gt_spp: int
    gt_ceiling: float
    converged: float
    rows: list[tuple] = field(default_factory=list)
    converged_ratio: float = math.nan
    """The proxy ceiling with ``delta = ratio`` (``converged``: ``additive``), same render."""


def gt_noise_mse(photo, transfer) -> float:
    """Mean squared display error of the ground truth from its own Monte Carlo noise:
    ``σ_d = display(gt + σ) − display(gt)`` per channel (σ: its standard error, linearised
    through the display transform), averaged over pixels. For an error independent of the
    ground truth's noise, ``E[MSE(x, gt)] = MSE(x, truth) + σ_d²``: subtracting it gives the
    PSNR against the noise-free truth."""
    from arlight.evaluate.metrics import display

    gt = photo.ground_truth
    d = display(gt + photo.ground_truth_stderr, transfer) - display(gt, transfer)
    return float(np.mean(d * d))


def full_res(seed: int, cfg: EvalConfig, gt_spp: int, configs: list[str] | None = None
             ) -> FullRun:
    """onepass at 640×480 on world ``seed`` in every FULL_CONFIGS configuration."""
    from dataclasses import replace

    from arlight.evaluate import metrics as M

    fcfg = replace(cfg, world_width=640, gt_spp=gt_spp)
    scene = eval_scene(f"world-{seed}", fcfg)
    photo = scene_photo(scene, fcfg)
    tr = scene.world.camera.transfer
    e_gt = gt_noise_mse(photo, tr)
    ar = scene.ar_scene(photo)
    method = get_method("onepass")
    state = method.prepare(ar.world, RenderSettings(spp=1, max_depth=cfg.max_depth))
    conv_layers = method.render(state, ar.view, RenderSettings(
        spp=FULL_CONVERGED_SPP, max_depth=cfg.max_depth, seed=cfg.seed + 1,
        options={"delta": "additive"}))
    d_gt = M.display(photo.ground_truth, tr)
    d_convs = {"additive": M.display(conv_layers.composite, tr),
               "ratio": M.display(method.ratio(  # the ratio's ceiling from the same render
                   conv_layers, state.data, ar.view, method.spec.parse_options(
                       {"delta": "ratio"}), StageTimer(), {}, state.world).composite, tr)}
    default = method.spec.parse_options({}).delta
    run = FullRun(f"world-{seed}", gt_spp, 10 * math.log10(1 / e_gt),
                  M.psnr(d_convs["additive"], d_gt, peak=1.0),
                  converged_ratio=M.psnr(d_convs["ratio"], d_gt, peak=1.0))
    print(run.world, "gt ceiling", round(run.gt_ceiling, 2), "converged", round(run.converged, 2),
          "ratio", round(run.converged_ratio, 2), flush=True)
    for label in configs or FULL_CONFIGS:
        opts = FULL_CONFIGS[label]
        for spp in FULL_SPP:
            s = RenderSettings(spp=spp, max_depth=cfg.max_depth, seed=cfg.seed,
                               options=dict(opts))
            method.render(state, ar.view, s)  # warm-up
            t0 = time.perf_counter()
            out = method.render(state, ar.view, s)
            dt = time.perf_counter() - t0
            d = M.display(out.composite, tr)
            mse = M.mse(d, d_gt)
            conv_d = d_convs[opts.get("delta", default)]  # the same delta's ceiling
            row = (label, spp, dt, M.psnr(d, d_gt, peak=1.0),
                   10 * math.log10(1 / max(mse - e_gt, 1e-12)), M.psnr(d, conv_d, peak=1.0),
                   {k: out.stats.get(k, 0.0) for k in STAGES},
                   region_bias(out.composite, photo.ground_truth, photo.frame, photo.mask))
            run.rows.append(row)
            print(run.world, label, spp, round(dt, 3), [round(x, 2) for x in row[3:6]],
                  {k: round(v, 3) for k, v in row[6].items()}, flush=True)
    return run


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


def full_section(data: dict) -> list[str]:
    """The 640×480 part: per world and configuration, frame time, stage times and PSNR;
    the ≤ 1 s target on the median world for :data:`ONE_SECOND_CONFIG`."""
    full: dict[int, FullRun] = data["full"]
    runs = list(full.values())
    lines = ["### 640×480: ≥ 35 dB in ≤ 1 s?", "",
             f"`{data.get('full_command', data['command'])}`. {len(runs)} worlds ("
             f"{data.get('full_selection', '')}), 640×480, onepass prepared once per world; "
             "per configuration one warm-up and one timed frame. Ground truth "
             f"{runs[0].gt_spp} spp; **GT ceiling** = the PSNR of the ground truth itself "
             "against the noise-free image, from its standard error (display-linearised); "
             "**vs truth** = PSNR with the ground truth's own noise subtracted from the MSE "
             "(E[MSE(x, GT)] = MSE(x, truth) + σ²_GT for an error independent of the GT's "
             f"noise), so the GT does not cap it; **proxy ceiling** = onepass at "
             f"{FULL_CONVERGED_SPP} spp against the GT (the proxy geometry's error: no sample "
             "count or denoiser gets above it; `delta = additive`, in brackets `delta = "
             "ratio` from the same render); **vs conv.** = against that converged onepass "
             "with the row's `delta` (the Monte Carlo + denoiser error alone). CPU pressure "
             "(PSI some avg60) "
             f"{data.get('full_pressure', '?')} %.", ""]
    head = ("| world | GT ceiling | proxy ceiling | config | spp | ms/frame | × raw 1 spp | "
            "trace | aux | OIDN | PSNR vs GT | vs truth | vs conv. | bias % shadow / object / "
            "silhouette |")
    lines += [head, "|" + "---|" * (head.count("|") - 1)]
    for r in runs:
        raw1 = next((row[2] for row in r.rows if row[0] == "raw" and row[1] == 1), math.nan)
        for label, spp, sec, p_gt, p_true, p_conv, st, bias in r.rows:
            lines.append(
                f"| {r.world} | {r.gt_ceiling:.1f} | {r.converged:.2f}"
                f"{'' if math.isnan(r.converged_ratio) else f' ({r.converged_ratio:.2f})'}"
                f" | {label} | {spp} | "
                f"{sec * 1e3:.0f} | {sec / raw1:.1f} | {st['time_trace'] * 1e3:.0f} | "
                f"{st['time_denoise_aux'] * 1e3:.0f} | {st['time_denoise'] * 1e3:.0f} | "
                f"{p_gt:.2f} | {p_true:.2f} | {p_conv:.2f} | {_bias(bias)} |")
    lines.append("")
    one = []  # (run, the ONE_SECOND_CONFIG frame at 1 spp, raw 1 spp seconds)
    for r in runs:
        row = next((x for x in r.rows if x[0] == ONE_SECOND_CONFIG and x[1] == 1), None)
        raw1 = next((x[2] for x in r.rows if x[0] == "raw" and x[1] == 1), math.nan)
        if row is not None:
            one.append((r, row, raw1))
    if one:
        med = {k: statistics.median(x[1][i] for x in one) for k, i in
               (("gt", 3), ("truth", 4), ("conv", 5))}
        ratio = statistics.median(x[1][2] / x[2] for x in one)
        under = sum(x[1][2] <= 1.0 for x in one)
        lines += [f"**`{ONE_SECOND_CONFIG}` at 1 spp** (the configuration chosen on training "
                  f"worlds) on {len(one)} held-out worlds: median PSNR {med['gt']:.2f} dB vs "
                  f"GT, {med['truth']:.2f} dB vs the noise-free truth, {med['conv']:.2f} dB vs "
                  f"converged onepass; median proxy ceiling "
                  f"{statistics.median(r.converged for r in runs):.2f} dB. Frame time "
                  f"{ratio:.1f}× the raw 1-spp frame of the same world and run (median); "
                  f"{under} of {len(one)} frames took ≤ 1 s on this run's load.", ""]
    return lines


def section(data: dict) -> str:
    runs: list[WorldRun] = data["runs"]
    cfg = data["config"]
    qs = [q for q in QUALITIES if any(q in r.denoised for r in runs)]
    lines = [HEADING, "",
             f"`benchmarks/bench_denoise.py` ({data['command']}). {len(runs)} held-out worlds "
             f"({', '.join(r.world.removeprefix('world-') for r in runs)}; "
             f"{data['selection']}), {cfg['width']}×{cfg['width'] * 3 // 4}, ground truth "
             f"{cfg['gt_spp']} spp (Mitsuba). 2 CPU cores shared with other jobs: CPU "
             f"pressure (PSI some avg60, %) {data['pressure_start']} at the start, "
             f"{data['pressure_end']} at the end; every comparison is within one world of "
             "one run. Real-time methods: harness frame time (median of "
             f"{cfg['repeats']} warm frame(s)); onepass: one warm-up and "
             f"{cfg['repeats']} timed frame(s) per spp, their median. t* = the world's "
             "slowest real-time method's frame time; onepass columns: "
             "the best frame that took ≤ t* (spp in brackets). PSNR on display values (dB).",
             "", "### Equal time: PSNR at t*", "",
             "| world | t* (ms) | " + " | ".join(REAL_TIME) + " | onepass raw | "
             + " | ".join(f"+ OIDN {q}" for q in qs) + " | OIDN best? |",
             "|---|---|" + "---|" * (len(REAL_TIME) + len(qs) + 2)]
    compared, at = 0, {k: [] for k in ("raw", *qs)}
    wins = dict.fromkeys(qs, 0)
    rt_wins = dict.fromkeys(qs, 0)
    unsupported, ties = [], 0
    for r in runs:
        t = r.t_star
        rt = [r.realtime.get(m) for m in REAL_TIME]
        raw = best_within(r.raw, t)
        dn = {q: best_within(r.denoised.get(q, []), t) for q in qs}
        best_rt = max((v[1] for v in rt if v), default=math.nan)
        at["raw"].append(raw.metrics["psnr"] if raw else math.nan)
        won = {}
        for q, p in dn.items():
            at[q].append(p.metrics["psnr"] if p else math.nan)
            beats_rt = p is not None and all(p.metrics["psnr"] > v[1] for v in rt if v)
            won[q] = beats_rt and (raw is None or p.metrics["psnr"] >= raw.metrics["psnr"])
        tie = any(rt) and dn[DEFAULT_QUALITY] is not None and all(
            abs(v[1] - dn[DEFAULT_QUALITY].metrics["psnr"]) < TIE_DB for v in rt if v)
        ties += tie
        if any(rt):
            compared += 1
            for q in qs:
                wins[q] += won[q]
                rt_wins[q] += dn[q] is not None and all(
                    dn[q].metrics["psnr"] > v[1] for v in rt if v)
        else:
            unsupported.append(r.world)
        verdict = ("not compared (no real-time method renders it)" if not any(rt) else
                   "yes" if won[DEFAULT_QUALITY] else
                   f"no (a tie: every method within {TIE_DB} dB)" if tie else
                   f"no (best real-time {best_rt:.2f})")
        lines.append(f"| {r.world} | {_f(t * 1e3, '{:.0f}')} | "
                     + " | ".join(_f(v[1]) if v else "skip" for v in rt)
                     + f" | {_cell(raw)} | " + " | ".join(_cell(dn[q]) for q in qs)
                     + f" | {verdict} |")
    pct = 100 * wins[DEFAULT_QUALITY] / max(compared, 1)
    extra = "".join(f", {k} = {v}" for k, v in DENOISED_EXTRA.items())
    lines += ["", f"**Denoised onepass (`{DEFAULT_QUALITY}`, aux on, separate{extra}; "
              f"raw onepass with its defaults) has the highest PSNR at t* — above every "
              f"real-time method and raw onepass — on {wins[DEFAULT_QUALITY]} of "
              f"{compared} worlds** ({pct:.0f} %; "
              f"target ≥ 75 %; {'met' if pct >= 75 else 'not met'}"
              + (f"; {ties} of them a tie — every method, onepass too, within "
                 f"{TIE_DB} dB: the insertion barely changes the image — counted as "
                 f"losses; without them {wins[DEFAULT_QUALITY]} of {compared - ties}"
                 if ties else "") + f"); above every real-time "
              f"method on {rt_wins[DEFAULT_QUALITY]}."
              + ("" if len(qs) < 2 else " Other qualities (not the default; reported, not "
                 "chosen on these worlds): " + ", ".join(
                     f"`{q}` {wins[q]} of {compared}" for q in qs if q != DEFAULT_QUALITY)
                 + ".")
              + " Median PSNR at t*: "
              + ", ".join(f"onepass + OIDN `{q}` {_f(np.nanmedian(at[q]))} dB"
                          for q in qs)
              + f", raw onepass {_f(np.nanmedian(at['raw']))} dB. 'no frame': even 1 spp + "
              "OIDN took longer than t*."
              + (f" Not counted ({', '.join(unsupported)}): no real-time method renders "
                 "these worlds (a sphere light), so there is no t* to compare at; onepass "
                 "renders them, so counting them as wins would inflate the share and as "
                 "losses would be false." if unsupported else ""), ""]
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
    names = list(runs[0].variants)
    if names:
        lines += ["", f"### Variants at {data['variant_spp']} spp (PSNR dB, bias % shadow / "
                  "object / silhouette, ms)", "",
                  "| world | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
        for r in runs:
            lines.append(f"| {r.world} | " + " | ".join(
                f"{p.metrics['psnr']:.2f}, {_bias(p.bias)}, {p.seconds * 1e3:.0f}"
                for p in (r.variants[v] for v in names)) + " |")
        med = {v: statistics.median(r.variants[v].metrics["psnr"] for r in runs)
               for v in names}
        lines += ["", "Median PSNR: " + ", ".join(f"{v} {x:.2f} dB" for v, x in med.items())
                  + ".", ""]
    if data.get("full"):
        lines += full_section(data)
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
    ap.add_argument("--repeats", type=int, default=3, help="timed frames per real-time "
                    "cell and per onepass spp (the median is compared)")
    ap.add_argument("--variant-spp", type=int, default=4)
    ap.add_argument("--full", type=int, default=0, help="worlds timed at 640×480")
    ap.add_argument("--full-worlds", default="", help="worlds of the 640×480 part (default "
                    "--worlds)")
    ap.add_argument("--full-gt-spp", type=int, default=256)
    ap.add_argument("--flicker", action="store_true")
    ap.add_argument("--parts", default="equal,variants,full,flicker", help="comma-separated "
                    "parts to run: equal (equal time, bias), variants (with equal), full "
                    "(640×480), flicker")
    ap.add_argument("--load", type=Path, action="append", default=[], help="pickled results "
                    "of earlier runs (repeatable: their parts are merged)")
    ap.add_argument("--qualities", default=",".join(QUALITIES), help="OIDN qualities "
                    "laddered at equal time")
    ap.add_argument("--configs", default="", help="640×480 configurations (comma-separated "
                    "names of FULL_CONFIGS; default all)")
    ap.add_argument("--selection", default="", help="how the worlds were chosen (the "
                    "report's wording; default from --worlds)")
    ap.add_argument("--delta", choices=("additive", "ratio"), default=None, help="onepass's "
                    "`delta` option on the denoised equal-time ladders (raw onepass keeps the "
                    "default; default: the option's default)")
    ap.add_argument("--save", type=Path)
    ap.add_argument("--write", action="store_true")
    args = ap.parse_args()
    if args.delta:
        DENOISED_EXTRA["delta"] = args.delta
    if args.load:
        data = None
        for path in args.load:
            with open(path, "rb") as f:
                part = pickle.load(f)
            if data is None:
                data = part
                continue
            data["runs"] = data["runs"] + part["runs"]  # worlds run in separate processes
            for key in ("full", "flicker", "full_command", "full_selection", "full_pressure"):
                data[key] = data.get(key) or part.get(key)
            data["command"] += "; " + part["command"]
            data["pressure_end"] += f"; another part {part['pressure_start']} → " \
                                    f"{part['pressure_end']}"
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
            data["runs"].append(run_world(seed, cfg, args.variant_spp, "variants" in parts,
                                          tuple(args.qualities.split(","))))
            if args.save:
                with open(args.save, "wb") as f:
                    pickle.dump(data, f)
        full_seeds = heldout_seeds(args.full_worlds) if args.full_worlds else seeds
        data["full_selection"] = ", ".join(str(s) for s in full_seeds[:args.full])
        p0 = cpu_pressure()
        for seed in full_seeds[:args.full] if "full" in parts else []:
            data["full"][seed] = full_res(seed, cfg, args.full_gt_spp,
                                          args.configs.split(",") if args.configs else None)
            data["full_pressure"] = f"{p0} at the start, {cpu_pressure()} at the end"
            if args.save:
                with open(args.save, "wb") as f:
                    pickle.dump(data, f)
        data["full_command"] = data["command"]
        if args.flicker and "flicker" in parts:
            data["flicker"] = flicker()
        data["pressure_end"] = cpu_pressure()
        if args.save:
            with open(args.save, "wb") as f:
                pickle.dump(data, f)
    if not data["runs"]:  # a part without the equal-time worlds: merge it with --load
        if data.get("full"):
            print("\n".join(full_section(data)))
        print("flicker:", data.get("flicker"))
        return
    if args.selection:
        data["selection"] = args.selection
    publish(section(data), args.write)


if __name__ == "__main__":
    main()
