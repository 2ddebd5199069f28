"""Run methods × scenes: warm wall time, peak memory, counters and image metrics per cell.

    from arlight.evaluate.harness import EvalConfig, run_evaluation
    results = run_evaluation(EvalConfig(methods=["reference"], scenes=["bunny-box"]))

Every cell (method, scene) is independent: an unknown method or scene, a missing ground-truth
cache (with ``cache_only``) or a method that raises is recorded in that cell's ``error`` and
the other cells still run. A cell the method cannot handle — the scene has a material or
light type outside the method's capabilities, or it needs depth the scene lacks — is
*skipped*: ``skipped`` holds the reason, the report shows it, and the ground truth of a scene
every method skips is not rendered.

Options: :attr:`EvalConfig.options` maps ``"method.key"`` (one method) or a bare ``"key"``
(every evaluated method that declares it) to a value; :func:`method_options` resolves and
validates them before any cell runs, so an unknown key is an :class:`InputError`, not a
column of failed cells.

Timing follows the method interface: a world is prepared once and then rendered per frame.
One warm-up (prepare + render: JIT compilation, kernel caches), then one timed
``prepare(world)`` (``stages["prepare"]``) and ``repeats`` timed ``render(state, view)``
calls from that state; the reported time is their median wall time (``time.perf_counter``),
the per-frame cost, and the other ``stages`` are the ``time_<stage>`` stats of the median run,
which add up to no more than it. The metrics are computed on the last timed call's output.
Each point of the spp sweep is also warmed up once before its
timed call (Dr.Jit compiles kernels per sample count).

Memory: Dr.Jit/LLVM allocate outside Python's allocator, so ``tracemalloc`` does not see
them, and ``ru_maxrss`` is a process-lifetime high-water mark that cannot be reset between
cells. The harness therefore samples the process RSS (``psutil``) every
:data:`RSS_INTERVAL_S` in a background thread during the warm-up call and reports the peak
minus the RSS just before it: the extra resident memory the method needs (MiB). Short spikes
between samples can be missed, and memory freed by an earlier cell and reused is not counted.
"""

from __future__ import annotations

import statistics
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from arlight.cache import default_cache_dir
from arlight.errors import InputError
from arlight.evaluate import metrics as M
from arlight.evaluate.distribution import LADDER_METHOD, LADDER_SPP, LadderPoint, onepass_at
from arlight.evaluate.suite import QUICK_WIDTH, SuiteScene, get_scene
from arlight.evaluate.variants import base_method, split_variant
from arlight.methods import RenderSettings, get_method
from arlight.synthetic import SyntheticPhoto, content_key
from arlight.timing import stage_times

RSS_INTERVAL_S = 0.005


@dataclass
class EvalConfig:
    """What to evaluate and how.

    Attributes:
        methods: registered method names.
        scenes: suite scene names.
        quick: CI resolution (80 px wide) instead of the papers' resolutions.
        spp: samples per pixel given to each method.
        gt_spp: samples per pixel of the synthetic frame and ground truth.
        repeats: timed calls per cell (after one warm-up call); the median is reported.
        seed: method seed (the ground truth uses its own seeds).
        max_depth: path depth given to the methods and the ground truth.
        use_cache: read/write the synthetic-photo cache.
        cache_only: fail a scene's cells when its ground truth is not cached (no rendering).
        cache_dir: cache root (default ``$ARLIGHT_CACHE`` or ``~/.cache/arlight``).
        sweep_spp: spp values for the error-vs-spp / error-vs-time curves (empty: none).
        options: method options: ``"method.key"`` for one method or a bare ``"key"`` for
            every evaluated method that declares it (see :func:`method_options`); values as
            in :attr:`RenderSettings.options` (command-line strings are converted).
        worlds: seeds of generated worlds (:mod:`arlight.evaluate.worlds`) to evaluate
            after the suite ``scenes``; each is the scene ``world-<seed>``.
        world_width: image width of the generated worlds (px; default 80 when ``quick``,
            else 640).
        equal_time: time ``onepass`` on a ladder of spp per scene and compare every method
            with it at the method's own frame time (:mod:`arlight.evaluate.distribution`).
        ladder_spp: the spp of that ladder (default
            :data:`~arlight.evaluate.distribution.LADDER_SPP`).
    """

    methods: list[str]
    scenes: list[str]
    quick: bool = True
    spp: int = 16
    gt_spp: int = 256
    repeats: int = 3
    seed: int = 0
    max_depth: int = 8
    use_cache: bool = True
    cache_only: bool = False
    cache_dir: Path | None = None
    sweep_spp: list[int] = field(default_factory=list)
    options: dict[str, Any] = field(default_factory=dict)
    worlds: list[int] = field(default_factory=list)
    world_width: int | None = None
    equal_time: bool = False
    ladder_spp: list[int] = field(default_factory=lambda: list(LADDER_SPP))

    def __post_init__(self) -> None:
        if not self.methods:
            raise InputError("no methods given", field="methods")
        if not self.scenes and not self.worlds:
            raise InputError("no scenes given", field="scenes")
        if self.world_width is not None and self.world_width < 8:
            raise InputError(f"must be >= 8 px, got {self.world_width}", field="width")
        for name in ("spp", "gt_spp", "repeats"):
            if getattr(self, name) < 1:
                raise InputError(f"must be >= 1, got {getattr(self, name)}", field=name)
        if any(s < 1 for s in [*self.sweep_spp, *self.ladder_spp]) or not self.ladder_spp:
            raise InputError(f"spp values must be >= 1, got {self.ladder_spp}",
                             field="ladder")
        if any(s < 1 for s in self.sweep_spp):
            raise InputError(f"spp values must be >= 1, got {self.sweep_spp}", field="sweep")
        if self.cache_only and not self.use_cache:
            raise InputError("cache_only needs the cache (do not combine with --no-cache)",
                             field="cache")


@dataclass
class SweepPoint:
    """One point of an error-vs-spp curve."""

    spp: int
    seconds: float
    rmse: float
    psnr: float
    flip: float


@dataclass
class CellResult:
    """The outcome of one (method, scene) cell.

    ``images`` holds ``frame``, ``composite``, ``ground_truth`` (radiance) and ``mask`` for
    the report; ``metrics`` the whole-image metrics and the same with prefix ``changed_`` on
    :func:`~arlight.evaluate.metrics.changed_region`; ``stats`` the method's counters;
    ``stages`` the seconds of the one ``prepare`` and per stage of the median timed frame
    (``trace``, ...); ``seconds`` the median frame time (without ``prepare``); ``skipped``
    why the method cannot handle the scene (the cell did not run).
    """

    method: str
    scene: str
    error: str = ""
    traceback: str = ""
    skipped: str = ""
    seconds: float = float("nan")
    seconds_all: list[float] = field(default_factory=list)
    peak_mib: float = float("nan")
    stats: dict[str, float] = field(default_factory=dict)
    stages: dict[str, float] = field(default_factory=dict)
    metrics: dict[str, float] = field(default_factory=dict)
    sweep: list[SweepPoint] = field(default_factory=list)
    resolution: tuple[int, int] = (0, 0)
    images: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    exposure: float = 0.0
    transfer_kind: str = "srgb"

    @property
    def ok(self) -> bool:
        """The cell ran and has metrics (neither failed nor skipped)."""
        return not self.error and not self.skipped


@dataclass
class EvalResults:
    """All cells of a run plus the configuration and per-scene descriptions."""

    config: EvalConfig
    cells: list[CellResult]
    scenes: dict[str, dict[str, str]] = field(default_factory=dict)
    seconds_total: float = 0.0
    ladders: dict[str, list[LadderPoint]] = field(default_factory=dict)
    """Per scene, the ``onepass`` time ladder of the equal-time comparison."""

    def world_classes(self) -> dict[str, str]:
        """Scene name → world class of the generated worlds evaluated."""
        return {k: v["class"] for k, v in self.scenes.items() if "class" in v}


class PeakRSS:
    """Context manager: peak resident memory above the level at entry, in MiB (psutil)."""

    def __init__(self, interval: float = RSS_INTERVAL_S):
        import psutil

        self._proc = psutil.Process()
        self._interval = interval
        self._stop = threading.Event()
        self.base = 0
        self.peak = 0

    def _run(self) -> None:
        while not self._stop.is_set():
            self.peak = max(self.peak, self._proc.memory_info().rss)
            self._stop.wait(self._interval)

    def __enter__(self) -> PeakRSS:
        self.base = self.peak = self._proc.memory_info().rss
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.peak = max(self.peak, self._proc.memory_info().rss)
        self._stop.set()
        self._thread.join()

    @property
    def mib(self) -> float:
        return (self.peak - self.base) / 2**20


def world_names(config: EvalConfig) -> list[str]:
    """Scene names of the generated worlds of ``config`` (``world-<seed>``)."""
    return [f"world-{s}" for s in config.worlds]


def eval_scene(name: str, config: EvalConfig) -> SuiteScene:
    """A suite scene, or a generated world named ``world-<seed>`` at ``config``'s world
    width."""
    if name.startswith("world-") and name[6:].isdigit():
        from arlight.evaluate.worlds import generate

        width = config.world_width or (QUICK_WIDTH if config.quick else None)
        return generate(int(name[6:])).suite_scene(width)
    return get_scene(name, quick=config.quick)


def scene_info(scene: SuiteScene) -> dict[str, str]:
    """What the report says about a scene (and, for a generated world, its class and
    split)."""
    info = {"description": scene.description, "paper_figure": scene.paper_figure,
            "resolution": "{}×{}".format(*scene.resolution)}
    if scene.paper_figure.startswith("generated ("):
        from arlight.evaluate.worlds import GENERATOR_VERSION

        split, _, cls = scene.paper_figure[len("generated ("):-1].partition(", ")
        info.update({"split": split, "class": cls, "generator": str(GENERATOR_VERSION)})
    return info


def photo_cache_path(scene: SuiteScene, config: EvalConfig) -> Path:
    """Where :func:`arlight.synthetic.synthesize` caches this scene's photo."""
    key = content_key(scene.world, spp=config.gt_spp, seed=1, max_depth=config.max_depth,
                      rr_depth=5)
    return Path(config.cache_dir or default_cache_dir()) / "synthetic" / f"{key}.npz"


def scene_photo(scene: SuiteScene, config: EvalConfig) -> SyntheticPhoto:
    """The scene's frame and ground truth (from the cache, or rendered unless cache_only)."""
    if config.cache_only and not photo_cache_path(scene, config).is_file():
        raise InputError(f"ground truth of {scene.name!r} is not cached at "
                         f"{photo_cache_path(scene, config)}; run without --cache-only "
                         f"(or `arlight synth`) first", field="cache")
    return scene.photo(spp=config.gt_spp, seed=1, max_depth=config.max_depth,
                       cache_dir=config.cache_dir, use_cache=config.use_cache)


def _error(exc: BaseException) -> str:
    return str(exc) if isinstance(exc, InputError) else f"{type(exc).__name__}: {exc}"


def method_options(methods: list[str], options: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Per-method options from ``"method.key"`` and bare ``"key"`` entries, validated.

    A bare key goes to every method in ``methods`` whose spec declares it; a qualified key
    overrides it for its method. Raises :class:`InputError` when a qualified key names a
    method that is not evaluated or an option that method does not declare, when no
    evaluated method declares a bare key (the message lists the options of each), or when a
    value is invalid. Unknown method names get no options (their cells report the error).
    """
    specs = {}
    for m in methods:
        try:
            specs[m] = get_method(base_method(m)).spec
        except InputError:
            continue
    out: dict[str, dict[str, Any]] = {m: dict(split_variant(m)[1]) for m in methods}

    def known() -> str:
        return "; ".join(f"{m}: {', '.join(s.options) or 'none'}" for m, s in specs.items())

    qualified = {k: v for k, v in options.items() if "." in k}
    for key, value in options.items():
        if key in qualified:
            continue
        takers = [m for m, s in specs.items() if key in s.options]
        if not takers:
            raise InputError(f"no evaluated method has option {key!r} (options: {known()})",
                             field="options")
        for m in takers:
            out[m][key] = value
    for key, value in qualified.items():
        method, _, opt = key.partition(".")
        if method not in out:
            raise InputError(f"option {key!r} is for method {method!r}, which is not "
                             f"evaluated (methods: {', '.join(methods)})", field="options")
        if method in specs and opt not in specs[method].options:
            raise InputError(f"method {method!r} has no option {opt!r} (options: {known()})",
                             field="options")
        out[method][opt] = value
    for m, spec in specs.items():
        spec.parse_options(out[m])
    return out


@dataclass
class _SuppliedView:
    """What the harness will give a method of a suite scene: a frame (the synthetic photo)
    and the proxy's depth, if any — for the capability check before rendering the photo."""

    frame: object
    depth: np.ndarray | None


def skip_reason(method: str, scene: SuiteScene) -> str:
    """Why ``method`` cannot handle ``scene`` ('' if it can, or if the method is unknown)."""
    try:
        spec = get_method(base_method(method)).spec
    except InputError:
        return ""
    return spec.unsupported_reason(scene.proxy, _SuppliedView(True, scene.proxy.depth)) or ""


def _median_run_stages(seconds: list[float], runs: list[dict[str, float]]) -> dict[str, float]:
    """The stage times of the run with the (low) median wall time, so that they add up to
    no more than the reported median (medians of each stage need not)."""
    i = seconds.index(statistics.median_low(seconds))
    return dict(runs[i])


def changed_region(photo: SyntheticPhoto) -> np.ndarray:
    """The pixels the insertion changes (:func:`arlight.evaluate.metrics.changed_region`)."""
    return M.changed_region(photo.frame, photo.ground_truth, photo.mask, photo.frame_stderr,
                            photo.ground_truth_stderr)


def composite_metrics(composite: np.ndarray, photo: SyntheticPhoto, transfer,
                      region: np.ndarray) -> dict[str, float]:
    """Whole-image metrics of ``composite`` against the ground truth, the same on
    ``region`` (prefix ``changed_``) and the region's fraction of the image."""
    gt = photo.ground_truth
    return {**M.image_metrics(composite, gt, transfer),
            **M.image_metrics(composite, gt, transfer, region, "changed_"),
            "changed_fraction": float(region.mean())}


def onepass_ladder(scene: SuiteScene, photo: SyntheticPhoto, config: EvalConfig,
                   options: dict[str, Any] | None, max_seconds: float) -> list[LadderPoint]:
    """``onepass`` on ``scene`` at each spp of ``config.ladder_spp`` (the world prepared once;
    per spp one warm-up and ``config.repeats`` timed frames, their median time — timed as
    the methods' cells are, so a load spike during one frame does not decide an equal-time
    comparison), stopped after the first spp slower than ``max_seconds``; empty when
    onepass cannot render the scene."""
    render = get_method(LADDER_METHOD)
    ar = scene.ar_scene(photo)
    if render.spec.unsupported_reason(ar, ar):
        return []

    def settings(spp: int) -> RenderSettings:
        return RenderSettings(spp=spp, max_depth=config.max_depth, seed=config.seed,
                              options=dict(options or {}))

    state = render.prepare(ar.world, settings(1))
    region, tr = changed_region(photo), scene.world.camera.transfer
    points = []
    for spp in sorted(config.ladder_spp):
        render.render(state, ar.view, settings(spp))  # warm-up: kernels compile per spp
        times = []
        for _ in range(config.repeats):
            t0 = time.perf_counter()
            out = render.render(state, ar.view, settings(spp))
            times.append(time.perf_counter() - t0)
        dt = statistics.median(times)
        points.append(LadderPoint(spp, dt, composite_metrics(out.composite, photo, tr,
                                                             region)))
        if dt > max_seconds:
            break
    return points


def attach_equal_time(cells: list[CellResult], ladder: list[LadderPoint]) -> None:
    """Give each successful cell (but onepass's own) the metrics of the onepass frame at
    its frame time (:func:`~arlight.evaluate.distribution.onepass_at`): ``onepass_at_time_
    psnr``, ``..._changed_psnr``, ``..._flip`` (NaN when onepass had no frame that fast)
    and ``onepass_at_time_spp`` (0 then)."""
    if not ladder:
        return
    for c in cells:
        if not c.ok or c.method == LADDER_METHOD:
            continue
        p = onepass_at(ladder, c.seconds)
        for k in ("psnr", "changed_psnr", "flip"):
            c.metrics[f"onepass_at_time_{k}"] = p.metrics[k] if p else float("nan")
        c.metrics["onepass_at_time_spp"] = float(p.spp if p else 0)


def evaluate_cell(method: str, scene: SuiteScene, photo: SyntheticPhoto,
                  config: EvalConfig, options: dict[str, Any] | None = None) -> CellResult:
    """Run one method on one scene: warm-up, timed repeats, metrics, optional spp sweep.

    ``options`` are this method's (see :func:`method_options`); a cell the method cannot
    handle comes back with ``skipped`` set, without running.
    """
    cam = scene.world.camera
    cell = CellResult(method=method, scene=scene.name, resolution=scene.resolution,
                      exposure=cam.transfer.exposure, transfer_kind=cam.transfer.kind)
    try:
        render = get_method(base_method(method))
        ar = scene.ar_scene(photo)
        cell.skipped = render.spec.unsupported_reason(ar, ar) or ""
        if cell.skipped:
            return cell

        def settings(spp: int) -> RenderSettings:
            return RenderSettings(spp=spp, max_depth=config.max_depth, seed=config.seed,
                                  options=dict(options or {}))

        world, view, base = ar.world, ar.view, settings(config.spp)
        with PeakRSS() as mem:
            render.render(render.prepare(world, base), view, base)
        cell.peak_mib = mem.mib
        t0 = time.perf_counter()
        state = render.prepare(world, base)
        prepare_seconds = time.perf_counter() - t0
        runs = []
        for _ in range(config.repeats):
            t0 = time.perf_counter()
            layers = render.render(state, view, base)
            cell.seconds_all.append(time.perf_counter() - t0)
            runs.append(stage_times(layers.stats))
        cell.seconds = statistics.median(cell.seconds_all)
        cell.stages = {"prepare": prepare_seconds,
                       **_median_run_stages(cell.seconds_all, runs)}
        cell.stats = {k: float(v) for k, v in layers.stats.items()
                      if isinstance(v, int | float)}
        gt, tr = photo.ground_truth, cam.transfer
        region = changed_region(photo)
        cell.metrics = composite_metrics(layers.composite, photo, tr, region)
        cell.images = {"frame": photo.frame, "composite": layers.composite,
                       "ground_truth": gt, "mask": photo.mask, "region": region}
        for spp in config.sweep_spp:
            render.render(state, view, settings(spp))  # warm-up: kernels compile per spp
            t0 = time.perf_counter()
            out = render.render(state, view, settings(spp))
            dt = time.perf_counter() - t0
            dc, dg = M.display(out.composite, tr), M.display(gt, tr)
            cell.sweep.append(SweepPoint(spp, dt, M.rmse(out.composite, gt),
                                         M.psnr(dc, dg, peak=1.0), M.flip(dc, dg)))
    except Exception as exc:  # noqa: BLE001 — every failure is reported in its cell
        cell.error = _error(exc)
        cell.traceback = traceback.format_exc()
    return cell


def run_evaluation(config: EvalConfig,
                   log: Callable[[str], None] | None = None) -> EvalResults:
    """Evaluate every method on every scene; failures stay in their cells."""
    log = log or (lambda s: None)
    t_start = time.perf_counter()
    options = method_options(config.methods, config.options)
    cells: list[CellResult] = []
    scenes: dict[str, dict[str, str]] = {}
    ladders: dict[str, list[LadderPoint]] = {}
    for name in [*config.scenes, *world_names(config)]:
        try:
            scene = eval_scene(name, config)
            scenes[name] = scene_info(scene)
            skips = {m: skip_reason(m, scene) for m in config.methods}
            if all(skips.values()):
                for m in config.methods:
                    log(f"{name} × {m}: skipped ({skips[m]})")
                    cells.append(CellResult(method=m, scene=name, skipped=skips[m],
                                            resolution=scene.resolution))
                continue
            log(f"{name}: ground truth ({config.gt_spp} spp, {scenes[name]['resolution']})")
            photo = scene_photo(scene, config)
        except Exception as exc:  # noqa: BLE001
            msg, tb = _error(exc), traceback.format_exc()
            log(f"{name}: ERROR {msg}")
            cells += [CellResult(method=m, scene=name, error=msg, traceback=tb)
                      for m in config.methods]
            continue
        for method in config.methods:
            cell = evaluate_cell(method, scene, photo, config, options[method])
            log(f"{name} × {method}: " + (
                f"ERROR {cell.error}" if cell.error else
                f"skipped ({cell.skipped})" if cell.skipped else
                f"{cell.seconds * 1e3:.0f} ms, PSNR {cell.metrics['psnr']:.2f} dB, "
                f"FLIP {cell.metrics['flip']:.4f}"))
            cells.append(cell)
        mine = [c for c in cells if c.scene == name and c.ok]
        if config.equal_time and mine:
            try:
                ladder = onepass_ladder(scene, photo, config, options.get(LADDER_METHOD),
                                        max(c.seconds for c in mine))
            except Exception as exc:  # noqa: BLE001 — the cells keep their own results
                log(f"{name}: equal-time ladder failed: {_error(exc)}")
                continue
            ladders[name] = ladder
            attach_equal_time(mine, ladder)
            log(f"{name}: onepass ladder " + ", ".join(
                f"{p.spp} spp {p.seconds * 1e3:.0f} ms {p.metrics['psnr']:.1f} dB"
                for p in ladder))
    return EvalResults(config=config, cells=cells, scenes=scenes,
                       seconds_total=time.perf_counter() - t_start, ladders=ladders)
