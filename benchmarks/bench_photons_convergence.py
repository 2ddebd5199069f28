"""Convergence of progressive photon mapping on glass-ring with Kán's point light.

Ground truth: the glass-ring *world* with its 6 cm area light replaced by a light
``type = "sphere"`` of radius 1 cm (:data:`BULB`) at the same centre and the same intensity
(radiance ``I/(πr²)``), rendered by Mitsuba's ``path`` (:func:`arlight.synthetic.synthesize`) at
``--gt-spp``; path tracing forms the bulb's caustic through the glass sphere (slowly). The
method gets the glass-ring *proxy* with a point light there (what a light estimate gives)
and renders ``onepass`` with ``caustics = "photons"``, PPM with K = 1, 4, 16, 64 maps of
``--photons`` photons each (first radius 8 mm, α = 0.7), plus ``caustics = "none"``.
``reproject = false`` for all (camera-image reprojection ignores the sphere's own shadow on
the table seen through it, a bias of its own; docs/methods/photons.md).

Error, over the caustic's pixels (see :func:`table`): the fraction of the ground truth's
caustic energy captured, and the bias RMSE (both images' variances subtracted).

    python benchmarks/bench_photons_convergence.py --write
"""

from __future__ import annotations

import argparse
import tomllib

import numpy as np
from results import publish

from arlight.evaluate.suite import scenes_dir
from arlight.methods import RenderSettings, get_method
from arlight.scene.load import parse_scene
from arlight.synthetic import synthesize

HEADING = "## Progressive photon mapping: convergence on glass-ring (issue 15)"
CENTRE = [-0.25, 0.55, 0.25]
INTENSITY = [2.016, 1.98, 1.872]  # the area light's on-axis intensity L·A, W/sr
BULB = 0.01
"""Radius of the ground truth's sphere light, m. Its image through the ball lens is
~1.5 mm (magnification ≈ 0.15), below a pixel (~4 mm on the table at 160×120). A 2 mm bulb
gives no usable ground truth: at 2048 spp Mitsuba's `path` found no caustic path at all
(the probability of reaching the bulb through the glass falls as r²)."""


def scenes(width: int):
    folder = scenes_dir() / "glass-ring"
    out = []
    for name, light in (("world", {"type": "sphere", "position": CENTRE, "radius": BULB,
                                   "intensity": INTENSITY}),
                        ("proxy", {"type": "point", "position": CENTRE,
                                   "intensity": INTENSITY})):
        data = tomllib.loads((folder / f"{name}.toml").read_text(encoding="utf-8"))
        data["lights"] = [light] + [x for x in data["lights"] if x["type"] != "area"]
        sc = parse_scene(data, base_dir=folder, file=f"glass-ring {name} + {light['type']}")
        w, h = sc.resolution
        out.append(sc.resized(width, width * h // w))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=160)
    ap.add_argument("--gt-spp", type=int, default=8192)
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--photons", type=int, default=50_000)
    ap.add_argument("--write", action="store_true")
    args = ap.parse_args()
    world, proxy = scenes(args.width)
    ph = synthesize(world, spp=args.gt_spp, batches=16, progress=True)
    scene = proxy.with_frame(ph.frame)
    one = get_method("onepass")
    imgs = {}
    for k in (0, 1, 4, 16, 64):
        opts = {"reproject": False}
        if k:
            opts.update(caustics="photons", photons=args.photons, photon_radius=0.008,
                        ppm_iterations=k)
        lay = one(scene, RenderSettings(spp=args.spp, seed=3, options=opts))
        imgs[k] = (lay.composite.astype(np.float64), lay.stderr["composite"].astype(np.float64),
                   lay.stats.get("time_photons", 0.0) + lay.stats.get("time_photon_index", 0.0))
        print(k, "done", flush=True)
    publish(table(imgs, ph, world, args), args.write)


def table(imgs: dict, ph, world, args) -> str:
    """Caustic pixels C: where the largest-K render exceeds the render without caustics by
    more than 5 % of its peak (chosen from the method's images, not from the noisy ground
    truth). Per K: the caustic energy captured, Σ_C (I_K − I_none) / Σ_C (GT − I_none) with
    its standard error (from the ground truth's), and the bias RMSE over C (mean squared
    error minus both images' variances)."""
    base, base_se, _ = imgs[0]
    kmax = max(imgs)
    gain = (imgs[kmax][0] - base).mean(axis=2)
    caustic = gain > 0.05 * gain.max()
    gt, gt_se = ph.ground_truth.astype(np.float64), ph.ground_truth_stderr.astype(np.float64)
    ref = float((gt - base)[caustic].sum())
    ref_se = float(np.sqrt((np.square(gt_se) + np.square(base_se))[caustic].sum()))
    lines = [HEADING, "",
             f"`python benchmarks/bench_photons_convergence.py` — glass-ring at "
             f"{world.camera.width}×{world.camera.height}; ground truth: the world with a "
             f"{BULB * 1000:.0f} mm sphere light (Mitsuba `path`, {args.gt_spp} spp); "
             f"method: the proxy with the point light, `onepass` {args.spp} spp, "
             f"`reproject = false`, {args.photons:,} "
             "photons per map, PPM radius 8 mm → h_K, α = 0.7. Caustic pixels C "
             f"({int(caustic.sum())} px): where the K = {kmax} render exceeds the render without "
             "caustics by > 5 % of its peak. Captured = Σ_C (I_K − I_none) / Σ_C (GT − I_none) "
             f"(ground truth's caustic energy in C: {ref:.2f} ± {ref_se:.2f}); bias RMSE over C "
             "= sqrt(MSE − both images' variance).", "",
             "| maps K | last radius (mm) | photons in all | captured | bias RMSE over C | "
             "t_p + t_b (s) |", "|---|---|---|---|---|---|"]
    for k, (img, se, sec) in imgs.items():
        d = img - gt
        var = np.square(se) + np.square(gt_se)
        mse = float(np.mean((np.square(d) - var)[caustic]))
        cap = float((img - base)[caustic].sum()) / ref if k else 0.0
        cap_se = abs(cap) * ref_se / abs(ref) if k else 0.0
        r = 8.0
        for i in range(1, k):
            r *= np.sqrt((i + 0.7) / (i + 1))
        lines.append(f"| {k or 'none'} | {f'{r:.2f}' if k else '—'} | "
                     f"{k * args.photons:,} | {cap:.3f} ± {cap_se:.3f} | "
                     f"{np.sqrt(max(mse, 0.0)):.4f} | {sec:.2f} |")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
