"""Benchmark: one-pass differential path tracing (``onepass``) against ``reference``.

For each scene (the demo and the Kán Fig. 4.5 glass-ring scene of the evaluation suite):

1. ground truth: ``reference`` composite at ``--gt-spp`` (its own per-pixel standard error
   is subtracted from the squared errors below);
2. ``reference`` at 64 spp: time ``t_ref`` and composite RMSE ``e_ref``;
3. ``onepass`` at 64 spp: time ``t_one`` and RMSE ``e_one``. Monte Carlo error falls as
   1/√spp, so onepass reaches ``e_ref`` after ``64 · (e_one/e_ref)²`` spp, i.e. in
   ``t_one · (e_one/e_ref)²`` seconds. The figure of merit is that time over ``t_ref``
   (target ≤ 0.65). Each RMSE is the root of the *mean* squared error over the repeats
   (per-seed RMSEs of the glass scene scatter by ±30 % from caustic fireflies);
4. rays per sample of onepass and of the same tracer in two-pass mode (what ``reference``
   traces: one radiance + one shadow ray per vertex per solution), and samples per second
   of Mitsuba's own ``path`` integrator on the mixed view;
5. the profile of onepass's two phases: fraction of samples that fork (hit a virtual
   object, continued by phase 2) and the share of the tracer's time spent in phase 2.

Timings are medians of ``--repeats`` warm runs, interleaved, in one process. ``onepass``
runs with ``reproject=False`` so both methods converge to the same image (camera-image
reprojection replaces proxy shading by the frame, a different — noisier-frame — estimate).

    python benchmarks/bench_onepass.py --quick --write   # 160×120 (the machine is slow)
    python benchmarks/bench_onepass.py --write           # 640×480
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
from results import publish

from arlight.methods import RenderSettings, get_method
from arlight.scene.model import ARScene

HEADING = "## One-pass differential path tracing (issue 3)"


def scaled(scene: ARScene, factor: int) -> ARScene:
    """The scene at 1/factor resolution (intrinsics scaled; frame box-filtered)."""
    w, h = scene.resolution
    return scene.resized(w // factor, h // factor) if factor > 1 else scene


def load_scenes(factor: int, frame_spp: int) -> dict[str, ARScene]:
    from arlight.demo import demo_scene_path
    from arlight.evaluate.suite import get_scene
    from arlight.scene.load import load_scene
    from arlight.synthetic import synthesize

    demo = scaled(load_scene(demo_scene_path()), factor)
    ring = get_scene("glass-ring", quick=False)
    world = scaled(ring.world, factor)
    photo = synthesize(world, spp=frame_spp, seed=1)
    proxy = scaled(ring.proxy, factor)
    return {"demo": demo, "glass-ring": proxy.with_frame(photo.frame)}


def mse_corrected(img: np.ndarray, gt: np.ndarray, gt_se: np.ndarray) -> float:
    """MSE against the ground truth with the ground truth's own variance removed."""
    return float(np.mean(np.square(img.astype(np.float64) - gt)) - np.mean(np.square(gt_se)))


def rmse_of(mses: list[float]) -> float:
    """RMSE from the mean of per-repeat MSEs (clamped at 0)."""
    return float(np.sqrt(max(statistics.fmean(mses), 0.0)))


def mse_ratio(num: list[float], den: list[float]) -> tuple[float, float]:
    """Ratio of mean MSEs and its standard error (delta method, independent repeats)."""
    mn, md = statistics.fmean(num), statistics.fmean(den)
    rel = [statistics.stdev(x) / np.sqrt(len(x)) / abs(m) if len(x) > 1 and m else 0.0
           for x, m in ((num, mn), (den, md))]
    r = mn / md
    return r, r * float(np.hypot(*rel))


def path_throughput(scene: ARScene, spp: int) -> float:
    """Samples per second of Mitsuba's ``path`` integrator on the mixed view alone."""
    from arlight.backend.mitsuba_scene import build_views
    from arlight.backend.passes import run_passes
    from arlight.methods.reference import path_integrator, trace_radiance

    views = build_views(scene)
    integ = path_integrator(RenderSettings())

    def kernel(rays, pixel, seed, lanes):
        return {"L": trace_radiance(integ, views.mixed, rays, seed, lanes)}

    res = run_passes(scene.camera, spp, kernel, seed=3)
    return res.lanes / res.seconds


def bench_scene(name: str, scene: ARScene, gt_spp: int, repeats: int) -> dict:
    ref_fn, one_fn = get_method("reference"), get_method("onepass")
    opts = {"reproject": False}
    print(f"[{name}] {scene.camera.width}x{scene.camera.height}: ground truth {gt_spp} spp…",
          flush=True)
    gt = ref_fn(scene, RenderSettings(spp=gt_spp, seed=1000))
    gt_img, gt_se = gt.composite.astype(np.float64), gt.stderr["composite"]
    one_fn(scene, RenderSettings(spp=1, options=opts))  # warm the kernel caches
    ref_fn(scene, RenderSettings(spp=1))
    t_ref, t_one, e_ref, e_one, t_path, fork, ph2 = [], [], [], [], [], [], []
    for r in range(repeats):
        ref = ref_fn(scene, RenderSettings(spp=64, seed=r + 1))
        one = one_fn(scene, RenderSettings(spp=64, seed=r + 101, options=opts))
        t_ref.append(ref.stats["seconds"])
        t_one.append(one.stats["seconds"])
        e_ref.append(mse_corrected(ref.composite, gt_img, gt_se))
        e_one.append(mse_corrected(one.composite, gt_img, gt_se))
        fork.append(one.stats["forked_fraction"])
        ph2.append(one.stats["phase2_seconds"] / (one.stats["phase1_seconds"]
                                                  + one.stats["phase2_seconds"]))
        t_path.append(path_throughput(scene, 16))
    two = one_fn(scene, RenderSettings(spp=16, seed=7, options={**opts, "mode": "twopass"}))
    one16 = one_fn(scene, RenderSettings(spp=16, seed=7, options=opts))
    med = statistics.median
    samples = scene.camera.width * scene.camera.height * 64
    mse_r, mse_se = mse_ratio(e_one, e_ref)
    t_equal = med(t_one) * rmse_of(e_one) ** 2 / max(rmse_of(e_ref) ** 2, 1e-30)
    row = {"scene": name, "res": f"{scene.camera.width}×{scene.camera.height}",
           "t_ref": med(t_ref), "t_one": med(t_one), "e_ref": rmse_of(e_ref),
           "e_one": rmse_of(e_one),
           "t_equal": t_equal, "ratio": t_equal / med(t_ref), "t_ratio": med(t_one) / med(t_ref),
           "mse_r": mse_r, "mse_se": mse_se,
           "rps_one": one16.stats["rays_per_sample"], "rps_two": two.stats["rays_per_sample"],
           "ms_ref": samples / med(t_ref) / 1e6, "ms_one": samples / med(t_one) / 1e6,
           "ms_path": med(t_path) / 1e6, "forked": med(fork), "phase2": med(ph2)}
    print(f"[{name}] " + ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"
                                   for k, v in row.items()), flush=True)
    return row


def table(rows: list[dict], args) -> str:
    import mitsuba as mi

    lines = [HEADING, "",
             f"`python benchmarks/bench_onepass.py {'--quick ' if args.quick else ''}"
             f"{f'--repeats {args.repeats} ' if args.repeats != 5 else ''}--write` "
             f"({mi.variant()}, 2 shared CPU cores; ground truth = reference composite at "
             f"{args.gt_spp} spp; times are medians of {args.repeats} interleaved warm runs, RMSEs "
             "the root of their mean squared error; onepass with `reproject=False`).", "",
             "| scene | res | reference 64 spp: s / RMSE | onepass 64 spp: s / RMSE | onepass "
             "time to reference's RMSE (s) | **time ratio** (target ≤ 0.65) | rays/sample "
             "onepass / two-pass | Msamples/s reference / onepass / Mitsuba `path` | forked "
             "samples | phase 2 share of tracer time | time ratio at equal spp | MSE ratio "
             "onepass / reference (± SE) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['scene']} | {r['res']} | {r['t_ref']:.2f} / {r['e_ref']:.4g} | "
                     f"{r['t_one']:.2f} / {r['e_one']:.4g} | {r['t_equal']:.2f} | "
                     f"**{r['ratio']:.2f}** | {r['rps_one']:.2f} / {r['rps_two']:.2f} | "
                     f"{r['ms_ref']:.2f} / {r['ms_one']:.2f} / {r['ms_path']:.2f} | "
                     f"{100 * r['forked']:.1f} % | {100 * r['phase2']:.0f} % | "
                     f"{r['t_ratio']:.2f} | {r['mse_r']:.2f} ± {r['mse_se']:.2f} |")
    lines += ["", "Time to equal error = onepass time × (RMSE_onepass / RMSE_reference)² "
              "(error ∝ 1/√spp); with the MSE ratio's standard error in view, a ratio within "
              "2 SE of 1 means the two estimators are equally noisy per sample and the time "
              "ratio at equal spp is the better figure. Two-pass rays/sample = the same tracer "
              "run once per view (one radiance + one shadow ray per vertex per solution, as "
              "Mitsuba's `path` does for `reference`). RMSEs have the ground truth's own "
              "variance removed.", ""]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="160×120 instead of 640×480")
    ap.add_argument("--gt-spp", type=int, default=None, help="ground-truth spp")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--write", action="store_true", help="update benchmarks/RESULTS.md")
    args = ap.parse_args()
    factor = 4 if args.quick else 1
    args.gt_spp = args.gt_spp or (1024 if args.quick else 512)
    t0 = time.perf_counter()
    rows = [bench_scene(n, s, args.gt_spp, args.repeats)
            for n, s in load_scenes(factor, 256).items()]
    publish(table(rows, args), args.write)
    print(f"total {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
