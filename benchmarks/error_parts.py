"""Where a method's changed-pixel error comes from, per world (issue #33).

    .venv/bin/python benchmarks/error_parts.py --method dlpv --worlds 1000000,1000002

The changed region (:func:`arlight.evaluate.metrics.changed_region`, as the harness scores
``changed_psnr``) is split into the virtual objects' pixels, the real pixels the insertion
darkens in the ground truth (shadows: GT luminance below the frame's) and the real pixels it
brightens (bounce). Per world: each part's share of the squared display error, the
changed-pixel PSNR (dB) if that part were perfect, and the mean luminance error (display
units) of the method and of the untouched frame on the darkened and brightened pixels (a
method whose error equals the frame's did not change those pixels). Worlds at 160×120,
ground truth Mitsuba 256 spp (the shared cache of ``benchmarks/tune_realtime.py``).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

LUM = np.array([0.2126, 0.7152, 0.0722])


def parts(method: str, seed: int) -> str:
    """One world's line (see the module docstring)."""
    import tune_realtime as T

    from arlight.evaluate import metrics as M
    from arlight.methods import get_method
    from arlight.methods.base import RenderSettings

    scene, photo = T.world(seed)
    layers = get_method(method)(scene.ar_scene(photo), RenderSettings(spp=16, max_depth=8,
                                                                      seed=0))
    gt, fr, tr = photo.ground_truth, photo.frame, scene.world.camera.transfer
    region = M.changed_region(fr, gt, photo.mask, photo.frame_stderr,
                              photo.ground_truth_stderr)
    dc, dg, df = M.display(layers.composite, tr), M.display(gt, tr), M.display(fr, tr)
    virt = region & (photo.mask > 0)
    real = region & ~(photo.mask > 0)
    dark = real & (dg @ LUM < df @ LUM)
    bright = real & ~dark
    err = ((dc - dg) ** 2).sum(-1)
    total = err[region].sum()

    def perfect(mask: np.ndarray) -> float:
        e = np.where(mask, 0.0, err)[region].sum() / (3 * region.sum())
        return 10 * math.log10(1.0 / e) if e > 0 else math.inf

    def bias(a: np.ndarray, mask: np.ndarray) -> float:
        return float(((a - dg) @ LUM)[mask].mean()) if mask.any() else math.nan

    base = M.psnr(dc, dg, peak=1.0, region=region)
    cells = [f"{err[m].sum() / total:.2f} / {perfect(m):.2f}" for m in (virt, dark, bright)]
    return (f"| world-{seed} | {base:.2f} | {virt.sum()}/{dark.sum()}/{bright.sum()} | "
            + " | ".join(cells)
            + f" | {bias(dc, dark):+.3f} ({bias(df, dark):+.3f}) | "
              f"{bias(dc, bright):+.3f} ({bias(df, bright):+.3f}) |")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--method", default="dlpv")
    ap.add_argument("--worlds", required=True, help="comma-separated seeds")
    args = ap.parse_args()
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    print("| world | changed PSNR (dB) | pixels virtual/darkened/brightened | virtual: "
          "error share / PSNR if perfect | darkened: share / if perfect | brightened: "
          "share / if perfect | darkened: method − GT (frame − GT) | brightened: method − GT "
          "(frame − GT) |")
    print("|---|---|---|---|---|---|---|---|")
    for s in args.worlds.split(","):
        print(parts(args.method, int(s)), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
