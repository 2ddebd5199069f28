"""Rohmer et al. 2015 (``nearfield``) on cornell-near-field at 960×540 (issue #17).

* **Fig. 11**: the same client renders five light models against the suite's path-traced
  ground truth — classical VPLs (Eq. 15) at several counts, VPLs on the direct atlas + SH
  indirect, clustered VPLs without split (τ = 1), ours (split + VALs + SH), PRT alone (τ = 0)
  — PSNR / FLIP (display) over the image and over the changed region, client time;
* **temporal coherence**: updates on fisheye images with 1 % radiance noise; mean VAL shift
  between updates and image flicker (``arlight.evaluate.metrics.temporal_flicker``);
* **server** stages next to Rohmer's Table 1 (GTX 580, 1024² atlas, 4 cameras);
* **client** frame at 960×540 with M = 16 on this machine's 2 cores, stage by stage.

The fisheye images are rendered once by Mitsuba's path tracer in the world (crate, tiled
wall: what real cameras would see) and cached in ``~/.cache/arlight/nearfield``; the server
gets the coarser proxy. Run: ``.venv/bin/python benchmarks/bench_nearfield.py [--write]
[--quick]``.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from results import cpu_pressure, publish  # noqa: E402

from arlight.cache import default_cache_dir  # noqa: E402
from arlight.evaluate.metrics import changed_region, image_metrics, temporal_flicker  # noqa: E402
from arlight.evaluate.suite import get_scene  # noqa: E402
from arlight.methods.nearfield import NearFieldClient  # noqa: E402
from arlight.nearfield.cameras import RigCamera, look_rotation  # noqa: E402
from arlight.nearfield.capture import capture, real_scene  # noqa: E402
from arlight.nearfield.pipeline import NearFieldServer, NearFieldSettings  # noqa: E402
from arlight.nearfield.state import NearFieldLight  # noqa: E402
from arlight.nearfield.vals import vpl_lights  # noqa: E402
from arlight.sphere.fisheye import FisheyeCamera  # noqa: E402
from arlight.synthetic import content_key  # noqa: E402

RIG = [  # name, position, look, up: four 180° fisheyes in the 2 m room (Table 1: 4 cameras)
    ("floor", (0.0, 0.3, 0.8), (0.0, 1.0, 0.0), (0.0, 0.0, -1.0)),
    ("high", (0.0, 1.8, 0.8), (0.0, -1.0, 0.0), (0.0, 0.0, -1.0)),
    ("left", (-0.8, 1.0, 0.6), (1.0, 0.0, -0.3), (0.0, 1.0, 0.0)),
    ("right", (0.8, 1.0, 0.6), (-1.0, 0.0, -0.3), (0.0, 1.0, 0.0)),
]
TABLE1 = {  # Rohmer Table 1, ms (GTX 580, 1024², 4 cameras, 4k samples, M = 16)
    "project (4 cameras: depth + projection)": 4 * (0.26 + 0.44),
    "combine": 0.58, "dilate": 1.33, "threshold": 9.1, "split": 0.53, "sampling": 6.67,
    "kmeans": 7.3, "integrate": 17.5,
}


def rig(size: int) -> list[RigCamera]:
    return [RigCamera(n, FisheyeCamera.equidistant((size, size), 180.0,
                                                   world_from_camera=look_rotation(lk, up)),
                      np.array(p, float)) for n, p, lk, up in RIG]


def captured(scene, cams, spp: int) -> list[np.ndarray]:
    """The rig's HDR images of the world (cached by content)."""
    h = hashlib.sha256(f"{content_key(scene, spp=16)}|{RIG}|{cams[0].size}|{spp}|v1".encode())
    path = default_cache_dir() / "nearfield" / f"capture-{h.hexdigest()[:24]}.npz"
    if path.exists():
        with np.load(path) as z:
            return [z[f"a{i}"] for i in range(len(cams))]
    mts = real_scene(scene.world)
    imgs = [capture(mts, c, spp, 1000 * i) for i, c in enumerate(cams)]
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **{f"a{i}": im for i, im in enumerate(imgs)})
    return imgs


def vpl_light(server: NearFieldServer, n: int, part: str, sh: np.ndarray,
              seed: int = 0) -> NearFieldLight:
    st = server.last
    rad = st.radiance if part == "all" else st.split.direct
    P, N, I, A = vpl_lights(server.position, server.normal, server.area, rad, n, seed)
    return NearFieldLight(P, N, I, A, sh)


def render_metrics(client, view, light, gt, transfer, region, repeats: int):
    times, layers = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        layers = client.render(view, light)
        times.append(time.perf_counter() - t0)
    m = image_metrics(layers.composite, gt, transfer)
    r = image_metrics(layers.composite, gt, transfer, region=region)
    return layers, {"psnr": m["psnr"], "flip": m["flip"], "psnr_region": r["psnr"],
                    "flip_region": r["flip"], "ms": 1e3 * float(np.median(times)),
                    "stages": {k[5:]: 1e3 * v for k, v in layers.stats.items()
                               if k.startswith("time_")}}


def val_shift(a: NearFieldLight, b: NearFieldLight) -> float:
    if not a.count or not b.count:
        return 0.0
    d = np.linalg.norm(a.positions[:, None] - b.positions[None], axis=2)
    return float(d.min(axis=1).mean())


STAGES = ["gbuffer", "indirect", "shadow_maps", "cull", "direct", "assemble"]


def client_budget(client, view, light: NearFieldLight, repeats: int = 5) -> dict:
    """Median stage and frame times (ms) of the client with the shadow maps rebuilt (a new
    light state) and reused (the same state)."""
    budgets = {}
    for case in ("new light state (maps rebuilt)", "same light state (maps reused)"):
        runs = []
        for _ in range(repeats):
            if case.startswith("new"):
                client.state.data.map_cache.clear()
            runs.append(client.render(view, light).stats)
        budgets[case] = ({s: 1e3 * float(np.median([b.get(f"time_{s}", 0.0) for b in runs]))
                          for s in STAGES},
                         1e3 * float(np.median([b["seconds"] for b in runs])))
    return budgets


def budget_table(budgets: dict, w: int, h: int) -> list[str]:
    """The client-frame table and its verdict against the ≤ 200 ms target."""
    out = [f"**Client frame** at {w}×{h}, M = 16, 2 CPU cores (median of 5; target "
           "≤ 200 ms)", "", "| case | " + " | ".join(STAGES) + " | frame |",
           "|" + "---|" * (len(STAGES) + 2)]
    for case, (bmed, bframe) in budgets.items():
        out.append(f"| {case} | " + " | ".join(f"{bmed[s]:.0f}" for s in STAGES)
                   + f" | **{bframe:.0f}** |")
    verdict = " / ".join("met" if f <= 200 else "not met" for _, f in budgets.values())
    out.append(f"\nTarget ≤ 200 ms: **{verdict}** (new / same light state). Load "
               f"average during the run: {os.getloadavg()[0]:.1f}; CPU pressure (PSI some "
               f"avg60): {cpu_pressure()} %.")
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--write", action="store_true", help="store the section in RESULTS.md")
    ap.add_argument("--quick", action="store_true", help="small images, few variants")
    ap.add_argument("--tau", type=float, default=0.6)
    ap.add_argument("--client-only", action="store_true",
                    help="only the client-frame table (printed, not stored)")
    args = ap.parse_args()
    q = args.quick
    suite = get_scene("cornell-near-field", quick=q)
    photo = suite.photo(spp=64 if q else 256)
    ar = suite.ar_scene(photo)
    view, gt, frame = ar.view, photo.ground_truth, photo.frame
    transfer = view.camera.transfer
    mask_gt = np.any(np.abs(gt - frame) > 0, axis=-1).astype(np.float32)
    region = changed_region(frame, gt, mask_gt)
    cams = rig(96 if q else 256)
    t0 = time.perf_counter()
    images = captured(suite.world, cams, 16 if q else 128)
    t_capture = time.perf_counter() - t0
    atlas = 256 if q else 1024
    out: list[str] = []

    def server_for(tau: float, m: int = 16) -> NearFieldServer:
        s = NearFieldServer(ar.world, cams, NearFieldSettings(atlas_resolution=atlas, tau=tau,
                                                              vals=m))
        s.update(images)
        return s

    # ---------------------------------------------------------------- server, Table 1
    srv = server_for(args.tau)
    runs = []
    for _ in range(2 if q else 5):
        srv.update(images)
        runs.append(dict(srv.stats))
    med = {k: float(np.median([r[k] for r in runs])) for k in runs[0]}
    proj = sum(v for k, v in med.items() if k.startswith("project_"))
    ours_rows = {"project (4 cameras: depth + projection)": proj,
                 **{k: med[k] for k in ("combine", "dilate", "threshold", "split", "sampling",
                                        "kmeans", "integrate")}}
    total = sum(ours_rows.values())
    sh_ms = med["sh"]

    # ---------------------------------------------------------------- Fig. 11
    client = NearFieldClient(ar.world, {"shadows": "maps"})
    ours = srv.light
    if args.client_only:
        client.render(view, ours)  # warm-up (kernel compilation)
        print("\n".join(budget_table(client_budget(client, view, ours),
                                      view.camera.width, view.camera.height)))
        return
    zero_sh = np.zeros_like(ours.sh)
    prt_only = server_for(0.0).light
    clustered = server_for(1.0).light
    variants: list[tuple[str, NearFieldLight]] = []
    counts_all = (16, 64) if q else (16, 64, 256, 512)
    counts_dir = (16, 64) if q else (16, 64, 256)
    for n in counts_all:
        variants.append((f"(1) VPLs, Eq. 15, N = {n}", vpl_light(srv, n, "all", zero_sh)))
    for n in counts_dir:
        variants.append((f"(2) VPLs on direct atlas + SH, N = {n}",
                         vpl_light(srv, n, "direct", ours.sh)))
    variants.append(("(3) clustered VPLs without split (τ = 1), M = 16", clustered))
    variants.append((f"(4) ours: split τ = {args.tau:g} + 16 VALs + SH", ours))
    for tau in ((0.9,) if q else (0.5, 0.75, 0.9, 0.98)):
        variants.append((f"(4) ours, τ = {tau:g}", server_for(tau).light))
    variants.append(("(4) ours, M = 64", server_for(args.tau, 64).light))
    variants.append(("(5) PRT alone (τ = 0: SH only)", prt_only))
    f_all = image_metrics(frame, gt, transfer)
    f_reg = image_metrics(frame, gt, transfer, region=region)
    rows = [("frame unchanged (no virtual object)", {"psnr": f_all["psnr"],
                                                     "flip": f_all["flip"],
                                                     "psnr_region": f_reg["psnr"],
                                                     "flip_region": f_reg["flip"], "ms": 0.0,
                                                     "stages": {}})]
    client.render(view, ours)  # warm-up (kernel compilation)
    for name, light in variants:
        reps = 3 if light.count <= 64 else 1
        _, m = render_metrics(client, view, light, gt, transfer, region, reps)
        rows.append((f"{name} ({light.count} lights)", m))
        print(name, {k: v for k, v in m.items() if k != "stages"}, flush=True)

    budgets = client_budget(client, view, ours)

    # ---------------------------------------------------------------- temporal coherence
    frames = 4 if q else 8
    rng = np.random.default_rng(11)
    noisy = [[im * (1 + 0.01 * rng.standard_normal(im.shape)).astype(np.float32)
              for im in images] for _ in range(frames)]
    coh = {}
    for label, tau, cold, vpl in (("ours (warm-started k-means)", args.tau, False, 0),
                                  ("ours without warm start", args.tau, True, 0),
                                  ("clustered, τ = 1", 1.0, False, 0),
                                  ("VPLs on direct atlas + SH, N = 64", args.tau, False, 64)):
        s = server_for(tau)
        lights, comps = [], []
        for imgs in noisy:
            if cold:
                s.centres = None
            lt = s.update(imgs)
            if vpl:
                lt = vpl_light(s, vpl, "direct", lt.sh)
            lights.append(lt)
            comps.append(client.render(view, lt).composite)
        shift = np.mean([val_shift(a, b) for a, b in zip(lights[1:], lights[:-1],
                                                          strict=True)])
        reg = region[..., None] if region is not None else 1.0
        flick = temporal_flicker(np.asarray(comps) * reg)
        coh[label] = (1e3 * shift, flick / max(float(np.mean(np.asarray(comps) * reg)), 1e-12))
        print(label, coh[label], flush=True)

    # ---------------------------------------------------------------- report
    w, h = view.camera.width, view.camera.height
    out.append(f"## nearfield (Rohmer 2015): cornell-near-field, {w}×{h}")
    out.append("")
    out.append(f"`benchmarks/bench_nearfield.py{' --quick' if q else ''}`. Four 180° "
               f"equidistant fisheyes of {cams[0].size[0]}² px rendered in the world "
               f"(crate and tiled wall, {16 if q else 128} paths per pixel, "
               f"{t_capture:.0f} s incl. cache); the server gets the proxy; atlas "
               f"{atlas}², {srv.layout.charts} charts; ground truth: the suite's path-traced "
               "frame. PSNR / FLIP on the display image (sRGB), whole frame and changed "
               "region (where the ground truth differs from the frame). Client: "
               "`NearFieldClient` with two 128² shadow maps per light, 1 G-buffer sample.")
    out.append("")
    out.append("**Fig. 11 comparison** (same client; time = client frame, median)")
    out.append("")
    out.append("| light model | PSNR | FLIP | PSNR region | FLIP region | client ms |")
    out.append("|---|---|---|---|---|---|")
    for name, m in rows:
        out.append(f"| {name} | {m['psnr']:.2f} | {m['flip']:.4f} | {m['psnr_region']:.2f} | "
                   f"{m['flip_region']:.4f} | {m['ms']:.0f} |")
    out.append("")
    out.append("**Temporal coherence** (1 % Gaussian radiance noise per fisheye pixel, "
               f"{frames} updates; VAL shift = mean distance of a light to the nearest light "
               "of the previous update; flicker = mean |frame-to-frame change| of the "
               "composite in the changed region / its mean)")
    out.append("")
    out.append("| light model | mean VAL shift (mm) | relative flicker |")
    out.append("|---|---|---|")
    tex = 1e3 * srv.layout.texel_size
    for k, (sh, fl) in coh.items():
        out.append(f"| {k} | {sh:.2f} | {fl:.2e} |")
    out.append(f"\nAtlas texel width: {tex:.1f} mm.")
    out.append("")
    out.append(f"**Server update** (τ = {args.tau:g}, M = 16, 4096 samples, 20 iterations; "
               "median of the warm updates; ms) next to Rohmer's Table 1 (GTX 580)")
    out.append("")
    out.append("| step | arlight (NumPy + Mitsuba, 2 CPU cores) | Rohmer Table 1 |")
    out.append("|---|---|---|")
    for k, v in ours_rows.items():
        out.append(f"| {k} | {v:.1f} | {TABLE1[k]:.2f} |")
    out.append(f"| **sum** | **{total:.0f}** | **{sum(TABLE1.values()):.1f}** |")
    out.append(f"| SH cube maps ({srv.probes.cube_maps} × 6×32², projection) | {sh_ms:.1f} | "
               "(Fig. 12, not in the sum) |")
    out.append(f"\nAtlas geometry (once per proxy): {srv.stats_static['atlas_geometry']:.0f} "
               f"ms. Payload per update: {32 * ours.count + 108 * ours.n_objects} B "
               "(32 M + 108 n_obj).")
    out.append("")
    out += budget_table(budgets, w, h)
    publish("\n".join(out), args.write)


if __name__ == "__main__":
    main()
