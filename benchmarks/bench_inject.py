"""Benchmark: DLPV's light injection, order-independent (fixed point) vs float atomics.

Issue #28 made ``realtime.sh_volume.inject`` deterministic: the lobes are summed in 64-bit
fixed point (:mod:`arlight.realtime.exact_sum`) instead of ``scatter_reduce`` on floats. This
times both on the same input in the same process, interleaved (the machines are shared and
noisy: compare the ratio), at Franke's defaults: a 512² RSM (262 144 lanes) into a 32³ volume.

    python benchmarks/bench_inject.py [--lanes 262144] [--grid 32] [--repeats 30]
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.jit import ensure_variant


def _atomic(vol, idx, act, vals) -> None:
    """The previous injection: float atomics (order follows thread timing)."""
    for k in range(4):
        dr.scatter_reduce(dr.ReduceOp.Add, vol.coeffs[k], vals[k], idx, act)
    dr.eval(vol.coeffs, act)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lanes", type=int, default=512 * 512, help="RSM texels injected")
    ap.add_argument("--grid", type=int, default=32, help="volume cells per axis")
    ap.add_argument("--repeats", type=int, default=30, help="timed injections per variant")
    args = ap.parse_args()
    ensure_variant()
    from arlight.realtime.sh_volume import Grid, SHVolume, inject

    rng = np.random.default_rng(0)
    n = args.lanes
    grid = Grid(np.zeros(3), 1.0 / args.grid, args.grid)
    pos = mi.Point3f(*(rng.random((3, n)).astype(np.float32)))
    d = rng.standard_normal((3, n))
    d /= np.linalg.norm(d, axis=0)
    dirn = mi.Vector3f(*d.astype(np.float32))
    flux = mi.Color3f(*(rng.random((3, n)).astype(np.float32)))
    act = mi.Bool(np.ones(n, bool))

    def fresh() -> SHVolume:
        return SHVolume(grid, [dr.zeros(mi.Color3f, args.grid ** 3) for _ in range(4)])

    def run_exact() -> None:
        inject(fresh(), pos, dirn, flux, act)

    def run_atomic() -> None:
        # the same lobes inject() computes, scattered with float atomics
        from arlight.realtime.sh_volume import COS_LOBE_0, COS_LOBE_1, cell_index

        vol = fresh()
        idx, inside = cell_index(grid, pos)
        scale = flux * (1.0 / math.pi)
        vals = [scale * COS_LOBE_0, scale * (-COS_LOBE_1 * dirn.x),
                scale * (COS_LOBE_1 * dirn.y), scale * (COS_LOBE_1 * dirn.z)]
        _atomic(vol, idx, act & inside, vals)

    times: dict[str, list[float]] = {"fixed point (exact)": [], "float atomics": []}
    for fn in (run_exact, run_atomic):  # warm-up: compile both
        fn()
    for _ in range(args.repeats):
        for name, fn in (("fixed point (exact)", run_exact), ("float atomics", run_atomic)):
            t = time.perf_counter()
            fn()
            dr.sync_thread()
            times[name].append(1e3 * (time.perf_counter() - t))
    base = statistics.median(times["float atomics"])
    print(f"injection of {n} lanes into {args.grid}³ cells, median of {args.repeats}:")
    for name, ts in times.items():
        med = statistics.median(ts)
        print(f"  {name:20s} {med:7.2f} ms  ({med / base:.2f}× float atomics)")


if __name__ == "__main__":
    main()
