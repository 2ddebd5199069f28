"""The studio's render engine: one scene, many client sessions, one render worker.

* The scene is loaded once (optionally box-filtered to a smaller studio resolution); each
  method is *prepared* once for its world (``method.prepare``) and every frame is a
  ``method.render`` of that state with the session's object poses as
  ``FrameView.object_transforms`` (``arlight.methods.base``: prepare once, render per frame).
* Picking, placement, rendering and saving run on one render worker thread; sessions with
  pending work are served round robin, one frame per turn. **Preparation** runs off that
  path, on a preparation thread of its own per method (:meth:`Engine._prepare_state`): a
  tab that switches to a method with a slow preparation gets a ``preparing`` status and
  waits for it alone while the worker renders the other tabs' frames; tabs that want the
  same method share one preparation. A method's ``prepare`` and ``render`` never overlap
  for the same state (the state is handed to the worker only when complete).
* At most :attr:`StudioConfig.max_sessions` sessions are open at once
  (:class:`SessionLimit` beyond it; the server answers HTTP 503).
* **Latest wins.** A client message only updates the session's state and bumps its
  version; the worker renders whatever the newest state is when it gets to the session, so
  a burst of drag events costs one frame, never a queue of stale ones. A frame in flight
  cannot be interrupted (the method interface has no cancellation point); when it finishes
  after a newer change it is still shown, flagged ``superseded``, and the newest state is
  rendered next. The outgoing side is latest-wins too (:mod:`arlight.studio.server`).
* **Progressive methods** (capability ``progressive``, e.g. ``onepass``) refine while the
  session is idle: frame ``n`` is rendered with :func:`arlight.progressive.frame_settings`
  (onepass: the next samples of one sequence; others: seed ``frame_seed(seed, n)``) and
  folded into running means by Kán Eq. 4.12
  (:class:`arlight.progressive.Accumulator`), exactly as ``arlight render --progressive``
  does; any change restarts at ``n = 1``.
* **Adaptive resolution** (:mod:`arlight.studio.adaptive`, issue #32): while drag and
  pose messages keep coming, a frame is rendered at 1/k of the size, k chosen per method
  from the measured render times against :attr:`StudioConfig.frame_budget_ms`, and its
  layers are upsampled (bilinear) and composited over the full-size photo; once no motion
  message came for :attr:`StudioConfig.rest_ms` the frame is rendered at full size once
  (progressive methods then refine as before; methods with several G-buffer samples per
  pixel show full size at one sample first, then the antialiased frame:
  :attr:`DragStates.preview`). Each frame's header gives its rendered
  ``width``/``height``, ``factor`` and ``latency_ms`` (newest change → frame posted).
  Per-frame work that does not shrink with the image (RSMs, volumes, propagation, VPLs)
  is scaled through the options the method's spec declares for drag frames
  (:attr:`~arlight.methods.spec.MethodSpec.drag_options`); where those are preparation
  options, drag frames render a second state prepared with them (:class:`DragStates`).
* Errors stay in their session: a failing render or a bad message is reported to that
  client only.
"""

from __future__ import annotations

import collections
import concurrent.futures
import copy
import os
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from arlight.errors import InputError
from arlight.evaluate.metrics import rmse
from arlight.jit import FREEZE_LOCK
from arlight.methods import Method, RenderSettings, get_method, methods
from arlight.methods.base import Layers, Prepared
from arlight.output_guard import check_outputs, file_digest, record_written, written_by_arlight
from arlight.progressive import Accumulator, frame_settings
from arlight.scene.load import PATH_KEYS
from arlight.scene.model import ARScene
from arlight.studio import imaging
from arlight.studio.adaptive import ScaleController, at_rest, drag_factors, until_rest
from arlight.studio.footprint import DragImages, PhotoCodes, Window, footprint, footprint_window
from arlight.studio.pose import ObjectPose
from arlight.studio.protocol import Message, ProtocolError

IMAGE_LAYERS = ("composite", "mixed", "delta", "mask")
DEFAULT_METHODS = ("dir", "dlpv", "ibl", "dvct", "prt", "onepass")
"""Preferred first method when the scene's [render] table names no interactive one."""

REFINE_IDLE_S = 0.25
"""A progressive method starts refining only after the tab has been quiet this long,
seconds: a refinement frame cannot be interrupted, so none is started while the pointer is
busy (a pick pauses it, and the drag that follows does not wait behind one)."""

HOLD_TIMEOUT_S = 10.0
"""While the pointer holds an object (a ``pick`` that found one, until ``release``) no
refinement frame starts, so the drag never waits behind one; a tab that never sends
``release`` gets refinement back after this many quiet seconds."""

Post = Callable[[str, Any], None]
"""How the worker hands a message to a session's connection: ``post("json", dict)`` or
``post("frame", bytes)``; must be thread-safe (the server wraps ``call_soon_threadsafe``)."""


@dataclass
class StudioConfig:
    """Settings of ``arlight studio``.

    Attributes:
        scene: the scene file.
        resolution: ``(width, height)`` of the studio's frames (None: the scene's); the
            scene's must be an integer multiple (the frame is box-filtered).
        method: the first method (None: the scene's [render] method if interactive, else
            the first of :data:`DEFAULT_METHODS` that supports the scene).
        save_dir: where the save button writes (None: the scene's folder).
        ground_truth: a ground-truth EXR at the scene's resolution for the error layer
            (None: ``ground_truth.exr`` beside the scene file if there is one).
        image_format: ``jpeg``, ``png`` or ``webp``.
        quality: JPEG/WebP quality, 1–100.
        seed: base seed of the Monte Carlo methods.
        max_refine: most frames a progressive method accumulates while idle.
        max_sessions: most sessions (tabs) open at once; a further one is refused.
        frame_budget_ms: render budget of a frame while the pointer drags, milliseconds
            (0: always render at full size).
        rest_ms: the pointer rests when no drag or pose message came for this long,
            milliseconds; a frame rendered smaller is then rendered again at full size.
        drag_threads: Dr.Jit LLVM worker threads while a drag frame (rendered smaller)
            renders, 0: Dr.Jit's default (one per core); full-size frames always render
            with the default. A drag frame is some 300 small kernels: on a loaded machine
            (the browser, other processes) each launch on two workers waits for both to be
            scheduled — with one, drag frames cost 0.5–0.6× the CPU and wall time
            (issue #32, docs/studio.md).
        drag_calls: how drag frames run Dr.Jit's virtual function calls (Mitsuba's shape
            and BSDF dispatch): ``evaluated`` (``JitFlag.SymbolicCalls`` off: the
            instances a call reaches are found first, each runs as its own kernel) or
            ``symbolic`` (Dr.Jit's default: every registered instance is traced into one
            kernel — every shape and BSDF of every Mitsuba scene alive in the process, the
            prepared states of all methods and drag sizes: ~1.3 ms per scene pair per
            call). Same images bit for bit; evaluated: drag frames 0.35–0.85× the time
            with the five methods prepared.
    """

    scene: Path
    resolution: tuple[int, int] | None = None
    method: str | None = None
    save_dir: Path | None = None
    ground_truth: Path | None = None
    image_format: str = "jpeg"
    quality: int = 85
    seed: int = 0
    max_refine: int = 256
    max_sessions: int = 16
    frame_budget_ms: float = 100.0
    rest_ms: float = 150.0
    drag_threads: int = 1
    drag_calls: str = "evaluated"


MOTION = frozenset({"drag", "pose"})
"""Messages that mean the pointer is moving something (rendered at the adaptive scale)."""


class SessionLimit(RuntimeError):
    """The studio already has ``max_sessions`` open sessions."""


class SaveExists(ProtocolError):
    """A save would replace existing files that this studio did not write; the page may
    ask the user and send the save again with ``overwrite: true``."""

    def __init__(self, message: str, names: list[str]) -> None:
        super().__init__(message)
        self.names = names


@dataclass
class Session:
    """One client's view of the studio (guarded by ``lock``; the worker reads snapshots)."""

    id: int
    post: Post
    method: str
    poses: dict[str, ObjectPose]
    lock: threading.Lock = field(default_factory=threading.Lock)
    selected: str | None = None
    grab: tuple[float, float] = (0.0, 0.0)  # anchor pixel minus pointer pixel at pick time
    pending_drag: tuple[float, float] | None = None
    exposure: float = 0.0
    layer: str = "composite"
    denoise: bool = False  # OIDN on the frames of a Monte Carlo method (issue #31)
    running: Any = None  # RunningLayers of the raw frames while a denoised method refines
    aux_full: Any = None  # the denoiser's auxiliary buffers of the refined version
    seq: int | None = None  # newest client seq folded into the state
    version: int = 1  # bumped by every change that needs a new render
    display_version: int = 1  # bumped by exposure/layer changes
    rendered_version: int = 0
    displayed_version: int = 0
    images: Mapping[str, np.ndarray] | None = None  # the current (accumulated) layers
    window: Window | None = None  # a drag frame's: outside it the composite is the photo
    shown: dict[str, Any] = field(default_factory=dict)  # seq, version, method, poses of them
    stats: dict[str, float] = field(default_factory=dict)
    accumulators: dict[str, Accumulator] = field(default_factory=dict)
    refine: int = 0  # frames accumulated for the current version (progressive methods)
    preview: bool = False  # the full-size frame shown is DragStates.preview's (one sample)
    closed: bool = False
    last_message: float = 0.0  # time.monotonic() of the newest client message
    holding: bool = False  # the pointer holds the picked object (pick .. release)
    prep: concurrent.futures.Future | None = None  # the preparation this session waits for
    prep_method: str | None = None  # ... of this method
    frames_sent: int = 0
    superseded: int = 0
    errors: int = 0
    changed_at: float = 0.0  # time.monotonic() of the newest change (latency)
    motion_at: float | None = None  # ... of the newest drag or pose message
    motion_version: int = 0  # the version that message made
    factor: int = 1  # downscale factor of the layers shown (1: full size)

    def bump(self, seq: int | None) -> None:
        """Mark a change that needs a new render (call with ``lock`` held)."""
        self.version += 1
        self.changed_at = time.monotonic()
        if seq is not None:
            self.seq = seq


@dataclass(frozen=True)
class MethodInfo:
    """A method the studio lists: name, description, progressive, why not (or None)."""

    name: str
    description: str
    progressive: bool
    unsupported: str | None
    noisy: bool = False  # has the denoiser's options (Monte Carlo noise)

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "description": self.description,
                "progressive": self.progressive, "unsupported": self.unsupported,
                "denoise": self.noisy}


def _resized(scene: ARScene, resolution: tuple[int, int] | None, file: str) -> ARScene:
    if resolution is None or resolution == scene.resolution:
        return scene
    try:
        return scene.resized(*resolution)
    except ValueError as exc:
        raise InputError(f"{exc} (the scene is {scene.resolution[0]}×{scene.resolution[1]};"
                         " use a size it divides by an integer)", file=file,
                         field="--resolution") from exc


def _box_filter(image: np.ndarray, width: int, height: int) -> np.ndarray:
    h, w = image.shape[:2]
    k = h // height
    return image.reshape(height, k, width, k, -1).mean(axis=(1, 3)).astype(np.float32)


def new_jit_scope() -> None:
    """Start a new Dr.Jit scope on this thread: required where arrays cross threads (a
    preparation thread reads the world, the render worker then uses the prepared state);
    Dr.Jit orders a kernel's variables by scope and refuses a dependency on a scope newer
    than its own."""
    import drjit as dr

    from arlight.backend import VARIANT

    dr.detail.new_scope(dr.JitBackend.CUDA if VARIANT.startswith("cuda")
                        else dr.JitBackend.LLVM)


def freeze_heap() -> None:
    """Collect the garbage, then move every live object out of the collector's reach
    (``gc.freeze``): the prepared states (Mitsuba scenes, NumPy arrays, Python objects by
    the hundred thousand) are never garbage, but a full collection scanned them all —
    80 ms and more, at random drag frames (issue #32: the p95 latency). Called on the
    worker after a state arrives, when no preparation is running (none of its
    temporaries frozen)."""
    import gc

    gc.collect()
    gc.freeze()


def _transforms(poses: dict[str, ObjectPose]) -> dict[str, np.ndarray]:
    """``FrameView.object_transforms`` of the poses (objects at rest are left out)."""
    return {k: p.matrix() for k, p in poses.items() if not p.is_rest}


@dataclass
class DragStates:
    """The states and settings drag frames render with, per downscale factor: the options
    of the method's :attr:`~arlight.methods.spec.MethodSpec.drag_options` at that factor;
    factors whose preparation options equal the full-size frame's share its state, the
    others one state per distinct set of preparation options (prepared once, with the
    full-size state, off the render path; each poses itself when a frame moves objects).

    Attributes:
        full: the full-size frame's state.
        base: the studio's settings.
        by_factor: factor -> (state, settings) of the factors that differ from ``full``.
        preview: the settings of the first full-size frame at rest when the method takes
            several G-buffer samples per pixel (``gbuffer_spp`` > 1, a frame option of its
            spec): one sample, with ``full``'s state — the pointer's rest shows full size
            at a fraction of the cost, and the antialiased frame follows (None: no such
            option).
    """

    full: Prepared
    base: RenderSettings
    by_factor: dict[int, tuple[Prepared, RenderSettings]] = field(default_factory=dict)
    preview: RenderSettings | None = None

    @classmethod
    def prepare(cls, fn: Method, world, full: Prepared, base: RenderSettings,
                factors: tuple[int, ...]) -> DragStates:
        """The drag states of ``fn`` (prepared here where the options require it)."""
        out = cls(full, base)
        spec = fn.spec
        opts = spec.parse_options(base.options)
        shared: dict[str, Prepared] = {}
        for k in factors[1:]:
            extra = spec.drag(opts, k)
            if not extra:
                continue
            settings = replace(base, options={**base.options, **extra})
            prep = spec.preparation_options(spec.parse_options(settings.options))
            if prep == spec.preparation_options(opts):
                state = full
            else:
                key = repr(sorted(prep.items()))
                if key not in shared:
                    shared[key] = fn.prepare(world, settings)
                state = shared[key]
            out.by_factor[k] = (state, settings)
        if "gbuffer_spp" in opts and opts["gbuffer_spp"] > 1:
            preview = replace(base, options={**base.options, "gbuffer_spp": 1})
            if (spec.preparation_options(spec.parse_options(preview.options))
                    == spec.preparation_options(opts)):  # the full state renders it
                out.preview = preview
        return out

    def state(self, factor: int) -> Prepared:
        """The state a frame at ``factor`` renders."""
        return self.by_factor[factor][0] if factor in self.by_factor else self.full

    def settings(self, factor: int) -> RenderSettings:
        """The settings a frame at ``factor`` renders with."""
        return self.by_factor[factor][1] if factor in self.by_factor else self.base


class Engine:
    """Loads the scene, owns the render worker and the sessions (see the module doc)."""

    def __init__(self, config: StudioConfig) -> None:
        from arlight.scene.load import load_scene

        self.config = config
        if config.image_format not in imaging.FORMATS:
            raise InputError(f"unknown image format {config.image_format!r}; use one of "
                             f"{', '.join(imaging.FORMATS)}", field="--format")
        if config.image_format == "webp" and not imaging.webp_available():
            raise InputError("this Pillow cannot write WebP; use jpeg or png",
                             field="--format")
        if not 1 <= config.quality <= 100:
            raise InputError(f"must be in [1, 100], got {config.quality}", field="--quality")
        if not 1 <= config.max_sessions <= 4096:
            raise InputError(f"must be in [1, 4096], got {config.max_sessions}",
                             field="--max-sessions")
        for name, v in (("--frame-budget-ms", config.frame_budget_ms),
                        ("--rest-ms", config.rest_ms)):
            if not 0 <= v <= 60000:
                raise InputError(f"must be in [0, 60000] ms, got {v}", field=name)
        if config.drag_calls not in ("evaluated", "symbolic"):
            raise InputError(f"must be evaluated or symbolic, got {config.drag_calls!r}",
                             field="--drag-calls")
        if not 0 <= config.drag_threads <= 256:
            raise InputError(f"must be in [0, 256], got {config.drag_threads}",
                             field="--drag-threads")
        self.source = Path(config.scene).resolve()
        self.full = load_scene(self.source)
        if self.full.frame is None:
            raise InputError("the scene has no background frame to composite onto; add a "
                             "[frame] table with `image = ...`", file=str(self.source),
                             field="frame")
        if not self.full.virtual_shapes:
            raise InputError("the scene has no virtual shape to move", file=str(self.source),
                             field="shapes")
        self.scene = _resized(self.full, config.resolution, str(self.source))
        self.view = self.scene.view
        self.width, self.height = self.scene.resolution
        self.factors = (drag_factors(self.width, self.height)
                        if config.frame_budget_ms > 0 else (1,))
        self.views = {k: self.scene.resized(self.width // k, self.height // k).view
                      for k in self.factors}  # the camera resized, photo box-filtered
        self.rest_s = config.rest_ms / 1e3
        self._photo = PhotoCodes(self.view.frame)  # its display codes per exposure
        self._jit_threads: int | None = None  # Dr.Jit's default worker count (worker thread)
        self._scales: dict[str, ScaleController] = {}  # per method; worker thread only
        self._wake_at = float("inf")  # the earliest rest of a session shown downscaled
        self.save_dir = Path(config.save_dir or self.source.parent).resolve()
        self.inputs = self._input_files()
        self.ground_truth = self._ground_truth()
        self.catalogue = self._catalogue()
        self.default_method = self._default_method()
        self.settings = RenderSettings(spp=1, seed=config.seed)
        self._states: dict[str, Prepared] = {}
        self._drag: dict[str, DragStates] = {}  # per method, set with _states
        self._preparing: dict[str, concurrent.futures.Future] = {}
        self._handoff = False  # a state came from a preparation thread since the last scope
        self.max_sessions = int(config.max_sessions)
        self.sessions_opened = 0  # every session ever opened (tests: refused = not counted)
        self._created: dict[Path, str] = {}  # files this studio saved -> SHA-256 written
        self._sessions: dict[int, Session] = {}
        self._next_id = 1
        self._rr: collections.deque[int] = collections.deque()
        self._calls: collections.deque[tuple[Callable[[], Any], concurrent.futures.Future]] = (
            collections.deque())
        self._cond = threading.Condition()
        self._stop = False
        self._thread: threading.Thread | None = None
        self.proxy = None  # built on the worker thread
        self.rest_poses: dict[str, ObjectPose] = {}

    # ------------------------------------------------------------------ set-up
    def _input_files(self) -> set[Path]:
        """The scene file and every file it references (a save may not overwrite them)."""
        out = {self.source}

        def walk(x: Any) -> None:
            if isinstance(x, dict):
                for k, v in x.items():
                    if k in PATH_KEYS and isinstance(v, str):
                        out.add(Path(v).resolve())
                    else:
                        walk(v)
            elif isinstance(x, list):
                for v in x:
                    walk(v)

        walk(self.full.raw)
        if self.config.ground_truth is not None:
            out.add(Path(self.config.ground_truth).resolve())
        return out

    def _ground_truth(self) -> np.ndarray | None:
        from arlight.io.images import read_hdr

        path = self.config.ground_truth
        if path is None:
            auto = self.source.parent / "ground_truth.exr"
            if not auto.is_file():
                return None
            path = auto
        gt = read_hdr(path)
        want = (self.full.camera.height, self.full.camera.width, 3)
        if gt.shape != want:
            raise InputError(f"ground truth is {gt.shape}, expected {want}", file=str(path),
                             field="ground_truth")
        return _box_filter(gt, self.width, self.height) if self.width != want[1] else gt

    def _catalogue(self) -> dict[str, MethodInfo]:
        out = {}
        for name, m in methods().items():
            caps = m.spec.capabilities
            if not caps.interactive:
                continue
            out[name] = MethodInfo(name, m.spec.description, caps.progressive,
                                   m.spec.unsupported_reason(self.scene, self.scene),
                                   bool(caps.noisy))
        if not out:
            raise InputError("no registered method renders interactive frames",
                             field="method")
        return out

    def _default_method(self) -> str:
        name = self.config.method or self.full.raw.get("render", {}).get("method")
        if self.config.method is not None:
            self.check_method(name)
            return name
        if name in self.catalogue and not self.catalogue[name].unsupported:
            return name
        ok = [n for n in DEFAULT_METHODS if n in self.catalogue
              and not self.catalogue[n].unsupported]
        ok += [n for n, i in self.catalogue.items() if not i.unsupported]
        if not ok:
            raise InputError("no interactive method supports this scene: " + "; ".join(
                f"{n}: {i.unsupported}" for n, i in self.catalogue.items()),
                file=str(self.source), field="method")
        return ok[0]

    def check_method(self, name: str) -> Method:
        """The registered interactive method ``name`` that supports the scene, else an
        InputError saying why."""
        if name not in self.catalogue:
            get_method(name)  # unknown: the error lists the registered names
            raise InputError(f"method {name!r} is not interactive; the studio offers "
                             f"{', '.join(self.catalogue)}", field="method")
        if reason := self.catalogue[name].unsupported:
            raise InputError(reason, field="method")
        return get_method(name)

    def info(self) -> dict[str, Any]:
        """The ``info`` message a client gets on connecting."""
        return {"type": "info", "width": self.width, "height": self.height,
                "scene": self.source.name, "methods": [i.to_json()
                                                       for i in self.catalogue.values()],
                "method": self.default_method, "objects": {
                    n: p.to_json() for n, p in self.rest_poses.items()},
                "layers": ["composite", "mixed", "delta", "mask"]
                + (["error"] if self.ground_truth is not None else []),
                "ground_truth": self.ground_truth is not None,
                "format": imaging.FORMATS[self.config.image_format][1],
                "error_gain": imaging.ERROR_GAIN}

    # ------------------------------------------------------------------ worker
    def start(self, timeout: float = 120.0) -> None:
        """Start the worker and wait until the proxy's ray-query scenes are built."""
        if self._thread is not None:
            return
        self._thread = threading.Thread(target=self._loop, name="arlight-studio-render",
                                        daemon=True)
        self._thread.start()
        self.call(self._build_proxy).result(timeout)

    def stop(self) -> None:
        """Stop the worker (pending calls fail)."""
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join(timeout=30)
            self._thread = None

    def _build_proxy(self) -> None:
        from arlight.studio.picking import Proxy

        self.proxy = Proxy(self.scene)
        self.rest_poses = self.proxy.rest_poses()

    def call(self, fn: Callable[..., Any], *args: Any) -> concurrent.futures.Future:
        """Run ``fn(*args)`` on the worker before any further render; a Future of it."""
        fut: concurrent.futures.Future = concurrent.futures.Future()
        with self._cond:
            if self._stop:
                fut.set_exception(RuntimeError("the studio is stopping"))
                return fut
            self._calls.append((lambda: fn(*args), fut))
            self._cond.notify_all()
        return fut

    def wake(self) -> None:
        with self._cond:
            self._cond.notify_all()

    def _loop(self) -> None:
        while True:
            with self._cond:
                while True:
                    if self._stop:
                        for _, fut in self._calls:
                            fut.set_exception(RuntimeError("the studio stopped"))
                        self._calls.clear()
                        return
                    call = self._calls.popleft() if self._calls else None
                    work = self._next_work() if call is None else None
                    if call is not None or work is not None:
                        break
                    self._cond.wait(timeout=min(REFINE_IDLE_S / 2, max(
                        0.001, self._wake_at - time.monotonic())))
            if self._handoff:  # arrays from a preparation thread: a new scope first
                with self._cond:
                    self._handoff = False
                    settled = not self._preparing
                new_jit_scope()
                if settled:
                    freeze_heap()
            if call is not None:
                fn, fut = call
                if fut.set_running_or_notify_cancel():
                    try:
                        fut.set_result(fn())
                    except BaseException as exc:  # noqa: BLE001 — handed to the caller
                        fut.set_exception(exc)
            elif work is not None:
                self._serve(*work)

    def _next_work(self) -> tuple[Session, str] | None:
        """The next (session, kind) round robin: renders and re-encodes before refinement
        (call with ``_cond`` held); sets :attr:`_wake_at` to the earliest time a session
        shown downscaled comes to rest."""
        self._wake_at = float("inf")
        for want in ("render", "refine"):
            for _ in range(len(self._rr)):
                sid = self._rr[0]
                self._rr.rotate(-1)
                s = self._sessions.get(sid)
                if s is None:
                    continue
                kind = self._work_of(s)
                if kind == want or (want == "render"
                                    and kind in ("display", "prepfail", "settle")):
                    return s, kind
        return None

    def _work_of(self, s: Session) -> str | None:
        """What the worker would do for ``s`` now (call with ``_cond`` held): ``render``,
        ``display`` (re-encode), ``settle`` (full size again once the pointer rests),
        ``refine``, ``prepfail`` (report a failed preparation) or None — also when the
        render waits for the method's preparation, which this starts on its own thread."""
        with s.lock:
            if s.closed:
                return None
            if s.version != s.rendered_version:
                if s.method in self._states:
                    return "render"
                if s.prep is not None and s.prep_method == s.method and s.prep.done():
                    return "prepfail"  # it failed (a success is in _states)
                if s.prep is None or s.prep_method != s.method:
                    s.prep, s.prep_method = self._start_preparing(s.method), s.method
                    s.post("json", {"type": "status", "preparing": s.method,
                                    "message": f"preparing {s.method}…"})
                if s.display_version != s.displayed_version:
                    return "display"
                return None
            if s.display_version != s.displayed_version:
                return "display"
            if s.factor > 1 or s.preview:  # downscaled or one-sample: full once at rest
                now = time.monotonic()
                if at_rest(now, s.motion_at, self.rest_s):
                    return "settle"
                self._wake_at = min(self._wake_at, now + until_rest(now, s.motion_at,
                                                                     self.rest_s))
                return None
            if (s.refine and self.catalogue[s.method].progressive
                    and s.refine < self.config.max_refine
                    and self._quiet(s)):
                return "refine"
        return None

    @staticmethod
    def _quiet(s: Session) -> bool:
        """Whether a progressive session may start a refinement frame (``s.lock`` held)."""
        quiet = time.monotonic() - s.last_message
        return quiet >= (HOLD_TIMEOUT_S if s.holding else REFINE_IDLE_S)

    def _serve(self, s: Session, kind: str) -> None:
        try:
            if kind == "display":
                self._send_frame(s, superseded=False)
            elif kind == "prepfail":
                with s.lock:
                    fut, s.prep = s.prep, None
                exc = fut.exception() if fut is not None else None
                if exc is not None:
                    raise exc
            else:  # render, settle (at rest: full size), refine
                self._render(s, refine=kind == "refine", settle=kind == "settle")
        except Exception as exc:  # noqa: BLE001 — one session's failure stays in it
            with s.lock:
                s.errors += 1
                s.rendered_version = s.version  # do not retry the same state forever
                s.refine = 0
                s.factor = 1  # nor its full-size frame at rest
            s.post("json", {"type": "error", "message": f"{type(exc).__name__}: {exc}",
                            "request": kind})

    # ------------------------------------------------------------------ preparation
    def _start_preparing(self, name: str) -> concurrent.futures.Future:
        """The Future of ``name``'s preparation, started on its own thread unless one is
        already running (call with ``_cond`` held)."""
        fut = self._preparing.get(name)
        if fut is not None:
            return fut
        fut = concurrent.futures.Future()
        fut.set_running_or_notify_cancel()
        self._preparing[name] = fut

        def run() -> None:
            try:
                new_jit_scope()  # after whatever the worker made from the world
                state, drag = self._prepare_state(name)
                new_jit_scope()
            except BaseException as exc:  # noqa: BLE001 — reported to the waiting sessions
                with self._cond:
                    self._preparing.pop(name, None)
                    self._cond.notify_all()
                fut.set_exception(exc)
                return
            with self._cond:
                self._states[name] = state
                self._drag[name] = drag
                self._handoff = True  # the worker opens a new scope before using it
                self._preparing.pop(name, None)
                self._cond.notify_all()
            fut.set_result(state)

        threading.Thread(target=run, name=f"arlight-studio-prepare-{name}",
                         daemon=True).start()
        return fut

    def _prepare_state(self, name: str) -> tuple[Prepared, DragStates]:
        """``method.prepare`` for the studio's world and the drag states
        (:class:`DragStates`), then one frame at each downscaled size (on a preparation
        thread, before the worker gets the state: Dr.Jit compiles kernels per image size,
        seconds each, which must not stall the first drag)."""
        fn = get_method(name)
        # frames that replay frozen functions wait for it (arlight.jit.FREEZE_LOCK)
        with FREEZE_LOCK:
            state = fn.prepare(self.scene.world, self.settings)
            drag = DragStates.prepare(fn, self.scene.world, state, self.settings,
                                      self.factors)
            for k in self.factors[1:]:
                fn.render(drag.state(k), self.views[k], drag.settings(k))
        return state, drag

    @property
    def preparing(self) -> list[str]:
        """Methods being prepared now."""
        with self._cond:
            return list(self._preparing)

    # ------------------------------------------------------------------ sessions
    def open_session(self, post: Post) -> Session:
        """A new session; :class:`SessionLimit` when ``max_sessions`` are open."""
        with self._cond:
            if len(self._sessions) >= self.max_sessions:
                raise SessionLimit(f"the studio already has {len(self._sessions)} open "
                                   f"tabs (at most {self.max_sessions}); close one and "
                                   "reload")
            s = Session(self._next_id, post, self.default_method, dict(self.rest_poses))
            self._next_id += 1
            self.sessions_opened += 1
            self._sessions[s.id] = s
            self._rr.append(s.id)
            self._cond.notify_all()
        return s

    def close_session(self, s: Session) -> None:
        with s.lock:
            s.closed = True
            s.images = None
            s.accumulators = {}
        with self._cond:
            self._sessions.pop(s.id, None)
            if s.id in self._rr:
                self._rr.remove(s.id)

    @property
    def sessions(self) -> list[Session]:
        with self._cond:
            return list(self._sessions.values())

    # ------------------------------------------------------------------ messages
    def apply(self, s: Session, msg: Message) -> concurrent.futures.Future | None:
        """Fold a checked client message into the session. State changes return None (the
        worker renders them); ``pick`` and ``save`` return a Future of the reply message.
        Raises :class:`ProtocolError` / :class:`InputError` for a message that cannot
        apply (unknown object or method, nothing picked)."""
        kind = msg.type
        with s.lock:
            s.last_message = time.monotonic()
            if kind in MOTION:
                s.motion_at = s.last_message
        if kind == "pick":
            return self.call(self._pick, s, msg["x"], msg["y"], msg.seq)
        if kind == "save":
            return self.call(self._save, s, msg["name"], msg.get("overwrite", False))
        if "object" in msg.fields and msg["object"] not in self.rest_poses:
            raise ProtocolError(f"{kind}: unknown object {msg['object']!r}; objects: "
                                f"{', '.join(self.rest_poses)}")
        with s.lock:
            if kind == "drag":
                if s.selected is None:
                    raise ProtocolError("drag: nothing is picked; send pick on an object "
                                        "first")
                s.pending_drag = (msg["x"] + s.grab[0], msg["y"] + s.grab[1])
                s.bump(msg.seq)
            elif kind == "place":
                s.selected, s.grab = msg["object"], (0.0, 0.0)
                s.pending_drag = (msg["x"], msg["y"])
                s.bump(msg.seq)
            elif kind == "pose":
                s.poses[msg["object"]] = s.poses[msg["object"]].with_(
                    msg.get("yaw_deg"), msg.get("scale"))
                s.bump(msg.seq)
            elif kind == "release":
                s.holding = False
            elif kind == "reset":
                s.poses = dict(self.rest_poses)
                s.pending_drag = None
                s.bump(msg.seq)
            elif kind == "method":
                self.check_method(msg["name"])
                s.method = msg["name"]
                s.bump(msg.seq)
            elif kind == "denoise":
                s.denoise = msg["on"]
                s.bump(msg.seq)
            elif kind == "exposure":
                s.exposure = msg["ev"]
                s.display_version += 1
            elif kind == "layer":
                if msg["name"] == "error" and self.ground_truth is None:
                    raise ProtocolError("layer: the scene has no ground truth (start the "
                                        "studio with --ground-truth FILE.exr)")
                s.layer = msg["name"]
                s.display_version += 1
            if kind in MOTION:  # rendered at the adaptive scale, full size at rest
                s.motion_version = s.version
        self.wake()
        return None

    def _pick(self, s: Session, x: float, y: float, seq: int | None) -> dict[str, Any]:
        with s.lock:
            poses = dict(s.poses)
        name = self.proxy.pick(x, y, poses)
        grab = (0.0, 0.0)
        if name is not None:
            uv = self.proxy.project(poses[name].position)
            grab = (uv[0] - x, uv[1] - y) if uv is not None else (0.0, 0.0)
        with s.lock:
            s.selected, s.grab, s.holding = name, grab, name is not None
        return {"type": "picked", "object": name, "seq": seq}

    # ------------------------------------------------------------------ rendering
    def prepared(self, name: str, timeout: float | None = None) -> Prepared:
        """The method's prepared state, waiting for (or starting) its preparation; not
        for the render worker, which never waits for one."""
        with self._cond:
            if name in self._states:
                return self._states[name]
            fut = self._start_preparing(name)
        return fut.result(timeout)

    def _resolve_drag(self, s: Session) -> tuple[int, int | None, bool]:
        """Stand the picked object on the surface under the pending drag target; returns
        the session version and client seq this covers (a later message makes the frame
        stale) and whether a drag or pose message made that version."""
        with s.lock:
            version, seq, target, name = s.version, s.seq, s.pending_drag, s.selected
            s.pending_drag = None
            motion = version == s.motion_version
        if target is None or name is None:
            return version, seq, motion
        hit = self.proxy.support(*target)
        if hit is None:
            s.post("json", {"type": "status", "message": "no real surface to stand on "
                            "there; the object stays"})
            return version, seq, motion
        with s.lock:
            s.poses[name] = s.poses[name].moved_to(hit.position)
        return version, seq, motion

    def _set_jit_threads(self, drag: bool) -> None:
        """Dr.Jit's LLVM worker count and call mode for the next frame: for a drag frame
        :attr:`StudioConfig.drag_threads` workers and :attr:`StudioConfig.drag_calls`, else
        Dr.Jit's defaults (symbolic calls; set only when they differ; render worker
        only)."""
        import drjit as dr

        if self._jit_threads is None:
            self._jit_threads = dr.thread_count()
        want = (self.config.drag_threads or self._jit_threads) if drag else self._jit_threads
        if dr.thread_count() != want:
            dr.set_thread_count(want)
        symbolic = not (drag and self.config.drag_calls == "evaluated")
        if dr.flag(dr.JitFlag.SymbolicCalls) != symbolic:
            dr.set_flag(dr.JitFlag.SymbolicCalls, symbolic)

    def scale_controller(self, method: str) -> ScaleController:
        """The method's :class:`ScaleController` (render times differ per method)."""
        if method not in self._scales:
            self._scales[method] = ScaleController(
                self.factors, budget_s=self.config.frame_budget_ms / 1e3)
        return self._scales[method]

    def _factor(self, method: str, motion: bool) -> int:
        """The downscale factor of the frame to render now: the controller's for a version
        a drag or pose message made (``motion``; also when the pointer came to rest before
        the worker got to it: the move is shown at once, the full-size frame follows),
        else 1 (full size: at rest, refinement, other changes)."""
        if not motion or len(self.factors) == 1:
            return 1
        return self.scale_controller(method).choose()

    def _drag_images(self, layers: Layers) -> DragImages:
        """The full-size images of a drag frame rendered smaller: bit for bit those of
        ``layers.upsampled(photo)`` (:meth:`arlight.layers.Layers.upsampled`), the
        composite computed in the insertion's footprint only
        (:mod:`arlight.studio.footprint`, issue #32)."""
        window = footprint_window(footprint(layers), self.height, self.width)
        return DragImages(layers, self.view.frame, window)

    def _render(self, s: Session, refine: bool, settle: bool = False) -> None:
        """Render the session's newest state and send it: a new version (at the adaptive
        scale if a motion message made it), ``settle`` (the same version at full size once
        the pointer rests) or ``refine`` (the next progressive frame, full size)."""
        t0 = time.perf_counter()
        started = time.monotonic()
        with s.lock:
            version, seq = s.version, s.seq
            if s.method not in self._states:  # switched since the worker chose this work
                return
            s.prep = None
        motion = False
        if not refine:
            version, seq, motion = self._resolve_drag(s)
        with s.lock:
            method, poses, denoise = s.method, dict(s.poses), s.denoise
            n = s.refine + 1 if refine else 1
            changed_at = s.changed_at
            settle = settle and version == s.rendered_version  # else a new change came
        t_place = time.perf_counter() - t0
        fn = get_method(method)
        state = self._states.get(method)
        if state is None:  # switched meanwhile: the worker prepares it first
            return
        factor = self._factor(method, motion and not (refine or settle))
        view = replace(self.views[factor], object_transforms=_transforms(poses))
        progressive = self.catalogue[method].progressive
        drag = self._drag.get(method)
        settings = drag.settings(factor) if drag is not None else self.settings
        if drag is not None:
            state = drag.state(factor)
        # at rest after a downscaled frame: full size at one G-buffer sample first, then the
        # antialiased frame (the next settle)
        preview = (settle and factor == 1 and drag is not None and drag.preview is not None
                   and s.factor > 1)
        if preview:
            settings = drag.preview
        if progressive:  # frame n of the refinement (onepass: samples continue one sequence)
            settings = frame_settings(fn, settings, n)
        denoise = denoise and self.catalogue[method].noisy
        if denoise:
            settings = replace(settings, options={**settings.options, "denoise": "oidn"})
        self._set_jit_threads(factor > 1)
        t1 = time.perf_counter()
        layers = fn.render(state, view, settings)
        if denoise and progressive and factor == 1:  # denoise the running mean instead
            layers = self._denoised_mean(s, fn, state, view, settings, layers, n)
        t_render = time.perf_counter() - t1
        ctl = self.scale_controller(method)
        if motion and not (refine or settle):
            ctl.observe(factor, t_render)
        else:
            ctl.seed(factor, t_render)
        t2 = time.perf_counter()
        drag_images = self._drag_images(layers) if factor > 1 else None
        t_upsample = time.perf_counter() - t2
        with s.lock:
            if s.closed:
                return
            stale = s.version != version
            if refine and stale:  # a change restarts the refinement; drop this frame
                return
            if stale:
                s.superseded += 1
            else:
                s.rendered_version = version
            # a downscaled frame is shown as it is; refinement starts from the full-size one
            if drag_images is not None:
                s.images, s.refine, s.accumulators = drag_images, 0, {}
                s.window = drag_images.window
            else:
                s.images, s.refine = self._fold(s, layers, n, progressive)
                s.window = None
            s.factor = factor
            s.preview = preview
            s.shown = {"seq": seq, "version": version, "method": method,
                       "objects": {k: p.to_json() for k, p in poses.items()},
                       "width": self.width // factor, "height": self.height // factor,
                       "factor": factor, "preview": preview}
            s.stats = {**{k: float(v) for k, v in layers.stats.items()
                          if k.startswith("time_")},
                       "time_place": t_place, "render_s": t_render,
                       "wait_s": max(started - changed_at, 0.0)}
            if drag_images is not None:
                s.stats["upsample_s"] = t_upsample
                rows, cols = drag_images.window
                s.stats["footprint"] = ((rows.stop - rows.start) * (cols.stop - cols.start)
                                        / (self.width * self.height))
        self._send_frame(s, superseded=stale, changed_at=changed_at)

    def _denoised_mean(self, s: Session, fn: Method, state: Prepared, view, settings,
                       layers: Layers, n: int) -> Layers:
        """The denoised layers of the running mean of the raw frames 1..n of a progressive
        method (:class:`arlight.denoise.differential.RunningLayers`); the auxiliary buffers
        are traced once per refined version (the posed world). Shown as a non-accumulated
        frame by :meth:`_fold`."""
        from arlight.denoise.aux import aux_buffers
        from arlight.denoise.differential import RunningLayers, denoise_layers
        from arlight.denoise.options import DenoiseSettings

        dn = DenoiseSettings.from_options(fn.options(settings))
        if n == 1 or s.running is None:
            s.running, s.aux_full = RunningLayers(), None
        mean = s.running.add(layers)

        def aux(rows: slice, cols: slice):
            if s.aux_full is None:
                data = (fn.pose(state, view.object_transforms, settings)
                        if view.object_transforms else state.data)
                s.aux_full = aux_buffers(fn.aux_view(data), self.scene.camera, dn.aux_spp)
            return s.aux_full.crop(rows, cols)

        use_aux = dn.aux and getattr(fn, "aux_view", None) is not None
        out = denoise_layers(mean, dn, aux if use_aux else None)
        out.stats = {**layers.stats, **{k: v for k, v in out.stats.items()
                                        if k.startswith(("denoise", "footprint"))}}
        out.running = True  # type: ignore[attr-defined]  # _fold shows it as it is
        return out

    def _fold(self, s: Session, layers: Layers, n: int, progressive: bool
              ) -> tuple[dict[str, np.ndarray], int]:
        """The layers to show after frame ``n``: running means for a progressive method
        (Kán Eq. 4.12; restarted at n = 1), else this frame's (call with ``s.lock``)."""
        current = {k: getattr(layers, k) for k in IMAGE_LAYERS}
        if getattr(layers, "running", False):  # already the (denoised) running mean
            s.accumulators = {}
            return current, n
        if not progressive:
            s.accumulators = {}
            return current, 0
        if n == 1:
            s.accumulators = {k: Accumulator() for k in IMAGE_LAYERS}
        return {k: s.accumulators[k].add(v) for k, v in current.items()}, n

    def _send_frame(self, s: Session, superseded: bool,
                    changed_at: float | None = None) -> None:
        """Encode the session's current layers and post them; ``changed_at``: the
        ``time.monotonic()`` of the change a new render shows (the header's ``latency_ms``:
        from then to this post; None for a re-encode)."""
        t0 = time.perf_counter()
        with s.lock:
            if s.images is None or s.closed:
                s.displayed_version = s.display_version
                return
            images, layer, ev, window = s.images, s.layer, s.exposure, s.window
            header: dict[str, Any] = {
                "type": "frame", **s.shown, "layer": layer, "exposure": ev,
                "refine": s.refine, "superseded": superseded, "stats": dict(s.stats)}
            s.displayed_version = s.display_version
        t_display = time.perf_counter()
        if layer == "composite" and window is not None:  # the photo's codes outside it
            codes = self._photo.display(images, window, self.scene.camera.transfer, ev)
        else:
            codes = imaging.display(layer, images, self.scene.camera.transfer, ev,
                                    self.ground_truth)
        t_encode = time.perf_counter()
        data = imaging.encode(codes, self.config.image_format, self.config.quality)
        header["stats"]["display_s"] = t_encode - t_display
        header["stats"]["jpeg_s"] = time.perf_counter() - t_encode
        if self.ground_truth is not None:
            header["rmse"] = rmse(images["composite"], self.ground_truth)
        header["stats"]["encode_s"] = time.perf_counter() - t0
        header["stats"] = {k: v for k, v in header["stats"].items() if np.isfinite(v)}
        header["bytes"] = len(data)
        from arlight.studio.protocol import frame_message

        with s.lock:
            s.frames_sent += 1
        if changed_at is not None:
            header["latency_ms"] = (time.monotonic() - changed_at) * 1e3
        s.post("frame", frame_message(header, data))

    # ------------------------------------------------------------------ saving
    def _save_paths(self, scene: ARScene, name: str) -> dict[str, Path]:
        """What a save of ``scene`` as ``name`` writes (what :func:`save_scene` writes,
        and the composite)."""
        out = {"scene": self.save_dir / f"{name}.toml"}
        if scene.frame_codes is not None:
            out["frame"] = self.save_dir / f"{name}.frame.png"
        elif scene.frame is not None:
            out["frame"] = self.save_dir / f"{name}.frame.exr"
        if scene.depth is not None:
            out["depth"] = self.save_dir / f"{name}.depth.exr"
        out["composite"] = self.save_dir / f"{name}.png"
        return out

    def created_here(self, path: Path) -> bool:
        """Whether ``path`` is a file this studio process saved, unchanged since."""
        path = Path(os.path.realpath(path))
        digest = self._created.get(path)
        if digest is None or not path.is_file():
            return False
        try:
            return file_digest(path) == digest
        except OSError:
            return False

    def _check_save(self, paths: dict[str, Path], overwrite: bool) -> None:
        """Refuse a save that would replace an input of the scene (always), or an existing
        file this studio did not write (unless ``overwrite``: the user confirmed)."""
        for p in paths.values():
            if p.resolve().parent != self.save_dir:
                raise ProtocolError(f"save: {p.name} is outside the save folder")
            if p.resolve() in self.inputs:
                raise ProtocolError(f"save: {p.name} is an input of the scene; choose "
                                    "another name")
        try:  # inputs (symlinks followed), a folder or an unwritable path in the way
            check_outputs({f"save ({k})": p for k, p in paths.items()}, self.inputs,
                          overwrite=True, overwrite_flag="overwrite")
        except InputError as exc:
            raise ProtocolError(f"save: {exc}") from None
        if overwrite:
            return
        taken = [p for p in paths.values()
                 if os.path.lexists(p) and not self.created_here(p)]
        if taken:
            earlier = [p.name for p in taken if written_by_arlight(p)]
            note = (f" ({', '.join(earlier)}: written by an earlier arlight run)"
                    if earlier else "")
            raise SaveExists(f"save: {', '.join(p.name for p in taken)} already exist"
                             f"{'s' if len(taken) == 1 else ''} in {self.save_dir} and "
                             f"{'was' if len(taken) == 1 else 'were'} not saved by this "
                             f"studio{note}; confirm to replace, or choose another name",
                             [p.name for p in taken])

    def _save(self, s: Session, name: str, overwrite: bool = False) -> dict[str, Any]:
        """Write ``<save_dir>/<name>.toml`` (the full-resolution scene with the session's
        poses and method, its frame as ``<name>.frame.png``) and ``<name>.png`` (the
        composite as shown). Only new files, files this studio saved, or — with
        ``overwrite`` (the user confirmed) — other existing files; never an input."""
        from arlight.io.images import write_png
        from arlight.scene.load import load_scene
        from arlight.scene.save import save_scene

        with s.lock:
            poses, method = dict(s.poses), s.method
            images, ev = s.images, s.exposure
        raw = copy.deepcopy(self.full.raw)
        render = {k: v for k, v in raw.get("render", {}).items()
                  if k in ("spp", "seed", "max_depth")}
        raw["render"] = {**render, "method": method}
        view = replace(self.full.view, object_transforms=_transforms(poses))
        scene = replace(ARScene.compose(self.full.world, view), raw=raw)
        paths = self._save_paths(scene, name)
        self._check_save(paths, overwrite)
        if images is None:
            raise ProtocolError("save: nothing rendered yet")
        toml, png = paths["scene"], paths["composite"]
        write_png(png, imaging.display("composite", images, self.scene.camera.transfer, ev,
                                       None))
        save_scene(scene, toml)  # its frame (and depth) first, the TOML last; atomic
        load_scene(toml)  # what was written reads back
        written = [p for p in paths.values() if p.is_file()]
        for p in written:
            self._created[Path(os.path.realpath(p))] = file_digest(p)
        record_written(written)
        return {"type": "saved", "scene": toml.name, "image": png.name,
                "files": [p.name for p in written], "folder": str(self.save_dir)}
