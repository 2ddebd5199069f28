"""Benchmark: differential caustic photon mapping (``onepass``, ``caustics = "photons"``).

Kán's Table 5.2 reports, per frame, photon shooting ``t_p``, kd-tree build ``t_b`` and the
camera pass with density estimation ``t_r`` (GTX 590, OptiX, 720×576). This script measures
the same three stages of ``onepass`` on the glass-ring proxy with Kán's point light in place
of its area light (640×480, 1 spp) for 100K, 300K and 1M emitted photons, all in
one process (best of ``--repeats`` warm runs: the two cores are shared with other jobs, so
the minimum is the least disturbed; compare ratios):

* ``t_p`` = ``time_photons`` (emission toward the generators + tracing in ρ, retrace in µ),
* ``t_b`` = ``time_photon_index`` (hash grid: keys in Dr.Jit, stable NumPy sort, tables),
* ``t_r`` = ``time_trace`` (one-pass path tracing + caustic walk + density estimation), and
  ``t_r0`` the same frame without caustics, so ``t_r − t_r0`` is the caustic gather.

Index choice (the issue asks to measure it): on the same stored photons and the same
gather points (first non-delta camera hits), the Dr.Jit hash grid (build ``t_b``, query =
kernel sums at every point) against ``scipy.spatial.cKDTree`` (build, then
``query_ball_point`` with 2 workers and the kernel sums in NumPy).

    python benchmarks/bench_photons.py --write            # 640×480
    python benchmarks/bench_photons.py --quick            # 160×120, 30K/100K photons
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from results import publish

from arlight.methods import RenderSettings, get_method
from arlight.scene.model import ARScene

HEADING = "## Differential caustic photon mapping (issue 15)"
KAN = {100_000: (20, 31, 24), 1_000_000: (167, 619, 45)}  # Glass Monkey, 1 rpp, ms


POINT_LIGHT = {"type": "point", "position": [-0.25, 0.55, 0.25],
               "intensity": [2.016, 1.98, 1.872]}
"""Kán's point light in place of glass-ring's 6 cm area light: same centre, the area light's
on-axis intensity L·A (W/sr)."""


def load_scene(factor: int) -> ARScene:
    """The glass-ring proxy with Kán's point light (:data:`POINT_LIGHT`) and a flat grey
    frame (timing only)."""
    import tomllib

    from arlight.evaluate.suite import scenes_dir
    from arlight.scene.load import parse_scene

    folder = scenes_dir() / "glass-ring"
    data = tomllib.loads((folder / "proxy.toml").read_text(encoding="utf-8"))
    data["lights"] = [POINT_LIGHT] + [x for x in data["lights"] if x["type"] != "area"]
    proxy = parse_scene(data, base_dir=folder, file="glass-ring proxy + point light")
    w, h = proxy.resolution
    if factor > 1:
        proxy = proxy.resized(w // factor, h // factor)
    w, h = proxy.resolution
    return proxy.with_frame(np.full((h, w, 3), 0.2, np.float32))


def stage_times(scene: ARScene, photons: int, repeats: int) -> dict[str, float]:
    one = get_method("onepass")
    opts = {"caustics": "photons", "photons": photons, "photon_radius": 0.004}
    one(scene, RenderSettings(spp=1, options=opts))  # warm the kernel caches
    rows = []
    for r in range(repeats):
        lay = one(scene, RenderSettings(spp=1, seed=r + 1, options=opts))
        base = one(scene, RenderSettings(spp=1, seed=r + 1))
        rows.append({"t_p": lay.stats["time_photons"], "t_b": lay.stats["time_photon_index"],
                     "t_r": lay.stats["time_trace"], "t_r0": base.stats["time_trace"],
                     "stored": lay.stats["photons_stored"],
                     "emitted": lay.stats["photons_emitted"]})
    out = {k: min(r[k] for r in rows) for k in rows[0]}  # best of: the cores are shared
    print(f"[{photons}] " + ", ".join(f"{k}={v:.4g}" for k, v in out.items()), flush=True)
    return out


def index_comparison(scene: ARScene, photons: int, radius: float = 0.004) -> dict[str, float]:
    """Hash grid vs cKDTree on the same photons and gather points (seconds)."""
    import drjit as dr
    import mitsuba as mi
    from scipy.spatial import cKDTree

    from arlight.backend.camera_rays import generate_rays
    from arlight.methods import photons as P
    from arlight.methods.reference import prepare_scenes

    views = prepare_scenes(scene.world).views
    ps = P.PhotonSettings(photons=photons, radius=radius)
    maps, _ = P.build_photon_maps(scene.world, views, ps)
    cam = scene.camera
    n = cam.width * cam.height
    rays = mi.Ray3f(generate_rays(cam, dr.arange(mi.UInt32, n), dr.zeros(mi.UInt32, n), 1,
                                  mi.UInt32(0)))
    qp, qn, _, found, _, _, _ = P._gather_walk(views.mixed, rays, dr.arange(mi.UInt32, n), 8)
    dr.eval(qp, qn, found)
    sel = np.asarray(found)
    q = np.asarray(qp).T[sel].astype(np.float64)
    qnorm = np.asarray(qn).T[sel]
    m = q.shape[0]
    qp_j = mi.Point3f(*q.T.astype(np.float32))
    qn_j = mi.Vector3f(*qnorm.T.astype(np.float32))
    t = {}
    best = {k: float("inf") for k in ("grid_build", "grid_query", "kd_build", "kd_query")}
    for _ in range(3):
        t0 = time.perf_counter()
        pm = P.PhotonMap.build(maps, ps.radii())
        t1 = time.perf_counter()
        em, _ = pm.estimate(qp_j, qn_j, dr.zeros(mi.UInt32, m), dr.full(mi.Bool, True, m))
        dr.eval(em)
        dr.sync_thread()
        t2 = time.perf_counter()
        pos = np.asarray(maps[0].p).T.astype(np.float64)
        wi = np.asarray(maps[0].wi).T
        flux = np.asarray(maps[0].flux)[0]
        t3 = time.perf_counter()
        tree = cKDTree(pos)
        t4 = time.perf_counter()
        lists = tree.query_ball_point(q, radius, workers=2, return_sorted=False)
        lens = np.fromiter((len(x) for x in lists), dtype=np.int64, count=m)
        flat = np.concatenate([np.asarray(x, dtype=np.int64) for x in lists]) if lens.sum() \
            else np.zeros(0, np.int64)
        row = np.repeat(np.arange(m), lens)
        d2 = np.sum((pos[flat] - q[row]) ** 2, axis=1)
        w = (2 / np.pi) * (1 - d2 / radius ** 2) / radius ** 2 * flux[flat]
        w *= np.sum(wi[flat] * qnorm[row], axis=1) > 0
        kd = np.bincount(row, weights=w, minlength=m)
        t5 = time.perf_counter()
        for k, v in (("grid_build", t1 - t0), ("grid_query", t2 - t1), ("kd_build", t4 - t3),
                     ("kd_query", t5 - t4)):
            best[k] = min(best[k], v)
    grid = np.asarray(em)[0]
    t.update(best)
    t["queries"] = float(m)
    t["max_rel_diff"] = float(np.max(np.abs(grid - kd)) / max(np.max(kd), 1e-30))
    print(f"[index {photons}] " + ", ".join(f"{k}={v:.4g}" for k, v in t.items()), flush=True)
    return t


def table(rows: dict[int, dict], idx: dict[int, dict], res: str) -> str:
    import mitsuba as mi

    lines = [HEADING, "",
             f"`python benchmarks/bench_photons.py` — glass-ring proxy (Kán Fig. 4.5) with his "
             f"point light (2 W/sr) instead of the 6 cm area light, {res}, 1 spp, kernel "
             f"radius 4 mm, Mitsuba {mi.__version__} "
             "`llvm_ad_rgb` on 2 shared CPU cores. Best of warm runs, milliseconds. Kán: "
             "Table 5.2 (GTX 590, OptiX, 720×576, Glass Monkey, kd-tree built on the CPU).", "",
             "| photons emitted | stored | t_p | t_b | t_p + t_b | t_r (t_r0 without caustics) | "
             "Kán t_p / t_b / t_r |",
             "|---|---|---|---|---|---|---|"]
    for n, r in rows.items():
        kan = KAN.get(n)
        ks = f"{kan[0]} / {kan[1]} / {kan[2]}" if kan else "—"
        lines.append(f"| {r['emitted']:,.0f} | {r['stored']:,.0f} | {1e3 * r['t_p']:.0f} | "
                     f"{1e3 * r['t_b']:.0f} | **{1e3 * (r['t_p'] + r['t_b']):.0f}** | "
                     f"{1e3 * r['t_r']:.0f} ({1e3 * r['t_r0']:.0f}) | {ks} |")
    lines += ["", "Index: Dr.Jit hash grid vs `scipy.spatial.cKDTree` on the same stored photons "
              "and the same gather points (best of 3, ms; the kd-tree's query is "
              "`query_ball_point(workers=2)` plus the kernel sums in NumPy; `diff` = largest "
              "difference of the two estimates relative to the peak):", "",
              "| photons emitted | gather points | grid build | grid query | kd build | "
              "kd query | diff |", "|---|---|---|---|---|---|---|"]
    for n, t in idx.items():
        lines.append(f"| {n:,} | {t['queries']:,.0f} | {1e3 * t['grid_build']:.0f} | "
                     f"{1e3 * t['grid_query']:.0f} | {1e3 * t['kd_build']:.0f} | "
                     f"{1e3 * t['kd_query']:.0f} | {t['max_rel_diff']:.1e} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="160×120, 30K and 100K photons")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--write", action="store_true", help="update benchmarks/RESULTS.md")
    args = ap.parse_args()
    factor = 4 if args.quick else 1
    counts = [30_000, 100_000] if args.quick else [100_000, 300_000, 1_000_000]
    scene = load_scene(factor)
    res = f"{scene.camera.width}×{scene.camera.height}"
    rows = {n: stage_times(scene, n, args.repeats) for n in counts}
    idx = {n: index_comparison(scene, n) for n in counts}
    publish(table(rows, idx, res), args.write and not args.quick)


if __name__ == "__main__":
    main()
