"""Re-choosing the measured constants of ``dlpv`` and ``dvct`` on training worlds (issue #30).

    .venv/bin/python benchmarks/tune_realtime.py                 # 16 training, 24 held out
    .venv/bin/python benchmarks/tune_realtime.py --train 4 --heldout 4 --methods dvct
    .venv/bin/python benchmarks/tune_realtime.py --write         # also RESULTS.md

The constants were chosen on the suite scenes they were reported on: ``dvct``'s ``SHELLS``
(0.5) and ``LEVEL_BIAS`` (1). ``dlpv``'s normalisation is derived since issue #33 (direct
lobes ÷ the plane response, VPLs ÷ the point response, :func:`arlight.methods.dlpv.
injection_scales`); its ``calibrate`` and ``calibrate_rho`` are extra divisors on top (1:
none), and the sweep checks on training worlds that the derived scale (1) is where the
changed pixels are best. Each is a method option (``dlpv.calibrate``, ``dlpv.calibrate_rho``,
``dvct.shells``, ``dvct.level_bias``), so ``arlight eval --option dvct.shells=1`` reproduces
any cell below.

Protocol (docs/testing.md, :mod:`arlight.evaluate.worlds`):

1. **Worlds**: per method, the first ``--train`` training worlds and the first ``--heldout``
   held-out worlds it can render (a world with a material or light type the method does not
   support is skipped and counted; the same seeds for every candidate), at 160×120, ground
   truth by Mitsuba at 256 spp, seed 1, max depth 8 (the shared photo cache).
2. **Grid**: every candidate of the method's grid on every training world, scored by the
   harness's ``changed_psnr`` (PSNR of the display image on the pixels the insertion changes)
   and ``psnr``. The candidate with the highest **median training ``changed_psnr``** is
   chosen; candidates within :data:`TIE_DB` of it count as ties, and among ties the one
   with the most constants at a principled value wins (a constant that makes no measurable
   difference falls back to its principled value), then the higher median ``psnr``.
3. **Held out**: the old values and the chosen ones on the held-out worlds: median, 10th
   percentile and worst ``changed_psnr`` and ``psnr``, and the per-world wins. The chosen
   value becomes the method's default only if it does not lose on the held-out median
   ``changed_psnr``: the held-out worlds can veto a change, never pick another value.

A world's volumes are built once and every candidate is composed from them
(:func:`arlight.methods.dlpv.compose`, :func:`arlight.methods.dvct.compose`: the constants
are read only after the volumes are built); a self-check compares that path with the harness's
:func:`~arlight.evaluate.harness.evaluate_cell` (same options) on the first training world.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from results import cpu_pressure, publish  # noqa: E402

WIDTH = 160
GT = {"spp": 256, "seed": 1, "max_depth": 8}
TIE_DB = 0.05
"""Candidates within this many dB of the best median training ``changed_psnr`` are ties."""
HEADING = ("## Held-out worlds: dlpv and dvct constants re-chosen on training worlds "
           "(issue #30)")


# --------------------------------------------------------------------------------------------
# Worlds
# --------------------------------------------------------------------------------------------

def usable_seeds(method: str, split: str, n: int) -> tuple[list[int], list[int]]:
    """The first ``n`` worlds of ``split`` that ``method`` can render, and the seeds skipped
    before them (a material or light type it does not support)."""
    from arlight.evaluate.worlds import generate, split_seeds
    from arlight.methods import get_method

    spec = get_method(method).spec
    seeds, skipped = [], []
    for s in split_seeds(split, 10_000):
        if len(seeds) == n:
            break
        proxy = generate(s).suite_scene(WIDTH).proxy
        (skipped if spec.unsupported_reason(proxy) else seeds).append(s)
    return seeds, skipped


def world(seed: int):
    """``(SuiteScene, SyntheticPhoto)`` of a generated world at :data:`WIDTH`."""
    from arlight.evaluate.worlds import generate

    scene = generate(seed).suite_scene(WIDTH)
    return scene, scene.photo(**GT)


def scores(composite: np.ndarray, scene, photo, full: bool = False) -> dict[str, float]:
    """The harness's metrics of ``composite`` (as :func:`~arlight.evaluate.harness.
    evaluate_cell` computes them): ``psnr`` and ``changed_psnr``, with ``full`` also FLIP."""
    from arlight.evaluate import metrics as M

    gt, tr = photo.ground_truth, scene.world.camera.transfer
    region = M.changed_region(photo.frame, gt, photo.mask, photo.frame_stderr,
                              photo.ground_truth_stderr)
    if full:
        return {**M.image_metrics(composite, gt, tr),
                **M.image_metrics(composite, gt, tr, region, "changed_")}
    dc, dg = M.display(composite, tr), M.display(gt, tr)
    return {"psnr": M.psnr(dc, dg, peak=1.0), "changed_psnr": M.psnr(dc, dg, peak=1.0,
                                                                      region=region)}


# --------------------------------------------------------------------------------------------
# Methods: candidates and composing a world for many of them
# --------------------------------------------------------------------------------------------

@dataclass
class Tuning:
    """One method's constants: ``old`` (the values before issue #30), the candidate grid, the
    principled values of each constant (tie-break) and the labels of special values."""

    method: str
    old: dict
    grid: list[dict]
    principled: dict[str, tuple[float, ...]]
    labels: dict = field(default_factory=dict)

    def n_principled(self, cand: dict) -> int:
        return sum(v in self.principled[k] for k, v in cand.items())

    def label(self, cand: dict) -> str:
        return ", ".join(f"{k}={self.labels.get((k, v), _fmt(v))}" for k, v in cand.items())


def _fmt(v: float) -> str:
    return f"{v:.3g}"


def dlpv_tuning() -> Tuning:
    """``calibrate`` (``V_Δ``) × ``calibrate_rho`` (``V_ρ``), extra divisors of the volume
    reads on top of the derived normalisation (issue #33): 1 (none, the default and the
    principled value) and 0.5, 0.75, 1.25, 1.5, 2 around it."""
    values = (0.5, 0.75, 1.0, 1.25, 1.5, 2.0)
    grid = [{"calibrate": a, "calibrate_rho": b} for a in values for b in values]
    principled = {k: (1.0,) for k in ("calibrate", "calibrate_rho")}
    labels = {(k, 1.0): "1 (derived)" for k in ("calibrate", "calibrate_rho")}
    return Tuning("dlpv", {"calibrate": 1.0, "calibrate_rho": 1.0}, grid, principled, labels)


def dvct_tuning() -> Tuning:
    """``shells`` × ``level_bias``: 1 (exact for one sheet) and 0.5 (a closed surface crosses a
    block twice; the old default), 0.25, 0.75; 0 ([CNS+11], Franke) and 1 (a trilinear tent
    two cells wide; the old default), 0.5, 1.5, 2."""
    grid = [{"shells": s, "level_bias": b} for s in (0.25, 0.5, 0.75, 1.0)
            for b in (0.0, 0.5, 1.0, 1.5, 2.0)]
    principled = {"shells": (1.0, 0.5), "level_bias": (0.0, 1.0)}
    return Tuning("dvct", {"shells": 0.5, "level_bias": 1.0}, grid, principled)


def compose_all(method: str, scene, photo, candidates: list[dict]) -> list[np.ndarray]:
    """Composites of ``scene`` for every candidate: the world prepared, its G-buffer and
    volumes built once (the constants are read only after), then composed per candidate."""
    from arlight.methods import dlpv, dvct, get_method
    from arlight.methods.base import RenderSettings
    from arlight.realtime.gbuffer import render_gbuffer

    render = get_method(method)
    ar = scene.ar_scene(photo)
    settings = RenderSettings(spp=16, max_depth=8, seed=0, options={})
    state = render.prepare(ar.world, settings)
    data, opts = state.data, state.options
    gb = render_gbuffer(data.views.mixed, ar.view.camera, opts.gbuffer_spp, settings.seed)
    out = []
    if method == "dlpv":
        vols = dlpv.build_volumes(data, opts)
        for cand in candidates:
            o = render.spec.parse_options({**dict(opts), **cand})
            k_delta, k_rho = dlpv.read_scales(o)
            layers = dlpv.compose(replace(data, read_scale=k_delta, rho_scale=k_rho), gb,
                                  vols, ar.view)
            out.append(layers.composite)
    else:
        vols = dvct.build_volumes(data, opts)
        for cand in candidates:
            o = render.spec.parse_options({**dict(opts), **cand})
            out.append(dvct.compose(data, gb, vols, ar.view, o).composite)
    return out


def self_check(method: str, scene, photo, candidates: list[dict]) -> float:
    """Largest |difference| (dB) between the fast path's ``psnr``/``changed_psnr`` and the
    harness's :func:`~arlight.evaluate.harness.evaluate_cell` with the same options."""
    from arlight.evaluate.harness import EvalConfig, evaluate_cell

    fast = [scores(c, scene, photo) for c in compose_all(method, scene, photo, candidates)]
    worst = 0.0
    for cand, f in zip(candidates, fast, strict=True):
        cell = evaluate_cell(method, scene, photo, EvalConfig(methods=[method],
                                                              scenes=[scene.name], repeats=1),
                             dict(cand))
        if cell.error:
            raise RuntimeError(f"{method} {scene.name}: {cell.error}")
        for k in ("psnr", "changed_psnr"):
            worst = max(worst, abs(cell.metrics[k] - f[k]))
    return worst


# --------------------------------------------------------------------------------------------
# The run
# --------------------------------------------------------------------------------------------

def pct(xs: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(xs, float), q))


def choose(t: Tuning, train: dict[int, list[dict]]) -> tuple[dict, list[tuple[dict, float,
                                                                               float]]]:
    """The chosen candidate and ``(candidate, median changed_psnr, median psnr)`` of the
    whole grid, best first."""
    rows = []
    for i, cand in enumerate(t.grid):
        cp = statistics.median(r[i]["changed_psnr"] for r in train.values())
        p = statistics.median(r[i]["psnr"] for r in train.values())
        rows.append((cand, cp, p))
    rows.sort(key=lambda r: -r[1])
    best = rows[0][1]
    ties = [r for r in rows if r[1] >= best - TIE_DB]
    ties.sort(key=lambda r: (-t.n_principled(r[0]), -r[2]))
    return ties[0][0], rows


def run_method(t: Tuning, n_train: int, n_held: int, log) -> dict:
    """Grid on the training worlds, choice, old vs new on the held-out worlds."""
    out: dict = {"method": t.method}
    seeds, skipped = usable_seeds(t.method, "training", n_train)
    out["train_seeds"], out["train_skipped"] = seeds, skipped
    log(f"{t.method}: training worlds {seeds} ({len(skipped)} skipped)")
    train: dict[int, list[dict]] = {}
    t0 = time.perf_counter()
    for s in seeds:
        scene, photo = world(s)
        if s == seeds[0]:
            check = [t.old] + [c for c in t.grid[:1] if c != t.old]
            out["self_check_db"] = self_check(t.method, scene, photo, check)
            log(f"  self-check vs evaluate_cell: max |Δ| {out['self_check_db']:.2g} dB")
        train[s] = [scores(c, scene, photo) for c in compose_all(t.method, scene, photo,
                                                                  t.grid)]
        i_old = t.grid.index(t.old)
        log(f"  world-{s}: old {train[s][i_old]['changed_psnr']:.2f} dB, best "
            f"{max(r['changed_psnr'] for r in train[s]):.2f} dB")
    out["train_seconds"] = time.perf_counter() - t0
    chosen, rows = choose(t, train)
    out["chosen"], out["grid_rows"] = chosen, [(t.label(c), cp, p) for c, cp, p in rows]
    out["chosen_label"], out["old_label"] = t.label(chosen), t.label(t.old)
    out["train_old"] = [train[s][t.grid.index(t.old)] for s in seeds]
    out["train_new"] = [train[s][t.grid.index(chosen)] for s in seeds]
    log(f"{t.method}: chosen {t.label(chosen)} (old {t.label(t.old)})")
    held, hskipped = usable_seeds(t.method, "heldout", n_held)
    out["held_seeds"], out["held_skipped"] = held, hskipped
    log(f"{t.method}: held-out worlds {held} ({len(hskipped)} skipped)")
    old, new = [], []
    t0 = time.perf_counter()
    for s in held:
        scene, photo = world(s)
        a, b = compose_all(t.method, scene, photo, [t.old, chosen])
        old.append(scores(a, scene, photo, full=True))
        new.append(scores(b, scene, photo, full=True))
        log(f"  world-{s}: changed_psnr {old[-1]['changed_psnr']:.2f} → "
            f"{new[-1]['changed_psnr']:.2f} dB")
    out["held_seconds"] = time.perf_counter() - t0
    out["held_old"], out["held_new"] = old, new
    return out


def summary(values_old: list[dict], values_new: list[dict]) -> list[str]:
    """Table rows: median, 10th percentile, worst of changed_psnr and psnr, old and new."""
    rows = []
    for key in ("changed_psnr", "psnr"):
        a = [r[key] for r in values_old]
        b = [r[key] for r in values_new]
        for name, f in (("median", statistics.median), ("10th percentile",
                                                        lambda x: pct(x, 10)), ("worst", min)):
            rows.append(f"| `{key}` {name} | {f(a):.2f} dB | {f(b):.2f} dB | "
                        f"{f(b) - f(a):+.2f} dB |")
    return rows


def wins(old: list[dict], new: list[dict], key: str, eps: float = 0.005) -> str:
    d = [b[key] - a[key] for a, b in zip(old, new, strict=True)]
    w, lo = sum(x > eps for x in d), sum(x < -eps for x in d)
    return f"{w} better, {lo} worse, {len(d) - w - lo} equal (±{eps} dB)"


def report(results: list[dict], note: str = "") -> str:
    """The RESULTS.md section of one or more method runs (:func:`run_method` results)."""
    runs = "; ".join(f"`{r['method']}` {r['seconds'] / 60:.0f} min, CPU pressure (PSI some "
                     f"avg60) {r['pressure_start']} → {r['pressure_end']} %" for r in results)
    lines = [HEADING, "",
             f"`benchmarks/tune_realtime.py` ({time.strftime('%Y-%m-%d')}, 2 shared cores; "
             f"{runs}). Worlds: generator of `arlight.evaluate.worlds`, per method the first "
             f"N training / held-out worlds it can render, {WIDTH}×{WIDTH * 3 // 4}, ground "
             "truth Mitsuba 256 spp, seed 1, max depth 8. Each candidate is scored by "
             "`changed_psnr` (primary) and `psnr`; the highest median training "
             f"`changed_psnr` wins; among ties (within {TIE_DB} dB) the candidate with the "
             "most constants at a principled value, then the higher median `psnr`. "
             "The old values and the chosen ones are then run on the held-out worlds, which "
             "played no part in the choice; a chosen value becomes the default only if it "
             "does not lose on the held-out median `changed_psnr` (a veto, never a second "
             "choice).", ""]
    for r in results:
        lines += [f"### `{r['method']}`", "",
                  f"Training: {len(r['train_seeds'])} worlds (seeds "
                  f"{_seeds(r['train_seeds'])}; {len(r['train_skipped'])} skipped, "
                  "unsupported materials or lights). Held out: "
                  f"{len(r['held_seeds'])} worlds (seeds {_seeds(r['held_seeds'])}; "
                  f"{len(r['held_skipped'])} skipped). Fast path vs `evaluate_cell`: max "
                  f"|Δ| {r['self_check_db']:.1g} dB.", "",
                  f"**Chosen: {r['chosen_label']}** (old: {r['old_label']}).", "",
                  "Training grid, median over the training worlds (best first; all "
                  f"{len(r['grid_rows'])} candidates):", "",
                  "| candidate | median `changed_psnr` | median `psnr` |", "|---|---|---|"]
        lines += [f"| {lab} | {cp:.2f} dB | {p:.2f} dB |" for lab, cp, p in r["grid_rows"]]
        lines += ["", f"Training, old → chosen: `changed_psnr` wins "
                  f"{wins(r['train_old'], r['train_new'], 'changed_psnr')}.", "",
                  f"Held out ({len(r['held_seeds'])} worlds), old → chosen:", "",
                  "| metric | old | chosen | Δ |", "|---|---|---|---|"]
        lines += summary(r["held_old"], r["held_new"])
        fo = statistics.median(x["flip"] for x in r["held_old"])
        fn = statistics.median(x["flip"] for x in r["held_new"])
        lines += [f"| `flip` median | {fo:.4f} | {fn:.4f} | {fn - fo:+.4f} |", "",
                  "Per-world wins (chosen vs old): `changed_psnr` "
                  f"{wins(r['held_old'], r['held_new'], 'changed_psnr')}; `psnr` "
                  f"{wins(r['held_old'], r['held_new'], 'psnr')}.", "",
                  f"**Default: {adoption(r)}.**", ""]
    if note:
        lines += [note.strip(), ""]
    return "\n".join(lines)


def adoption(r: dict) -> str:
    """Whether the chosen values become the default (the held-out veto of the protocol)."""
    old = statistics.median(x["changed_psnr"] for x in r["held_old"])
    new = statistics.median(x["changed_psnr"] for x in r["held_new"])
    if new >= old:
        return f"the chosen values ({r['chosen_label']}) are adopted"
    return (f"vetoed — the chosen values lose on the held-out median `changed_psnr` "
            f"({new - old:+.2f} dB), the old values ({r['old_label']}) stay")


def _note(path: Path | None) -> str:
    return path.read_text(encoding="utf-8") if path else ""


def _seeds(seeds: list[int]) -> str:
    return ", ".join(str(s) for s in seeds)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--train", type=int, default=16, help="training worlds per method")
    ap.add_argument("--heldout", type=int, default=24, help="held-out worlds per method")
    ap.add_argument("--methods", default="dlpv,dvct")
    ap.add_argument("--json", type=Path, help="also write every number here")
    ap.add_argument("--merge", type=Path, nargs="+", help="no run: the section from these "
                    "--json files (methods run separately)")
    ap.add_argument("--note", type=Path, help="a file whose text ends the section (how the run "
                    "went)")
    ap.add_argument("--write", action="store_true", help="write the RESULTS.md section")
    args = ap.parse_args(argv)
    if args.merge:
        results = [r for f in args.merge for r in json.loads(f.read_text())]
        publish(report(results, _note(args.note)), args.write)
        return 0
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    t0 = time.perf_counter()

    def log(msg: str) -> None:
        print(f"[{time.perf_counter() - t0:7.0f} s] {msg}", flush=True)

    makers = {"dlpv": dlpv_tuning, "dvct": dvct_tuning}
    results = []
    for m in args.methods.split(","):
        t1, p0 = time.perf_counter(), cpu_pressure() or "?"
        r = run_method(makers[m](), args.train, args.heldout, log)
        r.update(seconds=time.perf_counter() - t1, pressure_start=p0,
                 pressure_end=cpu_pressure() or "?")
        results.append(r)
        if args.json:
            args.json.write_text(json.dumps(results, indent=1, default=str))
    publish(report(results, _note(args.note)), args.write)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
