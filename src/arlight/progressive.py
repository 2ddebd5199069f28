"""Differential progressive path tracing (DPPT; Kán thesis §4.4, digest §8).

Two modes over any registered method (``onepass`` by default):

* **preview** (:func:`preview`): one frame with the *same* random sequence every time
  (the seed of the settings), so a static input renders bitwise identically — no flicker
  (Kán: "the same random parameters are used every frame").
* **refinement** (:func:`refine`): frames with new random samples, each composited
  (Eq. 2.20) and accumulated *after* compositing with Kán Eq. 4.12,

      L_acc ← ((n − 1) · L_acc + L_o) / n,

  until a time or frame budget is spent. :class:`Accumulator` keeps the running mean in
  float64. The method prepares the scene once (``method.prepare``: Mitsuba scenes, BVHs)
  and renders every frame from that state (``method.render``). Only methods whose
  capabilities say ``progressive`` are accepted.

**Which samples a frame draws** (:func:`frame_settings`). A method with the frame option
``sample_offset`` (:attr:`~arlight.methods.spec.MethodSpec.frame_options`: a render may change
it without preparing again; its samples are indices into per-pixel low-discrepancy sequences,
e.g. ``onepass``'s Sobol sampler, :mod:`arlight.backend.passes`) keeps the seed of the settings
for every frame and draws samples ``[o + (n − 1)·spp, o + n·spp)`` in frame ``n`` (``o``: the
``sample_offset`` given in the options, default 0): the first ``N`` frames together are exactly
the first ``N·spp`` samples of every pixel's sequences, so their mean layers equal one render
of ``N·spp`` samples (one low-discrepancy set converging faster than 1/√N), not ``N``
independent randomisations. The offset must be a multiple of the frame's replica count (the
standard errors' randomisations, the largest divisor of ``spp`` not above the ``replicas``
option): ``(n − 1)·spp`` always is, for any ``spp`` — with the default ``spp = 1`` a frame has
a single replica (its own standard error is then undefined, which refinement never reads).
Every other method gets a fresh seed :func:`frame_seed` ``(seed, n)`` per frame (independent
estimates). Either way frame ``n`` is bitwise the one-shot render with :func:`frame_settings`
``(method, settings, n)``.

**Denoising** (``denoise = oidn`` in the options, :mod:`arlight.denoise`): the frames are
rendered raw and their layers averaged (:class:`~arlight.denoise.differential.RunningLayers`);
each step's image is the denoised composite of that running mean (auxiliary buffers traced
once), so the denoiser's bias falls as the samples add up instead of being averaged in.

:func:`run_cli` is what ``arlight render --progressive`` calls: a progress task,
snapshots (EXR + PNG) at frames 1, 2, 4, 8, … and at the end, and, given a ground truth, the
RMSE after every frame printed as it falls and written to ``error.csv`` / ``error.png``.
"""

from __future__ import annotations

import csv
import math
import time
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from arlight.denoise.options import DenoiseSettings
from arlight.errors import InputError
from arlight.methods import Method, RenderSettings, get_method
from arlight.methods.base import Layers
from arlight.scene.model import ARScene
from arlight.timing import format_stages

SEED_STRIDE = 0x9E3779B1  # refinement frame n uses seed + n * stride (mod 2^32)


class Accumulator:
    """Running mean of images by Kán Eq. 4.12 (float64)."""

    def __init__(self) -> None:
        self.mean: np.ndarray | None = None
        self.count = 0

    def add(self, image: np.ndarray) -> np.ndarray:
        """Fold one frame in: ``L_acc ← ((n − 1) L_acc + L_o) / n``; returns the new mean."""
        self.count += 1
        img = np.asarray(image, dtype=np.float64)
        if self.mean is None:
            self.mean = img.copy()
        else:
            n = self.count
            self.mean = ((n - 1) * self.mean + img) / n
        return self.mean


def preview(scene: ARScene, method: str = "onepass",
            settings: RenderSettings | None = None) -> Layers:
    """One preview frame with the fixed random sequence of ``settings.seed``."""
    return get_method(method)(scene, settings or RenderSettings(spp=1))


@dataclass
class RefineStep:
    """State after refinement frame ``frame`` (1-based)."""

    frame: int
    seconds: float  # since refinement started, the preparation included
    image: np.ndarray  # running mean of the composites (float64)
    layers: Layers  # the layers of this frame alone (stats: this frame's render stages)


def frame_seed(base: int, n: int) -> int:
    """Seed of refinement frame ``n`` (fresh for every frame, reproducible) of a method
    without a ``sample_offset`` option."""
    return (base + n * SEED_STRIDE) & 0xFFFFFFFF


def continues_sequence(method: Method) -> bool:
    """Whether ``method``'s frames continue one sample sequence (``sample_offset`` is one of
    its frame options, :attr:`~arlight.methods.spec.MethodSpec.frame_options`) rather than
    taking fresh seeds."""
    return "sample_offset" in method.spec.frame_options


def frame_settings(method: Method, settings: RenderSettings, n: int) -> RenderSettings:
    """The settings of refinement frame ``n`` (1-based) of ``method``.

    With a ``sample_offset`` option: the same seed and ``sample_offset = o + (n − 1)·spp``
    (``o``: the offset given in ``settings.options``, default 0), so frames 1…N draw the
    first ``N·spp`` samples of one sequence. Otherwise: seed :func:`frame_seed` ``(seed, n)``.
    Progress bars are off either way.
    """
    if continues_sequence(method):
        base = int(settings.options.get("sample_offset", 0))
        options = {**settings.options, "sample_offset": base + (n - 1) * settings.spp}
        return replace(settings, options=options, progress=False)
    return replace(settings, seed=frame_seed(settings.seed, n), progress=False)


def progressive_method(name: str) -> Method:
    """The registered method ``name``, if its capabilities allow progressive refinement."""
    method = get_method(name)
    if not method.spec.capabilities.progressive:
        raise InputError(f"method {name!r} is not progressive (its renders with different "
                         "seeds are not independent estimates to average)", field="method")
    return method


def refine(scene: ARScene, method: str = "onepass", settings: RenderSettings | None = None,
           time_budget: float | None = None, frames: int | None = None) -> Iterator[RefineStep]:
    """Yield the accumulated composite after each refinement frame.

    The scene is prepared once and each frame rendered from that state. Stops after
    ``frames`` frames or once ``time_budget`` seconds have passed (checked after each frame;
    at least one frame is rendered). With neither given it runs until the caller stops
    iterating. Frame ``n`` renders with :func:`frame_settings` ``(method, settings, n)``:
    consecutive samples of one sequence where the method has a ``sample_offset`` option,
    fresh seeds otherwise.
    """
    if time_budget is not None and not (time_budget >= 0 and math.isfinite(time_budget)):
        raise InputError(f"must be a finite number of seconds >= 0, got {time_budget}",
                         field="time_budget")
    if frames is not None and frames < 0:
        raise InputError(f"must be >= 0, got {frames}", field="frames")
    settings = settings or RenderSettings(spp=1)
    fn = progressive_method(method)
    denoise = DenoiseSettings.from_options(fn.options(settings)) \
        if hasattr(fn, "options") else None
    if denoise is not None:  # raw frames; their running mean is denoised (denoising.md)
        settings = replace(settings, options={**settings.options, "denoise": "none"})
    acc = Accumulator()
    start = time.perf_counter()
    state = fn.prepare(scene.world, settings)
    view = scene.view
    denoised = _ProgressiveDenoiser(fn, state, scene, denoise) if denoise else None
    n = 0
    while True:
        n += 1
        frame = frame_settings(fn, settings, n)
        layers = fn.render(state, view, frame)
        image = acc.add(layers.composite) if denoised is None else denoised.add(layers)
        elapsed = time.perf_counter() - start
        yield RefineStep(n, elapsed, image, layers)
        if frames and n >= frames:
            return
        if time_budget is not None and elapsed >= time_budget:
            return


class _ProgressiveDenoiser:
    """The denoised composite of the running mean of the raw frames; the auxiliary buffers
    are traced once (the view does not change during refinement)."""

    def __init__(self, fn: Method, state, scene: ARScene, denoise: DenoiseSettings) -> None:
        from arlight.denoise.differential import RunningLayers

        self.running = RunningLayers()
        self.denoise = denoise
        self.aux_view = (getattr(fn, "aux_view", lambda d: None)(state.data)
                         if denoise.aux and hasattr(state, "data") else None)
        self.camera = scene.camera
        self.full = None

    def aux(self, rows: slice, cols: slice):
        from arlight.denoise.aux import aux_buffers

        if self.full is None:
            self.full = aux_buffers(self.aux_view, self.camera, self.denoise.aux_spp)
        return self.full.crop(rows, cols)

    def add(self, layers: Layers) -> np.ndarray:
        from arlight.denoise.differential import denoise_layers

        mean = self.running.add(layers)
        out = denoise_layers(mean, self.denoise, self.aux if self.aux_view else None)
        return out.composite.astype(np.float64)


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    """Root-mean-square error over all pixels and channels."""
    return float(np.sqrt(np.mean(np.square(np.asarray(a, np.float64) - b))))


def _snapshot(out: Path, scene: ARScene, image: np.ndarray, frame: int) -> None:
    from arlight.io.images import write_exr, write_png

    img = image.astype(np.float32)
    write_exr(out / f"progressive_{frame:05d}.exr", img)
    write_png(out / f"progressive_{frame:05d}.png", scene.camera.transfer.to_display(img))


def write_error_plot(rows: list[tuple[int, float, float]], path: Path) -> None:
    """Log–log plot of RMSE against time with the 1/√n slope for reference."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from arlight.io.images import atomic_write

    n, t, e = (np.array(c, dtype=np.float64) for c in zip(*rows, strict=True))
    fig, ax = plt.subplots(figsize=(5, 3.5))
    ax.loglog(t, e, "o-", ms=3, label="DPPT composite")
    ax.loglog(t, e[0] * np.sqrt(n[0] / n), "--", label=r"$\propto 1/\sqrt{n}$")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("RMSE vs ground truth")
    ax.legend()
    fig.tight_layout()
    with atomic_write(path, ".png") as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)


def run_cli(scene: ARScene, method_name: str, settings: RenderSettings, out_dir: Path,
            time_budget: float, frames: int, ground_truth_path: Path | None, console) -> None:
    """``arlight render --progressive``: refine until ``time_budget`` s or ``frames`` frames.

    Writes ``progressive_<n>.exr/.png`` snapshots (n = 1, 2, 4, … and the last frame) and,
    with a ground truth, ``error.csv`` (frame, seconds, rmse) and ``error.png``. The files are
    staged and swapped in as one set when the run ends
    (:class:`arlight.staged_output.StagedOutput`): an error or an interrupt leaves the
    previous output folder as it was (and creates none).
    """

    from arlight.io.images import read_hdr
    from arlight.layer_files import LAYER_FILES
    from arlight.staged_output import StagedOutput

    progressive_method(method_name)  # refuse before reading anything

    final = Path(out_dir)
    gt = None
    if ground_truth_path is not None:
        gt = read_hdr(ground_truth_path)
        want = (scene.camera.height, scene.camera.width, 3)
        if gt.shape != want:
            raise InputError(f"ground truth is {gt.shape}, expected {want}",
                             file=str(ground_truth_path), field="ground_truth")
    with StagedOutput(final, "render --progressive", LAYER_FILES) as out:
        last, rows = _refine_into(out, scene, method_name, settings, time_budget, frames, gt,
                                  console)
    console.print(f"[green]{method_name}[/] progressive: {last.frame} frames in "
                  f"{last.seconds:.1f} s -> {final}/progressive_{last.frame:05d}.exr")
    if stages := format_stages(last.layers.stats):
        console.print(f"stages of the last frame: {stages} (the scene was prepared once)")
    if rows:
        console.print(f"error: {rows[0][2]:.5f} -> {rows[-1][2]:.5f} "
                      f"({final}/error.csv, {final}/error.png)")


def _refine_into(out: Path, scene: ARScene, method_name: str, settings: RenderSettings,
                 time_budget: float, frames: int, gt: np.ndarray | None, console
                 ) -> tuple[RefineStep, list[tuple[int, float, float]]]:
    """The refinement loop of :func:`run_cli`, writing its files into the folder ``out``."""
    from arlight.io.images import atomic_write
    from arlight.progress import task

    rows: list[tuple[int, float, float]] = []
    last: RefineStep | None = None
    total = frames if frames else None
    with task(f"{method_name} progressive (frames)", total) as bar:
        for step in refine(scene, method_name, settings, time_budget=time_budget,
                           frames=frames or None):
            last = step
            err_text = ""
            if gt is not None:
                e = rmse(step.image, gt)
                rows.append((step.frame, step.seconds, e))
                err_text = f"RMSE {e:.5f}"
                console.print(f"frame {step.frame:5d}  {step.seconds:7.2f} s  RMSE {e:.6f}")
            bar.advance(info=err_text)
            if step.frame & (step.frame - 1) == 0:
                _snapshot(out, scene, step.image, step.frame)
    assert last is not None
    _snapshot(out, scene, last.image, last.frame)
    if rows:
        with atomic_write(out / "error.csv", ".csv") as tmp, open(tmp, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["frame", "seconds", "rmse"])
            w.writerows(rows)
        write_error_plot(rows, out / "error.png")
    return last, rows


