"""Benchmark: SH projection and median-cut light extraction against plain NumPy baselines.

Both contenders run in the same process on the same 1024x512 map (the bundled Grace probe
upsampled), interleaved, several repeats; the ratio of the medians is reported (these
machines are noisy, absolute times are not comparable across runs).

* SH projection to 9 coefficients: ``arlight.sphere.sh.project_equirect`` (separable
  Fourier x Legendre sums, exact pixel integrals) vs. the straightforward per-pixel
  ``Y (H*W x 9) ^T @ (L * dOmega)`` with the closed-form L2 polynomials.
* 16-light median cut: ``arlight.light.extract.median_cut`` (summed-area tables, O(1) region
  sums) vs. a straightforward recursive median cut that re-sums each sub-array with NumPy.

Usage: ``python benchmarks/bench_light.py [--write]`` (``--write`` updates the
``## Light estimation (issue 5)`` section of ``benchmarks/RESULTS.md``).
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time
from pathlib import Path

import numpy as np
from results import publish

from arlight.io.images import read_linear
from arlight.light import extract, sh
from arlight.sphere.envmap import equirect_directions, equirect_solid_angle, resize_equirect

ROOT = Path(__file__).resolve().parents[1]
SECTION = "## Light estimation (issue 5)"


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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--write", action="store_true", help="update benchmarks/RESULTS.md")
    args = ap.parse_args()

    grace = read_linear(ROOT / "src/arlight/data/light/grace_latlong_256x128.hdr")
    img = resize_equirect(grace, 512)  # 1024 x 512
    # the two contenders must agree before their times mean anything
    np.testing.assert_allclose(sh.project_equirect(img, 2), baseline_project_l2(img),
                               rtol=0, atol=2e-3 * np.abs(baseline_project_l2(img)).max())
    fast_dirs = sorted(tuple(np.round(lt.direction, 6)) for lt in extract.median_cut(img, 16))
    slow_dirs = sorted(tuple(np.round(d, 6)) for d in baseline_median_cut(img, 16))
    assert np.allclose(fast_dirs, slow_dirs, atol=1e-6), "median cut variants disagree"

    rows = [
        compare("SH projection, 9 coeffs, 1024x512", lambda m: sh.project_equirect(m, 2),
                baseline_project_l2, (img,), args.repeats),
        compare("median cut, 16 lights, 1024x512", lambda m: extract.median_cut(m, 16),
                lambda m: baseline_median_cut(m, 16), (img,), args.repeats),
    ]
    lines = [SECTION, "",
             f"`python benchmarks/bench_light.py --write` ({platform.processor() or 'cpu'}, "
             f"numpy {np.__version__}, median of {args.repeats} interleaved repeats, "
             "same process; ratio = baseline / arlight, > 1 means arlight is faster).", "",
             "| task | arlight (ms) | NumPy baseline (ms) | ratio |", "|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['name']} | {r['fast_ms']:.1f} | {r['base_ms']:.1f} | "
                     f"{r['ratio']:.2f} |")
    lines += ["", "Baselines: per-pixel closed-form L2 basis matrix product; recursive median "
              "cut re-summing sub-arrays. Both are checked to give the same result first.", ""]
    text = "\n".join(lines)
    publish(text, args.write)


if __name__ == "__main__":
    main()
