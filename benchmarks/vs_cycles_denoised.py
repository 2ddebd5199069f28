"""``bench_vs_cycles.py --denoise``: the denoiser on both sides (issue #31).

Per scene, ``onepass`` with and without ``denoise = oidn`` (OIDN ``high``, clean albedo and
normal, ``separate``: the defaults) and Cycles with and without its own OpenImageDenoise
(High, albedo + normal, accurate prefilter; :mod:`cycles_worker`), each at ``--denoise-spp``,
``--repeats`` interleaved renders (different seeds) per spp. Each render's PSNR against the
independent ground truth (Mitsuba's render of the world, the photograph's
``ground_truth``; directly seen lights left out as in every measure of
:mod:`bench_vs_cycles`) and its wall time — arlight: the whole method call (scene
preparation, auxiliary buffers and OIDN included); Cycles: the whole render call
(synchronisation, denoising and the EXR write included). **Equal time**: at the mean time of
each Cycles + OIDN point, onepass + OIDN's PSNR interpolated linearly in log time between
its own points (not extrapolated: "—" outside its range); onepass runs at Cycles' spp and at
2× and 4× each (:func:`arlight_spp`) so that its curve spans Cycles' times.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from bench_vs_cycles import Cycles, export_or_skip, lights_mask

HEADING = ("## Held-out worlds: denoised onepass vs denoised Cycles at equal time (issue #31)")
LABELS = ("onepass", "onepass + OIDN", "cycles", "cycles + OIDN")


def arlight_spp(spp: list[int]) -> list[int]:
    """onepass's spp: Cycles' and 2× and 4× each, so that Cycles' times fall inside
    onepass's curve (equal time is interpolated, never extrapolated)."""
    return sorted({s * m for s in spp for m in (1, 2, 4)})


def psnr_at(points: list[tuple[float, float]], t: float) -> tuple[float, str]:
    """PSNR of a (seconds, PSNR) curve at time ``t``: ``(value, "=")`` interpolated linearly
    in log time; past its slowest point ``(that point's PSNR, "≥")`` — reached sooner, so a
    lower bound (PSNR grows with time); before its fastest point ``(nan, "no frame")``."""
    ts = np.log([p[0] for p in points])
    order = np.argsort(ts)
    ts, ps = ts[order], np.array([p[1] for p in points])[order]
    lt = np.log(t)
    if lt < ts[0]:
        return float("nan"), "no frame"
    if lt > ts[-1]:
        return float(ps.max()), "≥"
    return float(np.interp(lt, ts, ps)), "="


def measure_denoised(name: str, proxy, photo, args, tmp: Path) -> dict:
    """PSNR and time of the four renderers on one scene (``skip`` when untranslatable)."""
    from arlight.evaluate.metrics import psnr
    from arlight.methods import RenderSettings, get_method

    scene = proxy.with_frame(photo.frame)
    res: dict = {"name": name}
    skip = export_or_skip(name, [(scene, tmp / f"{name}_ar.npz", True)], args.max_depth)
    if skip:
        return {**res, "skip": skip}
    gt = photo.ground_truth.astype(np.float64)
    keep = lights_mask(gt)
    method = get_method("onepass")

    def arlight(spp: int, seed: int, denoise: bool) -> tuple[np.ndarray, float]:
        opts = {"reproject": False,  # OIDN `high`: the quality Cycles denoises at
                **({"denoise": "oidn", "denoise_quality": "high"} if denoise else {})}
        lay = method(scene, RenderSettings(spp=spp, seed=seed, max_depth=args.max_depth,
                                           options=opts))
        return lay.composite.astype(np.float64), lay.stats["seconds"]

    cyc = Cycles(args.bpy_python, tmp / f"{name}_ar.npz", photo.frame, tmp, clock="wall")
    renderers = {"onepass": lambda s, k: arlight(s, k, False),
                 "onepass + OIDN": lambda s, k: arlight(s, k, True),
                 "cycles": lambda s, k: cyc.render(s, k, False),
                 "cycles + OIDN": lambda s, k: cyc.render(s, k, True)}
    runs: dict[str, dict[int, list[tuple[float, float]]]] = {
        k: {s: [] for s in (arlight_spp(args.denoise_spp) if k.startswith("onepass")
                            else args.denoise_spp)} for k in renderers}
    try:
        for r in renderers.values():  # warm-up: kernels compiled, Blender scene synced
            r(1, 7)
        for rep in range(args.repeats):
            for spp in arlight_spp(args.denoise_spp):
                for label, r in renderers.items():
                    if spp not in runs[label]:
                        continue
                    img, sec = r(spp, 1000 + rep)
                    runs[label][spp].append((sec, psnr(img, gt, region=keep)))
                    print(name, label, spp, rep, f"{sec:.2f} s",
                          f"{runs[label][spp][-1][1]:.2f} dB", flush=True)
    finally:
        cyc.close()
    res["pts"] = {k: [(float(np.mean([t for t, _ in v])), float(np.mean([p for _, p in v])))
                      for v in per.values()] for k, per in runs.items()}
    res["equal"] = [(t, p, *psnr_at(res["pts"]["onepass + OIDN"], t))
                    for t, p in res["pts"]["cycles + OIDN"]]
    return res


def denoised_report(results: list[dict], descriptions: dict[str, str], args, size,
                    pressure) -> str:
    """The RESULTS.md section of a ``--denoise`` run."""
    spp = " ".join(map(str, args.denoise_spp))
    worlds = f" --worlds {args.worlds}" if args.worlds else ""
    lines = [HEADING, "",
             f"`python benchmarks/bench_vs_cycles.py --denoise{worlds} --width "
             f"{size[0]} --denoise-spp {spp} --repeats {args.repeats} --frame-spp "
             f"{args.frame_spp}` — `{args.scene}`"
             + (f" and the generated worlds `{args.worlds}`" if args.worlds else "") + " "
             f"at {size[0]}×{size[1]}, max_depth {args.max_depth} (Cycles: "
             f"{args.max_depth - 2} bounces, shadow catcher, box filter, no adaptive "
             "sampling), ground truth "
             f"{args.frame_spp} spp (Mitsuba). Denoisers: onepass `denoise = oidn` (OIDN "
             "high, clean albedo/normal, I_m and I_r denoised separately and composited onto "
             "the photograph); Cycles' OpenImageDenoise (High, albedo + normal, accurate "
             "prefilter). Times are wall times of the whole render (arlight: the method call "
             "with its scene preparation, auxiliary buffers and OIDN; Cycles: the render call "
             "with synchronisation, denoising and EXR write). PSNR over the pixels that are "
             "not directly seen lights. CPU pressure (avg60, 2 shared cores) before/after: "
             f"{pressure[0] or 'n/a'} / {pressure[1] or 'n/a'} %.", "",
             "**Equal time**: for each Cycles + OIDN point, onepass + OIDN's PSNR at the same "
             "wall time (interpolated in log time between its own points; *≥*: Cycles took "
             "longer than onepass's slowest point, whose PSNR is shown — a lower bound; *no "
             "frame*: faster than onepass's fastest).",
             "", "| scene | Cycles + OIDN spp | time (s) | Cycles + OIDN PSNR (dB) | onepass + "
             "OIDN at that time (dB) | difference (dB) |", "|---|---|---|---|---|---|"]
    diffs = []
    for res in results:
        if "skip" in res:
            continue
        for k, (t, pc, po, how) in zip(args.denoise_spp, res["equal"], strict=True):
            d = po - pc
            if np.isfinite(d):
                diffs.append(d)
            cell = how if not np.isfinite(po) else f"{'≥ ' if how == '≥' else ''}{po:.2f}"
            dcell = "—" if not np.isfinite(d) else f"{'≥ ' if how == '≥' else ''}{d:+.2f}"
            lines.append(f"| {res['name']} | {k} | {t:.2f} | {pc:.2f} | {cell} | {dcell} |")
    if diffs:
        lines += ["", f"onepass + OIDN minus Cycles + OIDN at equal time: median "
                  f"{np.median(diffs):+.2f} dB, worst {min(diffs):+.2f} dB, best "
                  f"{max(diffs):+.2f} dB; onepass ahead at {sum(d > 0 for d in diffs)} of "
                  f"{len(diffs)} comparable points (≥ cells count with their lower bound)."]
    skipped = [r for r in results if "skip" in r]
    if skipped:
        lines += ["", "Skipped: " + "; ".join(f"{r['name']} — {r['skip']}" for r in skipped)
                  + "."]
    lines += ["", f"Points (mean wall seconds, mean PSNR dB); Cycles at spp {spp}, onepass at "
              f"{' '.join(map(str, arlight_spp(args.denoise_spp)))}:", ""]
    for res in results:
        for k in LABELS:
            if "pts" in res:
                lines.append(f"* {res['name']} {k}: "
                             + ", ".join(f"({t:.2f}, {p:.2f})" for t, p in res["pts"][k]))
    lines += ["", "Worlds:", ""]
    lines += [f"* {r['name']}: {descriptions.get(r['name'], '')}" for r in results]
    return "\n".join(lines)
