"""Wavefront one-pass differential path tracer in Dr.Jit (Kán thesis §3.3, Fig. 3.5).

Each lane (one camera sample) owns at most two paths, traced in two phases:

* **Phase 1**, one symbolic loop over the *mixed radiance* path traced in the mixed view ρ.
  While it has touched no virtual object it is *shared*: every vertex on it is a vertex of
  the real-only solution too, so its emission and next-event terms go to both ``L_m`` and
  ``L_r`` (hit rule 1: one mixed and one real shadow ray per light sample). The real shadow
  ray is only traced where the mixed one is blocked: µ ⊂ ρ, so a ray free in ρ is free in µ.
  When a shared path first hits a virtual object (hit rule 2) the lane is marked *forked* and
  its fork depth kept (two scalars per lane: the loop carries no other extra state). The
  mixed path then goes on mixed-only (mixed shadow rays only).
* **Phase 2**, the *real radiance* continuations: the forked lanes are compacted
  (``dr.compress``) and a second symbolic loop traces only them in the real view µ from
  their camera rays. Before its fork a lane's path met only real surfaces, so in µ it
  retraces phase 1's shared prefix bit for bit (same rays, same real shapes, same random
  numbers) — there it only updates the path state, its light being in ``L_r`` already; from
  the fork depth on (the ray that hit the virtual object now passes through it: the
  continuation ray) it gathers light with real shadow rays (hit rule 3), added to ``L_r`` of
  its lane (gather, accumulate, scatter back). Most forks are camera rays (no prefix). The
  real path's work is thus paid for only by the lanes that fork (4–8 % on the benchmark
  scenes), not by every SIMD packet, and phase 1 stays as lean as a plain mixed path
  (recording full fork states there, a masked scatter per iteration, cost ~30 %).
  Hit rule 4 (a real ray hitting a virtual object) cannot happen: µ holds no virtual shape.

The continuation is not a bounce: it takes over the mixed path's depth. Random numbers are
functions of (lane sampler, depth, dimension) — TEA hashes or shuffled Owen-scrambled Sobol
points (:mod:`arlight.sampling.stream`) — not a sequential stream, so the shared prefix, the
mixed suffix and the real suffix (phase 2 gathers the lane's key) use exactly the numbers a
separate render of ρ and of µ would use at the same depth: one-pass equals two-pass *sample
by sample* (``mode="twopass"`` runs phase 1 once per view, for the equivalence test and for
ray-count comparisons).

Per vertex (as Mitsuba's ``path``/``prb`` integrators): emitter hit with power-heuristic MIS
against the previous BSDF sample, next-event estimation with MIS via
``scene.sample_emitter_direction`` (importance-samples environment maps), BSDF sampling
through ``si.bsdf().sample`` (Mitsuba's ``conductor``/``dielectric`` do exact Fresnel, Snell
and total internal reflection with stochastic reflect/refract selection), Russian roulette
from ``rr_depth``. ``env_mode="miss_only"`` is the thesis's map lookup on misses only (no
light sampling of infinite emitters, MIS weight 1 on a miss), optionally with the lower
hemisphere mirrored from the upper one (Kán §5.3, for hemispherical fisheye maps).

Camera-image reprojection (Kán §5.2, after Grosch 2005): a mixed path whose last vertices
were delta-specular with at least one on a virtual object (``wasSpecular``) and that hits a
real surface with a diffuse lobe takes that point's outgoing radiance from the camera frame
at its projection (nearest pixel) and ends there, when the point is inside the frame and
visible from the camera centre in µ; otherwise it is shaded as usual.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.mitsuba_scene import ROLE_REAL, ROLE_VIRTUAL, SceneView
from arlight.backend.reproject import Reprojector
from arlight.sampling.lights import LightSampler, light_context
from arlight.sampling.stream import CAMERA_PIXEL, LaneSampler
from arlight.scene.camera import Camera

RAY_TYPES = ("rays_mixed_radiance", "rays_real_radiance", "rays_mixed_shadow",
             "rays_real_shadow", "rays_reprojection")
DIMS_PER_DEPTH = 8  # random dimensions reserved per path depth
DIM_NEE, DIM_BSDF1, DIM_BSDF2, DIM_RR = 0, 2, 3, 5
DIM_CAUSTIC_LOBE, DIM_CAUSTIC_DIR = 6, 7  # the caustic gather walk's (arlight.tracing.photons)


@dataclass
class TracerOptions:
    """Options of the one-pass tracer.

    Attributes:
        max_depth: longest path in vertices, Mitsuba's convention (2 = direct light only;
            -1 = unlimited, terminated by Russian roulette).
        rr_depth: depth from which Russian roulette starts.
        env_mode: ``"mis"`` (light sampling of environment maps with MIS) or ``"miss_only"``
            (Kán: look the map up when a path misses).
        mirror_lower_hemisphere: with ``miss_only``, directions below the horizon read the
            map at the mirrored direction (Kán §5.3, fisheye maps cover only the upper half).
        reproject: camera-image reprojection through virtual specular objects (Kán §5.2).
        first_emission_depth: vertices at smaller depths collect no emitted radiance (0: all
            do; 1: paths started at an irradiance-cache record gather indirect light only,
            the direct light being the camera's, Kán §4.2 / :mod:`arlight.methods.dic`).
        light_sampling: ``"importance"`` (emitters by their estimated contribution at the
            shading point), ``"solid_angle"`` (by one global power estimate; both sample
            rectangles by solid angle: :mod:`arlight.sampling.lights`) or ``"mitsuba"`` (the
            scene's ``sample_emitter_direction``: uniform emitter choice, rectangles by
            area).
    """

    max_depth: int = 8
    rr_depth: int = 5
    env_mode: str = "mis"
    mirror_lower_hemisphere: bool = False
    reproject: bool = True
    first_emission_depth: int = 0
    light_sampling: str = "importance"


@dataclass
class _Path:
    """State of one path slot per lane."""

    ray: mi.Ray3f
    beta: mi.Color3f
    eta: mi.Float
    active: mi.Bool
    prev_si: mi.Interaction3f
    prev_pdf: mi.Float
    prev_delta: mi.Bool
    spec_virtual: mi.Bool
    prev_imps: list[mi.Float]  # the light importances at prev_si (LightSelection.importances)

    @staticmethod
    def start(rays: mi.Ray3f, active: bool, lights: int = 0) -> _Path:
        """Paths starting on ``rays``; ``lights``: how many importances a vertex keeps."""
        n = dr.width(rays.d)
        return _Path(ray=mi.Ray3f(rays), beta=dr.full(mi.Color3f, 1.0, n),
                     eta=dr.full(mi.Float, 1.0, n), active=dr.full(mi.Bool, active, n),
                     prev_si=dr.zeros(mi.Interaction3f, n), prev_pdf=dr.full(mi.Float, 1.0, n),
                     prev_delta=dr.full(mi.Bool, True, n), spec_virtual=dr.full(mi.Bool, False, n),
                     prev_imps=[dr.zeros(mi.Float, n) for _ in range(lights)])


def mis_weight(pdf_a: mi.Float, pdf_b: mi.Float) -> mi.Float:
    """Power heuristic ``a² / (a² + b²)`` (Veach), 0 where undefined."""
    a2, b2 = dr.square(pdf_a), dr.square(pdf_b)
    w = a2 / (a2 + b2)
    return dr.select(dr.isfinite(w), w, 0.0)


def lane_keys(lanes: int, seed: mi.UInt32) -> mi.UInt32:
    """Per-lane 32-bit keys from the lane index and the pass seed."""
    return mi.sample_tea_32(dr.arange(mi.UInt32, lanes), seed, 4)[0]


def as_sampler(key: mi.UInt32 | LaneSampler) -> LaneSampler:
    """Per-lane keys (TEA-hashed ``independent`` numbers) or a sampler, as a sampler."""
    return key if isinstance(key, LaneSampler) else LaneSampler.independent(key)


def rand1(key: LaneSampler, depth: mi.UInt32, dim: int) -> mi.Float:
    """Uniform number for (lane, depth, dimension): order independent (hash or Sobol)."""
    return key.next_1d(depth * DIMS_PER_DEPTH + dim)


def rand2(key: LaneSampler, depth: mi.UInt32, dim: int) -> mi.Point2f:
    return key.next_2d(depth * DIMS_PER_DEPTH + dim)


def rand_lobe(key: LaneSampler, depth: mi.UInt32) -> mi.Float:
    """BSDF lobe choice (1D) at ``depth``."""
    return rand1(key, depth, DIM_BSDF1)


def rand_bsdf(key: LaneSampler, depth: mi.UInt32) -> mi.Point2f:
    """BSDF direction sample at ``depth``: with joint 4D sets (``sobol``) the first half of
    the set it shares with the next vertex's light sample (otherwise the 2D set itself)."""
    return key.next_2d_of_4d(depth * DIMS_PER_DEPTH + DIM_BSDF2, 0)


def rand_nee(key: LaneSampler, depth: mi.UInt32) -> mi.Point2f:
    """Light sample at ``depth``: with joint 4D sets the second half of the set of the
    previous vertex's BSDF direction (at depth 0: of the camera's pixel sample), so the
    light reached through a bounce is stratified over both (Burley's 4D padding)."""
    if key.joint_4d:
        prev = dr.select(depth == 0, mi.UInt32(CAMERA_PIXEL),
                         (depth - 1) * DIMS_PER_DEPTH + DIM_BSDF2)
        return key.next_2d_of_4d(prev, 1)
    return rand2(key, depth, DIM_NEE)


def rand_rr(key: LaneSampler, depth: mi.UInt32) -> mi.Float:
    """Russian roulette at ``depth``."""
    return rand1(key, depth, DIM_RR)


LIGHT_SAMPLING = ("importance", "solid_angle", "mitsuba")
_SELECTION = {"importance": "importance", "solid_angle": "power"}


def light_sampler(view: SceneView, mode: str) -> LightSampler:
    """The :class:`~arlight.sampling.lights.LightSampler` of ``view`` for ``mode``, built once
    per view and kept on it (its light table and environment integrals depend only on the
    world, not on the frame)."""
    cache = view.__dict__.setdefault("_light_samplers", {})
    if mode not in cache:
        cache[mode] = LightSampler(view.scene, selection=_SELECTION[mode])
    return cache[mode]


def hit_emitter(view: SceneView, si: mi.SurfaceInteraction3f) -> mi.EmitterPtr:
    """The emitter a ray found: the hit shape's, or the scene's environment on a miss — as
    ``si.emitter(scene)``, whose environment pointer Mitsuba writes into the kernel as a
    constant. That constant is the environment's registry id, new each time a scene is
    built, so every newly built scene compiled the tracer again (seconds per render; issue
    #35). Here the pointer is read from an opaque array kept on the view."""
    env = view.__dict__.get("_environment")
    if env is None:
        em = view.scene.environment()
        reg = int(np.array(dr.reinterpret_array(mi.UInt32, mi.EmitterPtr(em)))[0]) \
            if em is not None else 0
        env = dr.reinterpret_array(mi.EmitterPtr, mi.UInt32(np.array([reg, 0], np.uint32)))
        dr.make_opaque(env)
        view.__dict__["_environment"] = env
    miss = dr.gather(mi.EmitterPtr, env, mi.UInt32(0))
    return dr.select(si.is_valid(), si.shape.emitter(), miss)


def hit_sample(view: SceneView, si: mi.SurfaceInteraction3f, ref: mi.Interaction3f
               ) -> mi.DirectionSample3f:
    """``mi.DirectionSample3f(scene, si, ref)`` with the emitter of :func:`hit_emitter`."""
    ds = mi.DirectionSample3f(view.scene, si=si, ref=ref)
    ds.emitter = hit_emitter(view, si)
    return ds


class LightSelection:
    """Next-event light selection of the mixed (ρ) and real (µ) views — the one place that
    chooses an emitter and a point on it, and gives the matching pdf for MIS. The one-pass
    tracer, dic's record tracer and its camera walk
    (:mod:`arlight.tracing.irradiance_shading`) all sample through it.

    ``mode``: ``"importance"`` (:class:`~arlight.sampling.lights.LightSampler`: each light
    chosen by its estimated contribution at the shading point, rectangles by solid angle,
    environments with the cosine in mind), ``"solid_angle"`` (the same with one global power
    estimate per light) or ``"mitsuba"`` (the scene's ``sample_emitter_direction`` /
    ``pdf_emitter_direction``: uniform emitter choice, rectangles by area). The mixed and real
    views hold the same lights in the same order, so their samplers choose identical lights
    with identical numbers (the selection depends only on the lights and the shading context).
    """

    def __init__(self, mixed: SceneView, real: SceneView, mode: str = "importance"):
        if mode not in LIGHT_SAMPLING:
            raise ValueError(f"unknown light sampling {mode!r} (expected one of "
                             f"{LIGHT_SAMPLING})")
        self.mode = mode
        self.lights: dict[int, LightSampler] = {}
        if mode != "mitsuba":
            for view in (real, mixed):
                self.lights[id(view)] = light_sampler(view, mode)
        # importances a path vertex keeps for the next vertex's pdf (the same in both views)
        self.kept = max((len(ls.light_bounds) for ls in self.lights.values()), default=0)

    def importances(self, view: SceneView, it: mi.Interaction3f, active: mi.Bool
                    ) -> list[mi.Float]:
        """The light importances at the vertex ``it`` (``[]`` where the sampler has no
        per-light code): computed once, handed to :meth:`sample` here and to :meth:`pdf`
        at the next vertex, whose context is this vertex's ``light_context``."""
        ls = self.lights.get(id(view))
        return ls.importances(it, active) if ls is not None and self.kept else []

    def sample(self, view: SceneView, it: mi.Interaction3f, u: mi.Point2f,
               active: mi.Bool, imps: list[mi.Float] | None = None
               ) -> tuple[mi.DirectionSample3f, mi.Color3f]:
        """Next-event light sample in ``view`` (no visibility test): the direction sample
        (solid-angle pdf, selection included) and the weight ``L / pdf``. ``it``: the
        vertex's surface interaction; ``imps``: :meth:`importances` there, if known."""
        ls = self.lights.get(id(view))
        if ls is None:
            return view.scene.sample_emitter_direction(it, u, False, active)
        return ls.sample(it, u, active, imps or None)

    def pdf(self, view: SceneView, it: mi.Interaction3f, ds: mi.DirectionSample3f,
            active: mi.Bool, imps: list[mi.Float] | None = None) -> mi.Float:
        """Solid-angle pdf of :meth:`sample` producing ``ds`` (for MIS); ``it``: the surface
        interaction :meth:`sample` was given, or its :func:`~arlight.sampling.lights.
        light_context`; ``imps``: the importances :meth:`sample` was given, if any."""
        ls = self.lights.get(id(view))
        if ls is None:
            return view.scene.pdf_emitter_direction(it, ds, active)
        return ls.pdf(it, ds, active, imps or None)


class HitRules:
    """Kán's ray types over the mixed (ρ) and real (µ) views (thesis §3.3, Fig. 3.5): which
    solution a vertex feeds, which shadow rays it traces, where a lane forks and where its
    real continuation starts. The one-pass tracer and dic's camera walk both follow them.

    * rule 1: a vertex on a *shared* path (no virtual object touched yet) feeds both
      solutions: one mixed shadow ray and, only where it is blocked, a real one (µ ⊂ ρ);
    * rule 2: a shared path that hits a virtual object *forks*: the mixed path goes on
      mixed-only, the real continuation passes through the object (traced later, in µ,
      from the camera ray, for the forked lanes only);
    * rule 3: a real path's vertices trace real shadow rays only;
    * rule 4 (a real ray hitting a virtual object) cannot happen: µ holds no virtual shape.

    Ray counters are per-lane ``UInt32`` in a dict keyed by :data:`RAY_TYPES` names.
    """

    def __init__(self, mixed: SceneView, real: SceneView):
        self.mixed, self.real = mixed, real
        self.same_views = mixed is real

    def fork(self, active: mi.Bool, role: mi.Int32, depth: mi.UInt32, forked: mi.Bool,
             fork_depth: mi.UInt32) -> tuple[mi.Bool, mi.UInt32, mi.Bool]:
        """Rule 2 at a mixed-path hit: ``(forked, fork_depth, to_real)`` after it —
        ``to_real``: the lanes whose vertex still feeds the real solution (shared)."""
        forks = active & ~forked & (role == ROLE_VIRTUAL)
        fork_depth = dr.select(forks, depth, fork_depth)
        forked = forked | forks
        return forked, fork_depth, ~forked

    def shadow(self, ray: mi.Ray3f, active: mi.Bool, *, to_mixed: bool,
               to_real: mi.Bool | bool, c: dict[str, mi.UInt32],
               no_real: mi.Bool | None = None) -> tuple[mi.Bool | None, mi.Bool]:
        """Visibility of a light sample along ``ray`` (rules 1 and 3) for the lanes
        ``active``: ``(vis_m, vis_r)``, ``vis_m`` None on a real path (``to_mixed`` off),
        ``vis_r`` only where the vertex feeds the real solution (``to_real``). ``no_real``:
        lanes that need no real shadow ray (a reprojected point). Counts the rays in ``c``."""
        if not to_mixed:  # rule 3 (none on a retraced prefix, where to_real is off)
            need_r = active if to_real is True else active & to_real
            c["rays_real_shadow"] += dr.select(need_r, 1, 0)
            return None, need_r & ~self.real.scene.ray_test(ray, need_r)
        c["rays_mixed_shadow"] += dr.select(active, 1, 0)
        vis_m = active & ~self.mixed.scene.ray_test(ray, active)
        if self.same_views:
            vis_r = vis_m
        else:  # rule 1: the real ray only where the mixed one is blocked
            need_r = active & ~vis_m
            if no_real is not None:
                need_r &= ~no_real
            if to_real is not True:
                need_r &= to_real
            c["rays_real_shadow"] += dr.select(need_r, 1, 0)
            vis_r = vis_m | (need_r & ~self.real.scene.ray_test(ray, need_r))
        return vis_m, (vis_r if to_real is True else vis_r & to_real)

    @staticmethod
    def continuations(rays: mi.Ray3f, forked: mi.Bool, fork_depth: mi.UInt32,
                      key: LaneSampler) -> tuple[mi.UInt32, mi.Ray3f, LaneSampler, mi.UInt32]:
        """Rule 2's real continuations, compacted: ``(idx, camera rays, samplers, start
        depth)`` of the forked lanes. Traced in µ from the camera ray with the lane's own
        numbers, a continuation retraces the shared prefix bit for bit (it met only real
        surfaces) and feeds the real solution from its fork depth on (``depth >= start``)."""
        idx = dr.compress(forked)
        return (idx, dr.gather(mi.Ray3f, rays, idx), key.gather(idx),
                dr.gather(mi.UInt32, fork_depth, idx))


@dataclass
class TraceResult:
    """Per-lane radiance of both solutions and the primary-hit mask, plus ray counts."""

    mixed: mi.Color3f
    real: mi.Color3f
    mask: mi.Float
    rays: dict[str, int] = field(default_factory=dict)


class OnePassTracer:
    """Traces camera rays through the mixed (ρ) and real (µ) views of an AR scene.

    Two symbolic ``dr.while_loop`` s per pass (one compiled kernel each, cached across passes,
    like Mitsuba's own integrators) and one compaction between them; ray counts are per-lane
    counters summed after each loop.
    """

    def __init__(self, mixed: SceneView, real: SceneView, opts: TracerOptions,
                 camera: Camera | None = None, frame: np.ndarray | None = None):
        self.mixed, self.real, self.opts = mixed, real, opts
        self.same_views = mixed is real
        self.ctx = mi.BSDFContext()
        self.miss_only = opts.env_mode == "miss_only"
        self.rules = HitRules(mixed, real)
        self.light_selection = LightSelection(mixed, real, opts.light_sampling)
        self.reproj = (Reprojector(camera, frame, real)
                       if opts.reproject and camera is not None and frame is not None
                       and not self.same_views else None)
        # profiling, summed over passes: lanes, forked lanes, seconds of phase 1 and phase 2
        self.profile = {"lanes": 0, "forked_lanes": 0, "phase1_seconds": 0.0,
                        "phase2_seconds": 0.0}

    # ------------------------------------------------------------------ public
    def trace_onepass(self, rays: mi.Ray3f, key: mi.UInt32 | LaneSampler) -> TraceResult:
        """``L_m``, ``L_r`` and the mask in one pass (hit rules 1–4). ``key``: per-lane keys
        (independent numbers) or a :class:`~arlight.sampling.stream.LaneSampler`."""
        return self._trace(self.mixed, rays, as_sampler(key), onepass=True)

    def trace_view(self, view: SceneView, rays: mi.Ray3f,
                   key: mi.UInt32 | LaneSampler) -> TraceResult:
        """Radiance of one view alone (the two-pass baseline: same code, same numbers)."""
        return self._trace(view, rays, as_sampler(key), onepass=False)

    # ----------------------------------------------------------------- helpers
    def _trace(self, view: SceneView, rays: mi.Ray3f, key: LaneSampler,
               onepass: bool) -> TraceResult:
        n = dr.width(rays.d)
        t0 = time.perf_counter()
        fork_enabled = onepass and not self.same_views
        # which solutions phase-1 vertices feed: shared lanes (fork_enabled), all (onepass
        # without virtual objects: every path is shared) or only this view's (two-pass)
        to_real_const = onepass and self.same_views
        kind = "mixed" if view is self.mixed else "real"
        zero_u = dr.zeros(mi.UInt32, n)
        state = (_Path.start(rays, True, self.light_selection.kept), dr.zeros(mi.Color3f, n),
                 dr.zeros(mi.Color3f, n), dr.zeros(mi.Float, n), mi.UInt32(zero_u),
                 [mi.UInt32(zero_u) for _ in RAY_TYPES], dr.full(mi.Bool, False, n),
                 mi.UInt32(zero_u))

        def cond(a, lm, lr, mask, depth, cnt, forked, fork_depth):
            return a.active

        def body(a, lm, lr, mask, depth, cnt, forked, fork_depth):
            c = dict(zip(RAY_TYPES, cnt, strict=True))
            c[f"rays_{kind}_radiance"] += dr.select(a.active, 1, 0)
            si_a = view.scene.ray_intersect(a.ray, mi.RayFlags.All, False, a.active)
            role_a = view.hit_role(si_a)
            mask = dr.select((depth == 0) & (role_a == ROLE_VIRTUAL), 1.0, mask)
            if fork_enabled:
                # hit rule 2: the lane forks here; phase 2 continues its real path
                forked, fork_depth, to_real = self.rules.fork(a.active, role_a, depth, forked,
                                                              fork_depth)
            else:
                to_real = to_real_const
            lm, lr = self._vertex(view, a, si_a, role_a, key, depth, lm, lr, to_real=to_real,
                                  to_mixed=True, c=c,
                                  shadow_kind=None if onepass else kind)
            depth = depth + 1
            return a, lm, lr, mask, depth, [c[k] for k in RAY_TYPES], forked, fork_depth

        a, lm, lr, mask, depth, cnt, forked, fork_depth = dr.while_loop(
            state=state, cond=cond, body=body, label="onepass_mixed")
        dr.eval(lm, lr, mask, cnt, forked, fork_depth)
        counts = {k: int(dr.sum(v)[0]) for k, v in zip(RAY_TYPES, cnt, strict=True)}
        t1 = time.perf_counter()
        self.profile["lanes"] += n
        self.profile["phase1_seconds"] += t1 - t0
        if fork_enabled:
            lr = self._trace_forks(rays, forked, fork_depth, key, lr, counts)
            self.profile["phase2_seconds"] += time.perf_counter() - t1
        if not onepass:
            lr = lm
        return TraceResult(lm, lr, mask, counts)

    def _trace_forks(self, rays: mi.Ray3f, forked: mi.Bool, fork_depth: mi.UInt32,
                     key: LaneSampler, lr: mi.Color3f, counts: dict[str, int]) -> mi.Color3f:
        """Phase 2: the real continuations of the forked lanes only (hit rules 2–3).

        Compacts the forked lanes and traces them in µ from their camera rays. Random numbers
        depend only on (lane, depth, dimension), and before its fork a lane's path only met
        real surfaces, so in µ it retraces exactly the shared prefix of phase 1 (bit for bit:
        same rays, same real shapes, same numbers); that prefix updates the path state only —
        its light is already in ``L_r`` — and the real path gathers light from the fork depth
        on (the virtual hit there is passed through: the continuation ray of rule 2). Most
        forks happen at the camera ray, where there is no prefix. Keeping no per-lane fork
        state in phase 1 keeps its loop as lean as a plain mixed path. ``counts`` gains the
        rays traced here.
        """
        idx, rays_b, key_b, start_depth = self.rules.continuations(rays, forked, fork_depth,
                                                                   key)
        m = dr.width(idx)
        self.profile["forked_lanes"] += m
        if m == 0:
            return lr
        zero_u = dr.zeros(mi.UInt32, m)
        state = (_Path.start(rays_b, True, self.light_selection.kept),
                 dr.gather(mi.Color3f, lr, idx), mi.UInt32(zero_u), mi.UInt32(zero_u),
                 mi.UInt32(zero_u))

        def cond(b, lr_b, depth, n_rad, n_shadow):
            return b.active

        def body(b, lr_b, depth, n_rad, n_shadow):
            c = {"rays_real_shadow": n_shadow}
            n_rad += dr.select(b.active, 1, 0)
            si_b = self.real.scene.ray_intersect(b.ray, mi.RayFlags.All, False, b.active)
            _, lr_b = self._vertex(self.real, b, si_b, self.real.hit_role(si_b), key_b, depth,
                                   None, lr_b, to_real=depth >= start_depth, to_mixed=False,
                                   c=c)
            return b, lr_b, depth + 1, n_rad, c["rays_real_shadow"]

        _, lr_b, _, n_rad, n_shadow = dr.while_loop(state=state, cond=cond, body=body,
                                                   label="onepass_real")
        lr = mi.Color3f(lr)
        dr.scatter(lr, lr_b, idx)
        dr.eval(lr, n_rad, n_shadow)
        counts["rays_real_radiance"] += int(dr.sum(n_rad)[0])
        counts["rays_real_shadow"] += int(dr.sum(n_shadow)[0])
        return lr

    def _is_env(self, emitter: mi.EmitterPtr) -> mi.Bool:
        flags = emitter.flags()
        return (mi.has_flag(flags, mi.EmitterFlags.Infinite)
                & ~mi.has_flag(flags, mi.EmitterFlags.DeltaDirection))

    def _reprojected_shadow(self, lm: mi.Color3f, contrib: mi.Color3f, shadow: mi.Ray3f,
                            blocked_m: mi.Bool, c: dict[str, mi.UInt32]) -> mi.Color3f:
        """The direct part of the differential at a reprojected point: the frame already
        holds the real light there, so light that reaches it in µ but is blocked in ρ (a
        virtual object's shadow, seen through virtual glass) is subtracted. ``blocked_m``:
        reprojected lanes whose mixed shadow ray is blocked; their real ray is traced."""
        c["rays_real_shadow"] += dr.select(blocked_m, 1, 0)
        vis_r = blocked_m & ~self.real.scene.ray_test(shadow, blocked_m)
        return lm - dr.select(vis_r, contrib, 0.0)

    def _vertex(self, view: SceneView, st: _Path, si: mi.SurfaceInteraction3f, role: mi.Int32,
                key: LaneSampler, depth: mi.UInt32, lm: mi.Color3f | None, lr: mi.Color3f, *,
                to_real: mi.Bool | bool, to_mixed: bool, c: dict[str, mi.UInt32],
                shadow_kind: str | None = None) -> tuple[mi.Color3f | None, mi.Color3f]:
        """Shade one path vertex in ``view`` and advance the path state in place.

        ``to_mixed`` (Python bool) and ``to_real`` (bool or per-lane mask) say which
        solutions the vertex feeds; a vertex feeding both traces a mixed shadow ray and,
        where that is blocked, a real one (hit rule 1). ``shadow_kind`` (two-pass mode) names
        the counter of this view's shadow rays. ``lm`` may be None when ``to_mixed`` is off.
        """
        scene = view.scene
        active = mi.Bool(st.active)
        valid = si.is_valid()

        def add(acc, val, where):
            """``acc + val`` where ``where`` (True, False or a per-lane mask)."""
            if where is False:
                return acc
            if where is True:
                return acc + val
            return acc + dr.select(where, val, 0.0)

        # -- reprojection of the camera frame (Kán §5.2): ends the path, after the direct
        #    part of the point's differential (the NEE below, mixed minus real visibility)
        reproj = mi.Bool(False)
        if self.reproj is not None and to_mixed:
            cand = (active & st.spec_virtual & valid & (role == ROLE_REAL)
                    & mi.has_flag(si.bsdf().flags(), mi.BSDFFlags.Diffuse))
            c["rays_reprojection"] += dr.select(cand, 1, 0)
            val, ok = self.reproj.lookup(si.p, cand)[:2]
            lm = lm + dr.select(ok, st.beta * val, 0.0)
            active &= ~ok
            reproj = ok

        # -- emitter hit (area light or environment on a miss), MIS vs the previous BSDF
        if self.opts.mirror_lower_hemisphere:
            si.wi = dr.select(valid, si.wi, mi.Vector3f(si.wi.x, -dr.abs(si.wi.y), si.wi.z))
        ds = hit_sample(view, si, st.prev_si)
        em_pdf = self.light_selection.pdf(view, st.prev_si, ds, active & ~st.prev_delta,
                                          st.prev_imps)
        mis = mis_weight(st.prev_pdf, em_pdf)
        if self.miss_only:
            mis = dr.select(self._is_env(ds.emitter), 1.0, mis)
        le = st.beta * mis * ds.emitter.eval(si, active)
        if self.opts.first_emission_depth > 0:
            le = dr.select(depth >= self.opts.first_emission_depth, le, 0.0)
        lm = add(lm, le, to_mixed)
        lr = add(lr, le, to_real)

        # -- next-event estimation with separate mixed/real visibility
        active_next = active & valid
        if self.opts.max_depth > 0:
            active_next &= depth + 1 < self.opts.max_depth
            reproj &= depth + 1 < self.opts.max_depth
        bsdf = si.bsdf()
        active_em = (active_next | reproj) & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
        imps = self.light_selection.importances(view, si, active_next | reproj)
        ds, em_weight = self.light_selection.sample(view, si, rand_nee(key, depth),
                                                     active_em, imps)
        active_em &= ds.pdf != 0.0
        if self.miss_only:
            active_em &= ~self._is_env(ds.emitter)
        wo = si.to_local(ds.d)
        # one BSDF call for the NEE evaluation and the bounce sample (as Mitsuba's ``path``)
        f_em, pdf_em, bs, weight = bsdf.eval_pdf_sample(
            self.ctx, si, wo, rand_lobe(key, depth), rand_bsdf(key, depth),
            active_next | reproj)
        # a reprojected path ends here: its NEE is the only strategy (weight 1)
        mis_em = dr.select(ds.delta | reproj, 1.0, mis_weight(ds.pdf, pdf_em))
        contrib = st.beta * mis_em * f_em * em_weight
        active_em &= dr.max(contrib) > 0
        shadow = si.spawn_ray_to(ds.p)
        if shadow_kind is not None:  # two-pass: this view's own shadow rays
            c[f"rays_{shadow_kind}_shadow"] += dr.select(active_em, 1, 0)
            vis = active_em & ~scene.ray_test(shadow, active_em)
            lm = add(lm, contrib, vis & ~reproj)
            if self.reproj is not None and to_mixed:
                lm = self._reprojected_shadow(lm, contrib, shadow, reproj & active_em & ~vis, c)
        else:  # hit rules 1 (mixed shadow ray, real one only where needed) and 3
            vis_m, vis_r = self.rules.shadow(shadow, active_em, to_mixed=to_mixed,
                                             to_real=to_real, c=c, no_real=reproj)
            if to_mixed:
                lm = add(lm, contrib, vis_m & ~reproj)
                lr = add(lr, contrib, vis_r & ~reproj)
                if self.reproj is not None:
                    lm = self._reprojected_shadow(lm, contrib, shadow,
                                                  reproj & active_em & ~vis_m, c)
            else:
                lr = add(lr, contrib, vis_r)

        # -- BSDF sampling, path update, Russian roulette
        delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
        if to_mixed:
            st.spec_virtual = delta & (st.spec_virtual | (role == ROLE_VIRTUAL))
        st.ray = dr.select(active_next, si.spawn_ray(si.to_world(bs.wo)), st.ray)
        st.eta = dr.select(active_next, st.eta * bs.eta, st.eta)
        st.beta = dr.select(active_next, st.beta * weight, st.beta)
        st.prev_si = dr.select(active_next, light_context(si), st.prev_si)
        st.prev_pdf = dr.select(active_next, bs.pdf, st.prev_pdf)
        st.prev_delta = dr.select(active_next, delta, st.prev_delta)
        st.prev_imps = [dr.select(active_next, a, b) for a, b in zip(imps, st.prev_imps,
                                                                      strict=True)]
        beta_max = dr.max(st.beta)
        active_next &= beta_max != 0
        rr = active_next & (depth >= self.opts.rr_depth)
        q = dr.minimum(beta_max * dr.square(st.eta), 0.95)
        st.beta = dr.select(rr, st.beta / q, st.beta)
        active_next &= ~rr | (rand_rr(key, depth) < q)
        st.active = active_next
        return lm, lr
