"""Benchmark: light estimation: micro-benchmarks against NumPy baselines (issue 5), the main
light on every bundled panorama and end-to-end 4k ``light estimate`` old vs new (issue 10).

Both contenders run in the same process on the same 1024x512 map (the bundled Grace probe
upsampled), interleaved, several repeats; the ratio of the medians is reported (these
machines are noisy, absolute times are not comparable across runs).

* SH projection to 9 coefficients: ``arlight.sphere.sh.project_equirect`` (separable
  Fourier x Legendre sums, exact pixel integrals) vs. the straightforward per-pixel
  ``Y (H*W x 9) ^T @ (L * dOmega)`` with the closed-form L2 polynomials.
* 16-light median cut: ``arlight.light.extract.median_cut`` (summed-area tables, O(1) region
  sums) vs. a straightforward recursive median cut that re-sums each sub-array with NumPy.

Issue 10 adds two sections:

* ``## Light estimation II: main light per panorama (issue 10)``: on each panorama of
  the bundled panoramas (``src/arlight/data/light/panoramas``, the demo's lebombo, the Grace
  probe), the main light of
  ``LightEstimate.from_envmap`` (``regions``, and the former ``median_cut`` default) against
  the *dominant highlight region*, found here independently: pixels above 4x the mean
  luminance, 8-connected with ``scipy.ndimage.label``, joined across the seam and at the
  poles by a union-find written here; the region with the most luminance energy
  ``sum Y(L) Omega``. Its centre is the energy-weighted centroid of its full radiance and
  its size the radius of the cap with the same mean cosine. "Compact" = radius <= 10 deg;
  acceptance there: direction within 2 deg, energy >= 90 % of the region's.
* ``## Light estimation II: 4k end-to-end (issue 10)``: ``python -m arlight.light.cli
  estimate`` on a 4096x2048 EXR (the bundled rooitou_park upsampled), in subprocesses, today's
  code vs the code before issue 10 (a ``git worktree`` of ``--old-rev``), interleaved; wall time and
  the process's own peak RSS (``VmHWM``). The fixed overhead is the same command on a 256x128
  map.

Usage: ``python benchmarks/bench_light.py [--write] [--skip-micro] [--skip-e2e]``
(``--write`` updates the sections of ``benchmarks/RESULTS.md``).
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from results import publish

from arlight.io.images import read_linear
from arlight.light import extract
from arlight.sphere import sh
from arlight.sphere.envmap import equirect_directions, equirect_solid_angle, resize_equirect

ROOT = Path(__file__).resolve().parents[1]
SECTION = "## Light estimation (issue 5)"
SECTION_MAIN = "## Light estimation II: main light per panorama (issue 10)"
SECTION_E2E = "## Light estimation II: 4k end-to-end (issue 10)"
HDRI = ROOT / "src/arlight/data/light/panoramas"
DEMO_MAP = ROOT / "src/arlight/data/demo/lebombo_512x256.hdr"
GRACE = ROOT / "src/arlight/data/light/grace_latlong_256x128.hdr"
OLD_REV = "ae58ea7"  # the last commit before issue 10's light estimation work
COMPACT_DEG = 10.0


def baseline_project_l2(img: np.ndarray) -> np.ndarray:
    """Per-pixel closed-form L2 basis (our convention: pole +Y, CS phase) x solid angle."""
    H, W = img.shape[:2]
    d = equirect_directions(H, W).reshape(-1, 3)
    w = equirect_solid_angle(H, W).reshape(-1)
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    k0, k1 = 0.5 / np.sqrt(np.pi), np.sqrt(3 / (4 * np.pi))
    k2, k3, k4 = 0.5 * np.sqrt(15 / np.pi), 0.25 * np.sqrt(5 / np.pi), 0.25 * np.sqrt(15 / np.pi)
    # our basis is the Cartesian one with (x, y, z) -> (-z, x, y) relabelled (pole = +Y)
    X, Y, Z = -z, x, y
    Yb = np.stack([np.full_like(x, k0), -k1 * Y, k1 * Z, -k1 * X, k2 * X * Y, -k2 * Y * Z,
                   k3 * (3 * Z * Z - 1), -k2 * X * Z, k4 * (X * X - Y * Y)], axis=1)
    return Yb.T @ (img.reshape(-1, 3).astype(np.float64) * w[:, None])


def baseline_median_cut(img: np.ndarray, n_lights: int) -> list[np.ndarray]:
    """Debevec's median cut written directly: sums over sub-arrays at every split."""
    H, W = img.shape[:2]
    omega = equirect_solid_angle(H, W)
    e = (img.astype(np.float64) @ sh.LUMINANCE) * omega
    dirs = equirect_directions(H, W)
    regions = [(0, H, 0, W)]
    while len(regions) < n_lights:
        new = []
        for r0, r1, c0, c1 in regions:
            sub = e[r0:r1, c0:c1]
            lat = np.pi / 2 - np.pi * (r0 + r1) / (2 * H)
            xs = np.cos(lat) * (2 * np.pi / W) / (np.pi / H)
            if (c1 - c0) * xs >= (r1 - r0):
                cum = np.cumsum(sub.sum(axis=0))
                k = int(np.argmin(np.abs(cum[:-1] - cum[-1] / 2))) + 1
                new += [(r0, r1, c0, c0 + k), (r0, r1, c0 + k, c1)]
            else:
                cum = np.cumsum(sub.sum(axis=1))
                k = int(np.argmin(np.abs(cum[:-1] - cum[-1] / 2))) + 1
                new += [(r0, r0 + k, c0, c1), (r0 + k, r1, c0, c1)]
        regions = new
    out = []
    for r0, r1, c0, c1 in regions:
        w = e[r0:r1, c0:c1]
        v = (dirs[r0:r1, c0:c1] * w[..., None]).sum(axis=(0, 1))
        out.append(v / np.linalg.norm(v))
    return out


def timed(fn, *args) -> float:
    t = time.perf_counter()
    fn(*args)
    return time.perf_counter() - t


def compare(name: str, fast, slow, args, repeats: int) -> dict:
    tf, ts = [], []
    for _ in range(repeats):  # interleaved so both see the same machine load
        tf.append(timed(fast, *args))
        ts.append(timed(slow, *args))
    mf, ms = statistics.median(tf), statistics.median(ts)
    return {"name": name, "fast_ms": 1e3 * mf, "base_ms": 1e3 * ms, "ratio": ms / mf,
            "repeats": repeats}


def reference_region(img: np.ndarray) -> dict | None:
    """The dominant highlight region of an equirect map, computed independently of
    arlight's extraction (see the module docstring); None when nothing is above 4x the
    mean luminance."""
    from scipy import ndimage

    lum = img[..., :3].astype(np.float64) @ sh.LUMINANCE
    H, W = lum.shape
    om = equirect_solid_angle(H, W)
    tau = 4 * (lum * om).sum() / (4 * np.pi)
    mask = lum > tau
    pad = np.concatenate([mask[:, -1:], mask, mask[:, :1]], axis=1)
    lab, n = ndimage.label(pad, structure=np.ones((3, 3)))
    parent = list(range(n + 1))

    def find(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    def union(a: int, b: int) -> None:
        if a and b:
            parent[find(a)] = find(b)

    for r in range(H):  # the padding columns are copies of the far side
        union(int(lab[r, 0]), int(lab[r, W]))
        union(int(lab[r, W + 1]), int(lab[r, 1]))
    for row in (lab[0, 1:W + 1], lab[-1, 1:W + 1]):  # every pixel of a pole row meets
        ids = [int(i) for i in np.unique(row) if i]
        for a, b in zip(ids, ids[1:], strict=False):
            union(a, b)
    root = np.array([find(i) for i in range(n + 1)])[lab[:, 1:W + 1]]
    root[~mask] = 0
    ids = np.unique(root[root > 0])
    if ids.size == 0:
        return None
    e = lum * om
    energies = np.array([e[root == i].sum() for i in ids])
    sel = root == ids[int(np.argmax(energies))]
    v = (equirect_directions(H, W)[sel] * e[sel][:, None]).sum(axis=0)
    rho = np.linalg.norm(v) / e[sel].sum()
    return {"centre": v / np.linalg.norm(v), "energy": float(energies.max()),
            "radius_deg": float(np.degrees(np.arccos(np.clip(2 * rho - 1, -1, 1)))),
            "regions": int(ids.size)}


def panorama_table() -> tuple[list[str], bool]:
    """Rows of the per-panorama table and whether every compact map passes."""
    from arlight.light.estimate import LightEstimate

    files = sorted(p for p in HDRI.glob("*") if p.suffix.lower() in (".hdr", ".exr"))
    files += [DEMO_MAP, GRACE]
    rows, ok = [], True
    for f in files:
        img = read_linear(f)
        ref = reference_region(img)
        if ref is None:
            rows.append(f"| {f.name} | {img.shape[1]}x{img.shape[0]} | no pixel above 4x "
                        "the mean | | | | | | |")
            continue
        res = {}
        for method in ("regions", "median_cut"):
            est = LightEstimate.from_envmap(img, method=method, keep_map=False)
            ang = float(np.degrees(np.arccos(np.clip(est.main_direction @ ref["centre"], -1,
                                                     1))))
            res[method] = (ang, float(est.main_irradiance @ sh.LUMINANCE) / ref["energy"],
                           1 + len(est.lights), est.explicit_fraction)
        compact = ref["radius_deg"] <= COMPACT_DEG
        ang, ratio, count, frac = res["regions"]
        passed = ang <= 2.0 and ratio >= 0.9
        ok &= passed or not compact
        verdict = ("pass" if passed else "FAIL") if compact else "n/a (area source)"
        old_ang, old_ratio, _, _ = res["median_cut"]
        rows.append(f"| {f.name} | {img.shape[1]}x{img.shape[0]} | {ref['radius_deg']:.1f} | "
                    f"{ang:.2f} | {ratio:.3f} | {count} | {100 * frac:.1f} % | "
                    f"{old_ang:.1f} / {old_ratio:.3f} | {verdict} |")
    return rows, ok


# Runs the CLI in a fresh interpreter and records its own peak RSS (VmHWM) on exit: the
# rusage of a child (wait4's ru_maxrss) also counts the parent's memory at fork time.
_PEAK_WRAPPER = """
import runpy, sys
out, sys.argv = sys.argv[1], ["arlight", "light", *sys.argv[2:]]
try:  # `arlight light ...` through arlight.cli's one error path (old checkouts too)
    runpy.run_module("arlight.cli", run_name="__main__")
finally:
    hwm = [l for l in open("/proc/self/status") if l.startswith("VmHWM")][0].split()[1]
    open(out, "w").write(hwm)
"""


def _run_cli(src: Path | None, image: Path, out: Path) -> tuple[float, float]:
    """``arlight light estimate image`` (``python -m arlight.cli``) from ``src`` (None: this
    checkout's installed package) -> (wall seconds, peak RSS MiB of that process)."""
    env = dict(os.environ)
    if src is not None:
        env["PYTHONPATH"] = str(src)
    hwm = out.with_suffix(".hwm")
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-c", _PEAK_WRAPPER, str(hwm), "estimate", str(image),
                        "-o", str(out)], env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t
    if r.returncode != 0:
        raise RuntimeError(f"estimate failed ({src or 'new'}): {r.stderr[-400:]}")
    return wall, int(hwm.read_text()) / 1024.0


def end_to_end(repeats: int, old_rev: str) -> list[str]:
    """4k ``light estimate``, old vs new, interleaved in subprocesses."""
    from arlight.io.images import write_exr

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        old = tmp / "old"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(old),
                        old_rev], check=True, capture_output=True)
        try:
            big = tmp / "rooitou_4k.exr"
            write_exr(big, resize_equirect(read_linear(HDRI / "rooitou_park_512x256.hdr"), 2048))
            map_mb = 2048 * 4096 * 3 * 4 / 2**20
            stats = {}
            for name, src in (("old", old / "src"), ("new", None)):
                _run_cli(src, GRACE, tmp / f"warm_{name}.json")  # warm the caches
                stats[name] = {"base": [], "time": [], "peak": []}
            for _ in range(repeats):
                for name, src in (("old", old / "src"), ("new", None)):
                    stats[name]["base"].append(_run_cli(src, GRACE, tmp / "g.json")[1])
                    t, m = _run_cli(src, big, tmp / f"{name}.json")
                    stats[name]["time"].append(t)
                    stats[name]["peak"].append(m)
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force",
                            str(old)], capture_output=True)
    med = {k: {q: statistics.median(v) for q, v in d.items()} for k, d in stats.items()}
    lines = []
    for name in ("old", "new"):
        m = med[name]
        extra = m["peak"] - m["base"]
        lines.append(f"| {name} ({old_rev if name == 'old' else 'this commit'}) | "
                     f"{m['time']:.2f} | {m['peak']:.0f} | {m['base']:.0f} | {extra:.0f} | "
                     f"{extra / map_mb:.2f} |")
    extra = {k: med[k]["peak"] - med[k]["base"] for k in med}
    lines.append(f"| ratio old / new | {med['old']['time'] / med['new']['time']:.2f} | "
                 f"{med['old']['peak'] / med['new']['peak']:.2f} | | "
                 f"{extra['old'] / extra['new']:.2f} | |")
    return lines


def micro(repeats: int) -> str:
    """The issue-5 section: SH projection and median cut against NumPy baselines."""
    grace = read_linear(GRACE)
    img = resize_equirect(grace, 512)  # 1024 x 512
    # the two contenders must agree before their times mean anything
    np.testing.assert_allclose(sh.project_equirect(img, 2), baseline_project_l2(img),
                               rtol=0, atol=2e-3 * np.abs(baseline_project_l2(img)).max())
    fast_dirs = sorted(tuple(np.round(lt.direction, 6)) for lt in extract.median_cut(img, 16))
    slow_dirs = sorted(tuple(np.round(d, 6)) for d in baseline_median_cut(img, 16))
    assert np.allclose(fast_dirs, slow_dirs, atol=1e-6), "median cut variants disagree"

    rows = [
        compare("SH projection, 9 coeffs, 1024x512", lambda m: sh.project_equirect(m, 2),
                baseline_project_l2, (img,), repeats),
        compare("median cut, 16 lights, 1024x512", lambda m: extract.median_cut(m, 16),
                lambda m: baseline_median_cut(m, 16), (img,), repeats),
    ]
    lines = [SECTION, "",
             f"`python benchmarks/bench_light.py --write` ({platform.processor() or 'cpu'}, "
             f"numpy {np.__version__}, median of {repeats} interleaved repeats, "
             "same process; ratio = baseline / arlight, > 1 means arlight is faster).", "",
             "| task | arlight (ms) | NumPy baseline (ms) | ratio |", "|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['name']} | {r['fast_ms']:.1f} | {r['base_ms']:.1f} | "
                     f"{r['ratio']:.2f} |")
    lines += ["", "Baselines: per-pixel closed-form L2 basis matrix product; recursive median "
              "cut re-summing sub-arrays. Both are checked to give the same result first.", ""]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--e2e-repeats", type=int, default=3)
    ap.add_argument("--old-rev", default=OLD_REV, help="the code to compare against")
    ap.add_argument("--skip-micro", action="store_true")
    ap.add_argument("--skip-e2e", action="store_true")
    ap.add_argument("--write", action="store_true", help="update benchmarks/RESULTS.md")
    args = ap.parse_args()

    if not args.skip_micro:
        publish(micro(args.repeats), args.write)
    rows, ok = panorama_table()
    lines = [SECTION_MAIN, "",
             "`python benchmarks/bench_light.py --write`: main light of `LightEstimate."
             "from_envmap` (default `regions`; 16 = cap) against the dominant highlight "
             "region found independently in the benchmark (pixels > 4x mean luminance, "
             "8-connected with `scipy.ndimage.label`, joined across the seam and at the poles; "
             "the region with the most energy `sum Y(L) Omega`; radius = cap with the same "
             "mean cosine). Compact = radius <= 10 deg; there the main light must be within "
             "2 deg of the region's centre and hold >= 90 % of its energy (it holds the part "
             "above the threshold; the rest is in the SH). Old = the former default, 16-light "
             "median cut.", "",
             "| map | size | region radius (deg) | direction error (deg) | energy / region's | "
             "lights | explicit share of the map's energy | old: error (deg) / energy | "
             "acceptance |", "|---|---|---|---|---|---|---|---|---|", *rows, "",
             f"All compact maps pass: {'yes' if ok else 'NO'}.", ""]
    publish("\n".join(lines), args.write)
    if not args.skip_e2e:
        e2e = end_to_end(args.e2e_repeats, args.old_rev)
        lines = [SECTION_E2E, "",
                 f"`python benchmarks/bench_light.py --write`: `python -m arlight.light.cli "
                 f"estimate` on a 4096x2048 float32 EXR (rooitou_park upsampled; the map is "
                 f"96 MiB in float32), each in its own process, old and new interleaved, median "
                 f"of {args.e2e_repeats}. Peak = the process's VmHWM; overhead = the same "
                 f"command on the 256x128 Grace map (imports, Mitsuba); extra = peak - "
                 f"overhead. The machine is shared: read the ratios.", "",
                 "| code | time (s) | peak RSS (MiB) | overhead (MiB) | extra (MiB) | "
                 "extra / map size |", "|---|---|---|---|---|---|", *e2e, ""]
        publish("\n".join(lines), args.write)


if __name__ == "__main__":
    main()
