"""The studio's render engine: one scene, many client sessions, one render worker.

* The scene is loaded once (optionally box-filtered to a smaller studio resolution); each
  method is *prepared* once for its world (``method.prepare``) and every frame is a
  ``method.render`` of that state with the session's object poses as
  ``FrameView.object_transforms`` (``arlight.methods.base``: prepare once, render per frame).
* Every Dr.Jit call — picking, placement, preparation, rendering — runs on one worker
  thread, so the methods never see two threads. Sessions are served round robin.
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
* Errors stay in their session: a failing render or a bad message is reported to that
  client only.
"""

from __future__ import annotations

import collections
import concurrent.futures
import copy
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from arlight.errors import InputError
from arlight.evaluate.metrics import rmse
from arlight.methods import Method, RenderSettings, get_method, methods
from arlight.methods.base import Layers, Prepared
from arlight.progressive import Accumulator, frame_settings
from arlight.scene.load import PATH_KEYS
from arlight.scene.model import ARScene
from arlight.studio import imaging
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
    seq: int | None = None  # newest client seq folded into the state
    version: int = 1  # bumped by every change that needs a new render
    display_version: int = 1  # bumped by exposure/layer changes
    rendered_version: int = 0
    displayed_version: int = 0
    images: dict[str, np.ndarray] | None = None  # the current (accumulated) layers
    shown: dict[str, Any] = field(default_factory=dict)  # seq, version, method, poses of them
    stats: dict[str, float] = field(default_factory=dict)
    accumulators: dict[str, Accumulator] = field(default_factory=dict)
    refine: int = 0  # frames accumulated for the current version (progressive methods)
    closed: bool = False
    last_message: float = 0.0  # time.monotonic() of the newest client message
    holding: bool = False  # the pointer holds the picked object (pick .. release)
    frames_sent: int = 0
    superseded: int = 0
    errors: int = 0

    def bump(self, seq: int | None) -> None:
        """Mark a change that needs a new render (call with ``lock`` held)."""
        self.version += 1
        if seq is not None:
            self.seq = seq


@dataclass(frozen=True)
class MethodInfo:
    """A method the studio lists: name, description, progressive, why not (or None)."""

    name: str
    description: str
    progressive: bool
    unsupported: str | None

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "description": self.description,
                "progressive": self.progressive, "unsupported": self.unsupported}


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


def _transforms(poses: dict[str, ObjectPose]) -> dict[str, np.ndarray]:
    """``FrameView.object_transforms`` of the poses (objects at rest are left out)."""
    return {k: p.matrix() for k, p in poses.items() if not p.is_rest}


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
        self.save_dir = Path(config.save_dir or self.source.parent).resolve()
        self.inputs = self._input_files()
        self.ground_truth = self._ground_truth()
        self.catalogue = self._catalogue()
        self.default_method = self._default_method()
        self.settings = RenderSettings(spp=1, seed=config.seed)
        self._states: dict[str, Prepared] = {}
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
                                   m.spec.unsupported_reason(self.scene, self.scene))
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
                    self._cond.wait(timeout=REFINE_IDLE_S / 2)
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
        (call with ``_cond`` held)."""
        for want in ("render", "refine"):
            for _ in range(len(self._rr)):
                sid = self._rr[0]
                self._rr.rotate(-1)
                s = self._sessions.get(sid)
                if s is None:
                    continue
                kind = self._work_of(s)
                if kind == want or (want == "render" and kind == "display"):
                    return s, kind
        return None

    def _work_of(self, s: Session) -> str | None:
        with s.lock:
            if s.closed:
                return None
            if s.version != s.rendered_version:
                return "render"
            if s.display_version != s.displayed_version:
                return "display"
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
            else:
                self._render(s, refine=kind == "refine")
        except Exception as exc:  # noqa: BLE001 — one session's failure stays in it
            with s.lock:
                s.errors += 1
                s.rendered_version = s.version  # do not retry the same state forever
                s.refine = 0
            s.post("json", {"type": "error", "message": f"{type(exc).__name__}: {exc}",
                            "request": kind})

    # ------------------------------------------------------------------ sessions
    def open_session(self, post: Post) -> Session:
        with self._cond:
            s = Session(self._next_id, post, self.default_method, dict(self.rest_poses))
            self._next_id += 1
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
        if kind == "pick":
            return self.call(self._pick, s, msg["x"], msg["y"], msg.seq)
        if kind == "save":
            return self.call(self._save, s, msg["name"])
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
            elif kind == "exposure":
                s.exposure = msg["ev"]
                s.display_version += 1
            elif kind == "layer":
                if msg["name"] == "error" and self.ground_truth is None:
                    raise ProtocolError("layer: the scene has no ground truth (start the "
                                        "studio with --ground-truth FILE.exr)")
                s.layer = msg["name"]
                s.display_version += 1
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
    def prepared(self, name: str, s: Session | None = None) -> Prepared:
        """The method's prepared state for the studio's world (prepared on first use)."""
        if name not in self._states:
            if s is not None:
                s.post("json", {"type": "status", "message": f"preparing {name}…"})
            self._states[name] = get_method(name).prepare(self.scene.world, self.settings)
        return self._states[name]

    def _resolve_drag(self, s: Session) -> tuple[int, int | None]:
        """Stand the picked object on the surface under the pending drag target; returns
        the session version and client seq this covers (a later message makes the frame
        stale)."""
        with s.lock:
            version, seq, target, name = s.version, s.seq, s.pending_drag, s.selected
            s.pending_drag = None
        if target is None or name is None:
            return version, seq
        hit = self.proxy.support(*target)
        if hit is None:
            s.post("json", {"type": "status", "message": "no real surface to stand on "
                            "there; the object stays"})
            return version, seq
        with s.lock:
            s.poses[name] = s.poses[name].moved_to(hit.position)
        return version, seq

    def _render(self, s: Session, refine: bool) -> None:
        t0 = time.perf_counter()
        with s.lock:
            version, seq = s.version, s.seq
        if not refine:
            version, seq = self._resolve_drag(s)
        with s.lock:
            method, poses = s.method, dict(s.poses)
            n = s.refine + 1 if refine else 1
        t_place = time.perf_counter() - t0
        fn = get_method(method)
        state = self.prepared(method, s)
        view = replace(self.view, object_transforms=_transforms(poses))
        progressive = self.catalogue[method].progressive
        settings = self.settings
        if progressive:  # frame n of the refinement (onepass: samples continue one sequence)
            settings = frame_settings(fn, self.settings, n)
        t1 = time.perf_counter()
        layers = fn.render(state, view, settings)
        t_render = time.perf_counter() - t1
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
            s.images, s.refine = self._fold(s, layers, n, progressive)
            s.shown = {"seq": seq, "version": version, "method": method,
                       "objects": {k: p.to_json() for k, p in poses.items()}}
            s.stats = {**{k: float(v) for k, v in layers.stats.items()
                          if k.startswith("time_")},
                       "time_place": t_place, "render_s": t_render}
        self._send_frame(s, superseded=stale)

    def _fold(self, s: Session, layers: Layers, n: int, progressive: bool
              ) -> tuple[dict[str, np.ndarray], int]:
        """The layers to show after frame ``n``: running means for a progressive method
        (Kán Eq. 4.12; restarted at n = 1), else this frame's (call with ``s.lock``)."""
        current = {k: getattr(layers, k) for k in IMAGE_LAYERS}
        if not progressive:
            s.accumulators = {}
            return current, 0
        if n == 1:
            s.accumulators = {k: Accumulator() for k in IMAGE_LAYERS}
        return {k: s.accumulators[k].add(v) for k, v in current.items()}, n

    def _send_frame(self, s: Session, superseded: bool) -> None:
        t0 = time.perf_counter()
        with s.lock:
            if s.images is None or s.closed:
                s.displayed_version = s.display_version
                return
            images, layer, ev = s.images, s.layer, s.exposure
            header: dict[str, Any] = {
                "type": "frame", **s.shown, "layer": layer, "exposure": ev,
                "refine": s.refine, "superseded": superseded, "stats": dict(s.stats)}
            s.displayed_version = s.display_version
        codes = imaging.display(layer, images, self.scene.camera.transfer, ev,
                                self.ground_truth)
        data = imaging.encode(codes, self.config.image_format, self.config.quality)
        if self.ground_truth is not None:
            header["rmse"] = rmse(images["composite"], self.ground_truth)
        header["stats"]["encode_s"] = time.perf_counter() - t0
        header["stats"] = {k: v for k, v in header["stats"].items() if np.isfinite(v)}
        header["bytes"] = len(data)
        from arlight.studio.protocol import frame_message

        with s.lock:
            s.frames_sent += 1
        s.post("frame", frame_message(header, data))

    # ------------------------------------------------------------------ saving
    def _save(self, s: Session, name: str) -> dict[str, Any]:
        """Write ``<save_dir>/<name>.toml`` (the full-resolution scene with the session's
        poses and method) and ``<name>.png`` (the composite as shown)."""
        from arlight.io.images import write_png
        from arlight.scene.load import load_scene
        from arlight.scene.save import save_scene

        toml = (self.save_dir / f"{name}.toml").resolve()
        png = (self.save_dir / f"{name}.png").resolve()
        frame = (self.save_dir / f"{name}.frame.png").resolve()
        for p in (toml, png, frame):
            if p.parent != self.save_dir:
                raise ProtocolError(f"save: {p.name} is outside the save folder")
            if p in self.inputs:
                raise ProtocolError(f"save: {p.name} is an input of the scene; choose "
                                    "another name")
        with s.lock:
            poses, method = dict(s.poses), s.method
            images, ev = s.images, s.exposure
        if images is None:
            raise ProtocolError("save: nothing rendered yet")
        raw = copy.deepcopy(self.full.raw)
        render = {k: v for k, v in raw.get("render", {}).items()
                  if k in ("spp", "seed", "max_depth")}
        raw["render"] = {**render, "method": method}
        view = replace(self.full.view, object_transforms=_transforms(poses))
        scene = replace(ARScene.compose(self.full.world, view), raw=raw)
        save_scene(scene, toml)
        write_png(png, imaging.display("composite", images, self.scene.camera.transfer, ev,
                                       None))
        load_scene(toml)  # what was written reads back
        return {"type": "saved", "scene": toml.name, "image": png.name,
                "folder": str(self.save_dir)}
