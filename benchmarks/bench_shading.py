"""Benchmark: ``ibl`` and ``prt`` frame times (issue 13) next to Franke's Table 4.1, AR-OOF
lookup time, PRT precomputation per vertex, and PSNR against ``onepass`` at the same wall time.

Scenes: the suite's outdoor-env (HDR sky and sun, bunny + steel ring) and bunny-box (area
light, bunny + box), 640×480, photographs synthesised by Mitsuba (64 spp, cached) so that
PSNR is against the ground truth. Every frame is rendered from the prepared state after a
warm-up frame (kernel compilation); medians over ``--repeats`` rounds of ``--block``
consecutive frames per method. ``onepass`` at the same wall time: the samples per pixel whose
frame time is closest to the method's median frame (at least 1 spp). The AR-OOF lookup is
timed alone on the real pixels of the frame (its kernel plus the per-light tables, which are
reused while the light stays). The PRT precomputation is timed by calling it directly
(no cache). PSNR is that of ``arlight eval``: display images, peak 1. Usage:

    python benchmarks/bench_shading.py [--repeats 5] [--block 3] [--write]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import drjit as dr
import mitsuba as mi
import numpy as np
from results import cpu_pressure, publish

from arlight.evaluate.metrics import display, psnr
from arlight.evaluate.suite import get_scene
from arlight.methods import RenderSettings, get_method
from arlight.synthetic import synthesize

HEADING = "## Shading virtual objects: ibl, prt and AR-OOF (issue 13)"
SCENES = ("outdoor-env", "bunny-box")
TARGETS = {"prt": 20.0, "ibl": 150.0}  # ms per frame of shading (issue 13)
FRANKE_4_1 = {"ibl": 1.292, "prt": 0.02}  # ms at 480p, GTX 780 (thesis Table 4.1)


def display_psnr(img: np.ndarray, gt: np.ndarray, transfer) -> float:
    """PSNR (dB) of the display images (the camera's exposure and transfer, peak 1), as
    ``arlight eval`` reports it (linear HDR PSNR is ruled by a few sun-glint pixels)."""
    return psnr(display(img, transfer), display(gt, transfer), peak=1.0)


def frames(method, state, view, settings, n: int) -> list[dict]:
    return [method.render(state, view, settings).stats for _ in range(n)]


def onepass_at(scene, seconds: float, gt: np.ndarray) -> tuple[int, float, float]:
    """(spp, frame seconds, PSNR dB) of ``onepass`` with the frame time nearest ``seconds``."""
    m = get_method("onepass")
    st = m.prepare(scene.world, RenderSettings(spp=1))
    m.render(st, scene.view, RenderSettings(spp=1))
    t1 = statistics.median(m.render(st, scene.view, RenderSettings(spp=1)).stats["seconds"]
                           for _ in range(3))
    spp = max(1, int(round(seconds / max(t1, 1e-9))))
    out = m.render(st, scene.view, RenderSettings(spp=spp, seed=1))
    return spp, out.stats["seconds"], display_psnr(out.composite, gt, scene.camera.transfer)


def oof_lookup_ms(data, gb_stats_view, repeats: int) -> tuple[float, int]:
    """Median ms of the occlusion-field lookup on the frame's real lanes, and their count."""
    from arlight.realtime.gbuffer import render_gbuffer

    gb = render_gbuffer(data.views.mixed, gb_stats_view.camera)
    real = dr.compress(gb.valid & ~gb.virtual)
    p = dr.gather(mi.Point3f, gb.position, real)
    n = dr.gather(mi.Vector3f, gb.normal, real)
    dr.eval(p, n)
    amb = data.lights.ambient_sh
    data.field.occluded_irradiance(amb, p, n)  # compile, tables
    times = []
    for _ in range(repeats):
        dr.sync_thread()
        t = time.perf_counter()
        e = data.field.occluded_irradiance(amb, p, n)
        dr.eval(e)
        dr.sync_thread()
        times.append(time.perf_counter() - t)
    near = int(dr.count(dr.norm(p - mi.Point3f(*[float(x) for x in data.field.centre]))
                        < data.field.r_max)[0])
    return statistics.median(times) * 1e3, near


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5, help="rounds over the methods")
    ap.add_argument("--block", type=int, default=3, help="consecutive frames per round")
    ap.add_argument("--write", action="store_true", help="store the section in RESULTS.md")
    args = ap.parse_args()

    rows, oof_rows, pre_rows, verdicts = [], [], [], []
    for name in SCENES:
        s = get_scene(name, quick=False)
        ph = synthesize(s.world, spp=64, batches=16)
        scene = s.ar_scene(ph)
        gt = ph.ground_truth
        states = {}
        for m in ("ibl", "prt"):
            method = get_method(m)
            settings = RenderSettings(options={"cache": False} if m == "prt" else {})
            t = time.perf_counter()
            state = method.prepare(scene.world, settings)
            prep = time.perf_counter() - t
            method.render(state, scene.view, settings)  # warm-up
            states[m] = (method, state, settings, prep)
        stats = {m: [] for m in states}
        for _ in range(args.repeats):
            for m, (method, state, settings, _) in states.items():
                stats[m] += frames(method, state, scene.view, settings, args.block)
        for m, (method, state, settings, prep) in states.items():
            def med(key: str, runs: list[dict] = stats[m]) -> float:
                return statistics.median(x.get(key, 0.0) for x in runs) * 1e3
            layers = method.render(state, scene.view, settings)
            q = display_psnr(layers.composite, gt, scene.camera.transfer)
            frame = med("seconds")
            spp, t_op, q_op = onepass_at(scene, frame / 1e3, gt)
            rows.append(f"| {name} | {m} | {med('time_gbuffer'):.1f} | "
                        f"{med('time_shade_virtual'):.1f} | {med('time_shade_real'):.1f} | "
                        f"{med('time_assemble'):.1f} | **{frame:.1f}** | {q:.2f} | "
                        f"{spp} spp, {t_op * 1e3:.0f} ms: {q_op:.2f} |")
            shading = med("time_shade_virtual")
            verdicts.append(f"{m} on {name}: virtual shading {shading:.1f} ms, frame "
                            f"{frame:.0f} ms (target ≤ {TARGETS[m]:.0f} ms per frame of "
                            f"shading: **{'met' if frame <= TARGETS[m] else 'not met'}** for "
                            f"the whole frame, **{'met' if shading <= TARGETS[m] else 'not met'}"
                            "** for the virtual shading stage)")
            if m == "prt":
                from arlight.realtime.prt_shading import object_mesh
                from arlight.realtime.prt_transfer import precompute

                loaded = {sh.id(): sh for sh in state.data.views.mixed.scene.shapes()}
                n_v, secs = 0, 0.0
                for o in state.data.objects:
                    mesh, _ = object_mesh(scene.world.shapes[o.shape], loaded[str(o.shape)])
                    t = precompute(mesh, state.options.order, state.options.directions)
                    n_v, secs = n_v + t.vertices, secs + t.seconds
                pre_rows.append(f"| {name} | {n_v} | {secs:.2f} | {1e6 * secs / n_v:.0f} | "
                                f"{prep:.2f} |")
            if m == "ibl" and state.data.field is not None:
                ms, near = oof_lookup_ms(state.data, scene.view, 3 * args.repeats)
                oof_rows.append(f"| {name} | {near} | {ms:.1f} | "
                                f"{'met' if ms <= 30 else 'not met'} |")
    text = "\n".join([
        HEADING, "",
        f"`python benchmarks/bench_shading.py --repeats {args.repeats} --block {args.block}`; "
        f"640×480, {os.cpu_count()} CPU threads (shared), Mitsuba llvm_ad_rgb, default options "
        "(ibl: SH order 2, split-sum GGX (64 prefilter samples), 16 AO rays, bounce probe; "
        "prt: order 2, 512 rays per vertex, local lights per pixel, bounce probe; "
        "AR-OOF order 4, 24 shells, 1024 rays per sample); medians of "
        f"{args.repeats} × {args.block} warm frames; PSNR (dB) of the composite against the "
        "synthetic ground truth (display images, as `arlight eval`); `onepass` at the spp whose "
        "frame time is nearest (1 spp when even that is slower than the method).", "",
        "| scene | method | G-buffer | virtual shading | real shading (shadows, AR-OOF) | "
        "assemble | frame | PSNR | onepass at that time |", "|---|---|---|---|---|---|---|---|---|",
        *rows, "",
        f"Franke Table 4.1 (GTX 780, 480p, sphere covering the screen): dynamic "
        f"{FRANKE_4_1['ibl']} ms, precomputed {FRANKE_4_1['prt']} ms.", "",
        "AR-OOF lookup alone (kernel on the real lanes inside the outermost shell; target "
        "≤ 30 ms):", "", "| scene | lanes inside | ms | target |", "|---|---|---|---|",
        *oof_rows, "",
        "PRT precomputation (no cache): ", "",
        "| scene | vertices | seconds | µs per vertex | prepare (s, incl. views, AR-OOF) |",
        "|---|---|---|---|---|", *pre_rows, "",
        *[f"- {v}" for v in verdicts], "",
        f"Load average during the run: {os.getloadavg()[0]:.1f}; CPU pressure (PSI some avg60): "
        f"{cpu_pressure() or 'n/a'} %.",
    ])
    publish(text, args.write)


if __name__ == "__main__":
    main()
