"""``dic``: differential irradiance caching (Kán thesis §4.2, ISMAR 2013; digest §7).

Per frame (Algorithm 4.1):

1. *UpdateTemporalData / RecalculateIrradiance* (sequences only): records age by one frame;
   records older than ``t_max`` are re-evaluated with their own fixed random sequence;
   records near a virtual object that moved are dropped.
2. *SplatIrradiance*: every record is splatted into a per-pixel buffer against the pinhole
   G-buffer (Tabellion's weight, Eq. 2.15; :mod:`arlight.tracing.irradiance_cache`).
3. *DetectCacheMiss* by tiles (≤ 1 new record per tile per iteration, each tile resuming where
   it stopped); the new records' ``R_i`` (one first-hit kernel) and splat weights; repeat
   until no tile has a miss. Then *EvaluateIrradiance* of all new records in one Dr.Jit
   wavefront — one-pass path tracing from the record with Kán's four ray types,
   multi-bounce, cosine-weighted (:mod:`arlight.tracing.irradiance_eval`) — and their splat.
   (Miss detection needs only the weights, which do not depend on the irradiance: the same
   records and values as evaluating inside the loop, one launch instead of one per
   iteration.)
4. Final shading from the camera (:mod:`arlight.tracing.irradiance_shading`): direct light
   with the one-pass rules (the virtual objects' shadows on the real scene, their real
   continuation rays) plus ``ρ_d/π · E`` read from the splat buffer through the reprojection
   of §4.2.5 (depth of field, mirrors and glass read the pixel their hit projects to); real
   pixels get ``E_d``, virtual ones ``E_m``.

``DicMethod.render(state, view)`` builds the cache from scratch (a pure function of the state
and the view, as the interface requires); :class:`DicSequence` renders a sequence of views
and carries the cache from frame to frame (the temporal part above).

Stats: ``records`` (cache size at the end of the frame), ``records_new``,
``records_reevaluated``, ``records_dropped``, ``iterations`` (miss-detection iterations),
``record_rays`` (rays per record), ``rays_record_*`` (record paths by ray type) and
``rays_camera_*`` (the camera walk), ``samples``, ``spp``. Stages, seconds: ``setup``
(G-buffer, tracers), ``update`` (re-evaluation of aged records), ``records`` (evaluation of
new records), ``splat``, ``miss`` (tile scans), ``trace`` (camera walk), ``assemble``;
``pose`` when the view moves objects.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import mitsuba as mi
import numpy as np

from arlight.backend.passes import run_passes
from arlight.errors import InputError
from arlight.layers import differential_samples, layers_from_passes
from arlight.methods.base import (
    Layers,
    Prepared,
    RenderSettings,
)
from arlight.methods.fragments import SAMPLER_OPTIONS, PathScenesMethod
from arlight.methods.spec import Capabilities, Field, MethodSpec, Options
from arlight.realtime.shading import virtual_bounds
from arlight.scene.model import FrameView, World
from arlight.timing import StageTimer
from arlight.tracing.irradiance_cache import (
    Records,
    SplatBuffer,
    SplatGeometry,
    TileScanner,
    invalidate_near,
    splat_batches,
)
from arlight.tracing.irradiance_eval import evaluate_records, record_radius, record_tracer
from arlight.tracing.irradiance_shading import (
    CameraWalk,
    RecordGrid,
    SplatLookup,
    splat_geometry,
    validity_tolerance,
)
from arlight.tracing.irradiance_splat import splat_dr
from arlight.tracing.onepass import lane_keys
from arlight.tracing.scenes import PathScenes, frame_gather

OPTIONS: dict[str, Field] = {
    "rays": Field("int", 128, "mixed radiance rays per cache record (Kán: 100–4000)",
                  min=1, max=65536),
    "accuracy": Field("float", 1.0, "κ of Tabellion's weight (Eq. 2.15): a record reaches "
                      "R_i/(2κ) and normals 10°/κ away; larger: more records, less "
                      "interpolation", min=0.0, max=1000.0, exclusive_min=True),
    "tile": Field("int", 8, "side of the cache-miss tiles (≤ 1 new record per tile per "
                  "iteration)", "px", min=1, max=4096),
    "max_iterations": Field("int", 100, "miss-detection iterations per frame at most",
                            min=1, max=100000),
    "min_radius_px": Field("float", 8.0, "smallest record footprint radius (R_i clamp)",
                           "px", min=0.0, max=1.0e4, exclusive_min=True),
    "max_radius_px": Field("float", 16.0, "largest record footprint radius (R_i clamp)",
                           "px", min=0.0, max=1.0e4, exclusive_min=True),
    "t_max": Field("int", 8, "frames after which a record is re-evaluated with its own random "
                   "sequence (DicSequence)", "frames", min=1, max=1000000),
    "validate": Field("bool", True, "validate each splat-buffer lookup by depth and normal "
                      "(the pixel's surface within its smallest record footprint, normals "
                      "within Eq. 2.15's 10°/κ) and search the records in world space where "
                      "it fails; false: Kán's plain reprojection"),
    "glossy": Field("bool", True, "the camera walk continues at glossy surfaces without a "
                    "diffuse lobe (metals, rough glass) along its BSDF sample, as at mirrors, "
                    "so their indirect reflection is traced (the cache holds diffuse light "
                    "only); false: such a surface gets direct light only"),
    "trace_unresolved": Field("bool", True, "where a validated lookup finds neither its "
                              "pixel's surface nor a record (a surface the camera does not "
                              "see, e.g. reflected in a glossy floor), the camera walk path "
                              "traces on from the point instead of reading the pixel's "
                              "irradiance (validate only); false: keep the pixel's value"),
    # the camera walk draws its numbers as onepass does (the same fields and defaults)
    **SAMPLER_OPTIONS,
    "invalidate_distance": Field("float", 0.3, "records this close to a moved virtual "
                                 "object's old or new bounds are dropped (DicSequence)", "m",
                                 min=0.0, max=1.0e6),
}


def _check(opts: Options) -> None:
    if opts.min_radius_px > opts.max_radius_px:
        raise InputError(f"min_radius_px ({opts.min_radius_px}) exceeds max_radius_px "
                         f"({opts.max_radius_px})", file="method 'dic'",
                         field="options.min_radius_px")


SPEC = MethodSpec(
    name="dic",
    description="Differential irradiance caching: path-traced differential irradiance at "
                "sparse records, splatted, plus one-pass direct light (Kán §4.2).",
    options=OPTIONS,
    capabilities=Capabilities(interactive=True, noisy=True),
    check=_check,
)


def record_keys(ident: np.ndarray, seed: int) -> np.ndarray:
    """32-bit random-sequence keys (a fixed hash of an integer, e.g. a pixel index, and the
    seed)."""
    with np.errstate(over="ignore"):  # arithmetic modulo 2^64
        x = (ident.astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15)
             + np.uint64(seed & 0xFFFFFFFF) * np.uint64(0xBF58476D1CE4E5B9))
        x ^= x >> np.uint64(31)
        x *= np.uint64(0x94D049BB133111EB)
        x ^= x >> np.uint64(29)
    return (x & np.uint64(0xFFFFFFFF)).astype(np.uint32)


@dataclass
class DicCache:
    """What a frame hands the next (:class:`DicSequence`).

    Attributes:
        records: the cache records.
        next_id: id of the next record created.
        next_batch: batch number of the next miss-detection iteration.
        transforms: the object transforms of the frame that produced it.
        bounds: the virtual objects' bounds in that frame ``(lo, hi)`` (m), or None.
    """

    records: Records = field(default_factory=Records.empty)
    next_id: int = 0
    next_batch: int = 0
    transforms: dict[str, np.ndarray] = field(default_factory=dict)
    bounds: tuple[np.ndarray, np.ndarray] | None = None


@dataclass
class FrameResult:
    """Layers of a frame plus what the cache looked like (for tests and benchmarks)."""

    layers: Layers
    cache: DicCache
    buffer: SplatBuffer
    geometry: SplatGeometry


def _ray_stats(prefix: str, counts: dict[str, int]) -> dict[str, float]:
    return {f"rays_{prefix}_{k.removeprefix('rays_')}": float(v) for k, v in counts.items()}


def _add_counts(total: dict[str, int], counts: dict[str, int]) -> None:
    for k, v in counts.items():
        total[k] = total.get(k, 0) + v


def render_frame(data: PathScenes, view: FrameView, options: Options,
                 settings: RenderSettings, timer: StageTimer,
                 cache: DicCache | None = None, moved: bool = False) -> FrameResult:
    """One frame of Algorithm 4.1 from ``cache`` (None: empty); returns the new cache too.

    ``data`` is the posed world's; ``moved``: the virtual objects moved since ``cache``.
    """
    views, camera, frame = data.views, view.camera, view.frame
    cache = cache or DicCache()
    kappa, lo_px, hi_px = options.accuracy, options.min_radius_px, options.max_radius_px
    with timer.stage("setup"):
        geom = splat_geometry(views.mixed, camera)
        tracer = record_tracer(views, settings.max_depth, settings.rr_depth)
        bounds = virtual_bounds(data.world, views.mixed)
    records, next_id, next_batch = cache.records, cache.next_id, cache.next_batch
    rec_counts: dict[str, int] = {}
    stats: dict[str, float] = {"records_reevaluated": 0.0, "records_dropped": 0.0}

    def evaluate(pos: np.ndarray, nrm: np.ndarray, keys: np.ndarray):
        vals = evaluate_records(tracer, views, pos, nrm, keys, options.rays)
        _add_counts(rec_counts, vals.rays)
        return vals

    if len(records):
        with timer.stage("update"):  # UpdateTemporalData + RecalculateIrradiance
            if moved:
                boxes = [b for b in (cache.bounds, bounds) if b is not None]
                drop = invalidate_near(records, boxes, options.invalidate_distance)
                stats["records_dropped"] = float(drop.sum())
                records = records.take(~drop)
            records = replace(records, age=records.age + 1)
            stale = np.flatnonzero(records.age >= options.t_max)
            if len(stale):
                vals = evaluate(records.position[stale], records.normal[stale],
                                records.key[stale])
                fresh = _records(records.position[stale], records.normal[stale],
                                 records.key[stale], records.ident[stale], vals,
                                 records.batch[stale])
                records = records.with_values(stale, fresh)
                stats["records_reevaluated"] = float(len(stale))
    with timer.stage("splat"):
        buf = splat_batches(records, geom, camera, kappa, lo_px, hi_px, splat_dr)
    # DetectCacheMiss iterations need only the splat weights, which depend on x, n and R_i:
    # each iteration's new records get R_i from their rays' first hits (one intersection
    # kernel), and all of them are path traced together afterwards in one wavefront (the
    # values are those of Algorithm 4.1's per-iteration EvaluateIrradiance: a record's
    # estimate depends only on its key)
    scanner = TileScanner(camera.width, camera.height, options.tile)
    weight = buf.weight.copy()
    batches: list[Records] = []
    while scanner.iterations < options.max_iterations:
        with timer.stage("miss"):
            pix = scanner.misses(weight, geom.needs)
        if len(pix) == 0:
            break
        with timer.stage("records"):
            ident = np.arange(next_id, next_id + len(pix), dtype=np.int64)
            # the key hashes the pixel the record starts at: a record dropped and created
            # again at the same pixel (an object moved nearby) reuses its random sequence
            keys = record_keys(pix.astype(np.int64), settings.seed)
            pos, nrm = geom.position[pix], geom.normal[pix]
            radius = record_radius(views, pos, nrm, keys, options.rays)
            z3 = np.zeros((len(pix), 3))
            new = Records(pos, nrm, z3, z3, radius, np.zeros(len(pix), np.int64), keys, ident,
                          batch=np.full(len(pix), next_batch, np.int64))
        with timer.stage("splat"):
            weight = weight + splat_dr(new, geom, camera, kappa, lo_px, hi_px).weight
        batches.append(new)
        next_id += len(pix)
        next_batch += 1
    n_new = sum(len(b) for b in batches)
    if batches:
        with timer.stage("records"):  # EvaluateIrradiance of every new record, one launch
            new = batches[0]
            for b in batches[1:]:
                new = new.concat(b)
            vals = evaluate(new.position, new.normal, new.key)
            new = _records(new.position, new.normal, new.key, new.ident, vals, new.batch)
        with timer.stage("splat"):
            buf = splat_batches(new, geom, camera, kappa, lo_px, hi_px, splat_dr, start=buf)
        records = records.concat(new)
    with timer.stage("splat"):
        e_mixed, e_delta = buf.irradiance()
    with timer.stage("setup"):
        # the walk samples lights through the record tracer's selection: one set of rules
        if options.validate:
            lookup = SplatLookup(camera, e_mixed, e_delta, geom,
                                 validity_tolerance(geom, camera, lo_px),
                                 RecordGrid(records, camera, kappa, lo_px, hi_px), kappa)
        else:
            lookup = SplatLookup(camera, e_mixed, e_delta)
        walk = CameraWalk(views, lookup, settings.max_depth, tracer.light_selection,
                          glossy=options.glossy,
                          trace_unresolved=options.validate and options.trace_unresolved)
        background = frame_gather(frame)
    cam_counts: dict[str, int] = {}

    def kernel(rays, pixel, seed, lanes, key=None):
        res = walk.trace(mi.Ray3f(rays), lane_keys(lanes, seed) if key is None else key)
        _add_counts(cam_counts, res.rays)
        return differential_samples(res.mixed, res.real, res.mask, background(pixel))

    with timer.stage("trace"):
        res = run_passes(camera, settings.spp, kernel, seed=settings.seed,
                         spp_per_pass=settings.spp_per_pass,
                         progress="dic" if settings.progress else None,
                         sampler=options.sampler, replicas=options.replicas,
                         scramble_replicas=options.replica_mode == "scrambles")
    with timer.stage("assemble"):
        stats.update(records=float(len(records)), records_new=float(n_new),
                     iterations=float(scanner.iterations), record_rays=float(options.rays),
                     covered_fraction=float(np.mean(buf.weight[geom.needs] > 0))
                     if geom.needs.any() else 1.0)
        stats.update(_ray_stats("record", rec_counts))
        for k in ("lookups", "lookups_rejected", "lookups_unresolved"):
            stats[k] = float(cam_counts.pop(k, 0))
        stats.update(_ray_stats("camera", cam_counts))
        layers = layers_from_passes(frame, res, **stats)
        _add_record_noise(layers, geom, buf)
    if not data.world.has_virtual:  # every path is shared: L_m == L_r, E_d == 0 exactly
        assert not np.any(layers.delta), "dic delta must vanish without virtual objects"
    return FrameResult(layers, DicCache(records, next_id, next_batch,
                                        dict(view.object_transforms), bounds), buf, geom)


def _add_record_noise(layers: Layers, geom: SplatGeometry, buf: SplatBuffer) -> None:
    """Add the records' Monte Carlo noise to the layers' standard errors (the camera samples
    of a pixel share its interpolated irradiance, so the passes' errors miss it): ``ρ/π`` of
    the pixel's own surface times the interpolated irradiance's standard error, for the
    mixed, delta and composite layers. Specular paths that read other pixels and the
    interpolation's bias are not included."""
    var_m, var_d = buf.variance()
    scale = np.square(geom.albedo / np.pi)
    h, w = layers.mask.shape
    vm, vd = (scale * var_m).reshape(h, w, 3), (scale * var_d).reshape(h, w, 3)
    m = layers.mask[..., None].astype(np.float64)
    extra = {"mixed": vm, "delta": vd, "composite": np.square(m) * vm + np.square(1 - m) * vd}
    for name, var in extra.items():
        if name in layers.stderr:
            se = np.asarray(layers.stderr[name], np.float64)
            layers.stderr[name] = np.sqrt(np.square(se) + var)


def _records(pos: np.ndarray, nrm: np.ndarray, keys: np.ndarray, ident: np.ndarray,
             vals, batch: int | np.ndarray = 0) -> Records:
    return Records(position=np.asarray(pos, np.float64), normal=np.asarray(nrm, np.float64),
                   e_mixed=vals.e_mixed, e_delta=vals.e_delta, radius=vals.radius,
                   age=np.zeros(len(pos), np.int64), key=np.asarray(keys, np.uint32),
                   ident=ident, stderr_mixed=vals.stderr_mixed, stderr_delta=vals.stderr_delta,
                   batch=np.broadcast_to(np.asarray(batch, np.int64), (len(pos),)).copy())


class DicMethod(PathScenesMethod):
    """Differential irradiance caching (Kán §4.2): sparse path-traced records, splatting,
    one-pass direct light."""

    spec = SPEC
    incremental_pose = True
    move = PathScenesMethod.move_in_place
    """Issue #32: the shapes move in place in both Mitsuba views; a frame builds its cache
    from the posed views, so it renders bitwise what a fresh preparation of the posed world
    renders (:class:`DicSequence` keeps the records away from the moved object)."""

    def render_view(self, data: PathScenes, view: FrameView, options: Options,
                    settings: RenderSettings, timer: StageTimer) -> Layers:
        return render_frame(data, view, options, settings, timer).layers


class DicSequence:
    """Renders the views of one world frame after frame, carrying the cache (Algorithm 4.1's
    temporal part): records age, are re-evaluated with their own random sequence after
    ``t_max`` frames (a static scene renders bitwise the same frames) and are dropped near
    a virtual object that moved.

    Moving an object (issue #32) moves its shapes in place (:meth:`DicMethod.move`) and
    drops exactly the records within ``invalidate_distance`` of the objects' bounds before
    or after the move; the others keep their values (and ages) bit for bit, and the frame is
    bitwise what :func:`render_frame` makes from a fresh preparation of the posed world and
    the same cache. (It is not a fresh frame: kept records hold the light of the old pose
    until they age out — the definition of the temporal cache.)

    >>> seq = DicSequence(scene.world, RenderSettings(options={"rays": 128}))
    >>> layers = [seq.render(v) for v in views]   # doctest: +SKIP
    """

    def __init__(self, world: World, settings: RenderSettings | None = None,
                 method: DicMethod | None = None):
        self.method = method or DicMethod()
        self.settings = settings or RenderSettings()
        self.state: Prepared = self.method.prepare(world, self.settings)
        self.cache: DicCache | None = None
        self.last: FrameResult | None = None

    def render(self, view: FrameView) -> Layers:
        """The next frame; ``view.object_transforms`` poses the world for it."""
        t0 = time.perf_counter()
        m, st, settings = self.method, self.state, self.settings
        opts = m.options(settings)
        m.check_supported(st.world, view)
        timer = StageTimer()
        transforms = dict(view.object_transforms)
        prev = self.cache.transforms if self.cache is not None else {}
        moved = self.cache is not None and not _same_transforms(prev, transforms)
        with st.lock:  # the views are moved in place (incremental pose, issue #32)
            t1 = time.perf_counter()
            data = m.pose(st, transforms, settings)
            if transforms or moved:
                timer.add("pose", time.perf_counter() - t1)
            res = render_frame(data, replace(view, object_transforms={}), opts, settings,
                               timer, self.cache, moved)
        res.cache.transforms = transforms
        self.cache, self.last = res.cache, res
        layers = res.layers
        layers.stats.update(timer.stats())
        layers.stats["seconds"] = time.perf_counter() - t0
        layers.method = m.spec.name
        return layers


def _same_transforms(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> bool:
    eye = np.eye(4)
    return all(np.array_equal(np.asarray(a.get(k, eye)), np.asarray(b.get(k, eye)))
               for k in set(a) | set(b))


__all__ = ["DicCache", "DicMethod", "DicSequence", "FrameResult", "OPTIONS", "SPEC",
           "record_keys", "render_frame"]
