"""Next-event light sampling: which light, and which point on it.

Replaces Mitsuba's ``Scene.sample_emitter_direction`` / ``pdf_emitter_direction`` pair for a
path tracer (the two must agree for MIS). Three ways of choosing the emitter (``selection``):

* ``"importance"`` (default) — **per shading point** (pbrt-v4's light-bounds importance, as
  its ``BVHLightSampler`` / ``ExhaustiveLightSampler`` and Cycles' light tree): emitter ``i``
  is chosen with probability ∝ an upper estimate of the irradiance it can bring to the point
  ``p`` with normal ``n``:

  - bounded lights (area, sphere, point, spot): ``J cos θ'_e cos θ'_i / max(d², r_b²)`` with
    ``J`` the light's largest radiant intensity (luminance, W/sr: ``L·A`` for a flat area
    light, ``L·π r²`` for a sphere, ``I`` for point and spot), ``d`` the distance to the
    centre of its bounding sphere (radius ``r_b``), ``θ'_e`` the smallest angle between the
    light's emission cone and ``p`` and ``θ'_i`` the smallest angle between ``±n`` and the
    light, both widened by the angle ``θ_b`` the bounding sphere subtends (pbrt-v4
    ``LightBounds::Importance``). It is zero only where the light cannot reach ``p``: behind
    a one-sided flat light's plane, outside a spot's cone;
  - a directional light: its irradiance ``E |n · ω_l|``;
  - a constant or environment emitter: the irradiance of its first-order (linear)
    approximation ``L(ω) ≈ L̄ + a·ω`` on the better-lit side, ``π L̄ + 2π/3 |a · n|``
    (``L̄`` and ``a`` integrated once over the sphere with the emitter's own sampling).

  None of these depend on the scene's size: distant and local lights are weighed by what
  they bring to the point (Cycles' distant/local split by estimated contribution). A share
  ``uniform_mix`` of the selection is uniform over the lights, ``p_i = (1 − ε) imp_i / Σ imp
  + ε / N`` (defensive sampling: occlusion is not in the estimate, so a shadowed point keeps
  sampling the lights that do reach it). Cost: ``O(N)`` per sample (one weighted-reservoir
  pass over the emitters to sample, one sum to evaluate the pdf); a light tree would make it
  ``O(log N)`` for scenes with hundreds of lights, which ours do not have.
* ``"power"`` — one global estimate of each emitter's power (pbrt-v4's
  ``PowerLightSampler``): one-sided area light ``π A L``, sphere ``4π² r² L``, point ``4π I``,
  spot ``2π (1 − cos θ) I``, directional ``π R² E`` and constant / environment ``4π² R² L̄``
  with ``R`` the scene's bounding radius — which lets a large scene's sky take nearly every
  sample from a small bright light (issue #35).
* ``"uniform"`` — every emitter equally (Mitsuba).

Where a point on the light is drawn:

* **Spherical rectangles** (Ureña, Fajardo & King, *An Area-Preserving Parametrization for
  Spherical Rectangles*, EGSR 2013, Alg. 1): a rectangular area light (``rectangle`` shape
  with an ``area`` emitter and orthogonal edges) is sampled uniformly in the solid angle it
  subtends, pdf ``1/S``, instead of uniformly in area (pdf ``d²/(A cos θ_l)``). Where the
  solid angle is tiny (``S < min_solid_angle``: the float32 angle sum ``S = Σγ_i − 2π``
  loses precision) the emitter's own area sampling is used; the choice depends only on the
  reference point and the light, so sampling and pdf agree.
* **Skies with the cosine in mind** (``selection="importance"``): a constant emitter is
  sampled cosine-weighted about the shading normal turned towards the side the path arrived
  from (pdf ``cos θ / π``; none of its samples below the horizon); an environment map with
  the one-sample mixture ``env_cosine · cos θ / π + (1 − env_cosine) · p_map``, where
  ``env_cosine`` is 0 by default (chosen on training worlds: the map's own importance
  sampling, which finds its sun, did better than any mixture). Light from behind the
  surface (rough glass) is left to BSDF sampling, whose MIS weight there is one.
* Other emitters (spheres — Mitsuba samples their cone —, point, spot, directional) use the
  emitter's ``sample_direction`` / ``pdf_direction``.

The shading context of a vertex (:func:`light_context`) is its position and geometric
normal turned towards the arriving path; :meth:`LightSampler.sample` and
:meth:`LightSampler.pdf` must see the same context for MIS (the tracer keeps it as the
previous vertex's interaction).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

MIN_SOLID_ANGLE = 1e-2
"""Solid angle (sr) below which a rectangle falls back to area sampling (see module doc)."""

SELECTIONS = ("importance", "power", "uniform")
UNIFORM_MIX = 0.1
"""Share of the importance selection spread evenly over the lights that can reach a point."""
ENV_COSINE = 0.0
"""Share of an environment map's samples drawn cosine-weighted about the shading normal.
Chosen on training worlds (``benchmarks/tune_light_selection.py``, RESULTS.md): any cosine
share raised onepass's variance there (e.g. 0.70 → 1.34 of reference's at 0.5 on world-0),
the map's own importance sampling being the better half; a constant sky, whose importance
sampling is uniform over the sphere, is always sampled cosine-weighted."""
ENV_INTEGRAL_SAMPLES = 1 << 16
"""Directions (stratified, the emitter's own importance sampling) integrating ``L̄`` and
``a`` of an environment once per scene."""

KIND_LOCAL, KIND_DISTANT, KIND_INFINITE = 0, 1, 2
NO_LIGHT = 0xFFFFFFFF


def _lum(rgb) -> float:
    c = np.asarray(rgb, np.float64).reshape(-1)
    if c.size == 1:
        return float(c[0])
    return float(0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2])


def _value(params: mi.SceneParameters, key: str):
    return np.array(params[key], dtype=np.float64) if key in params else None


def _matrix(params: mi.SceneParameters, key: str = "to_world") -> np.ndarray:
    m = np.array(params[key].matrix, dtype=np.float64)
    return m.reshape(4, 4) if m.size == 16 else m[..., 0]


def _spot_angles(emitter: mi.Emitter) -> tuple[float, float]:
    """(beam width, cutoff) of a Mitsuba spot light, radians."""
    p = mi.traverse(emitter)
    cut = float(np.array(p["cutoff_angle"]).reshape(-1)[0]) if "cutoff_angle" in p else 20.0
    beam = float(np.array(p["beam_width"]).reshape(-1)[0]) if "beam_width" in p else cut * 0.75
    return math.radians(min(beam, cut)), math.radians(cut)


def emitter_power(emitter: mi.Emitter, shape: mi.Shape | None, radius: float,
                  env_mean: float | None = None) -> float:
    """Estimated power (luminance, W) of one emitter for ``selection="power"`` (see the
    module docstring); ``radius`` (m) is the scene's bounding radius, ``env_mean`` an
    infinite emitter's ``L̄`` when already known (:func:`environment_moments`)."""
    name = emitter.class_name()
    p = mi.traverse(emitter)
    if name == "AreaLight" and shape is not None:
        lum = _lum(_value(p, "radiance.value")) if "radiance.value" in p else 1.0
        area = float(dr.sum(shape.surface_area())[0]) if hasattr(shape, "surface_area") else 1.0
        return math.pi * area * lum
    if name == "PointLight":
        return 4 * math.pi * _lum(_value(p, "intensity.value"))
    if name == "SpotLight":
        beam, cut = _spot_angles(emitter)
        return 2 * math.pi * (1 - math.cos(0.5 * (cut + beam))) * _lum(_value(p, "intensity.value"))
    if name == "DirectionalEmitter":
        return math.pi * radius**2 * _lum(_value(p, "irradiance.value"))
    if name in ("ConstantBackgroundEmitter", "EnvironmentMapEmitter"):
        mean = environment_moments(emitter)[0] if env_mean is None else env_mean
        return 4 * math.pi**2 * radius**2 * mean
    return 1.0  # unknown emitter: a neutral weight (still unbiased)


def environment_moments(emitter: mi.Emitter, n: int = ENV_INTEGRAL_SAMPLES
                        ) -> tuple[float, np.ndarray]:
    """Mean radiance ``L̄`` (luminance, W/(sr·m²)) of an infinite emitter over the sphere and
    the vector ``a`` of its linear approximation ``L(ω) ≈ L̄ + a·ω`` (least squares:
    ``a = 3/(4π) ∫ L(ω) ω dω``), both integrated with the emitter's own importance sampling
    over a stratified ``√n × √n`` grid (the map's texels, a sun included, are found by its
    own sampling, not missed by a fixed grid)."""
    side = max(int(math.isqrt(n)), 1)
    g = (np.arange(side, dtype=np.float64) + 0.5) / side
    u = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2).astype(np.float32)
    it = dr.zeros(mi.Interaction3f, len(u))
    ds, w = emitter.sample_direction(it, mi.Point2f(u[:, 0], u[:, 1]), True)
    lum = mi.luminance(w) + dr.zeros(mi.Float, len(u))
    lum = np.array(dr.select(dr.isfinite(lum), lum, 0.0), np.float64)
    d = np.stack([np.array(ds.d[c] + dr.zeros(mi.Float, len(u)), np.float64) for c in range(3)], 1)
    mean = float(lum.mean() / (4 * math.pi))
    a = 3.0 * (lum[:, None] * d).mean(axis=0) / (4 * math.pi)
    return mean, a


class LightTable:
    """The emitters of one scene as light bounds (NumPy rows in the order of
    ``scene.emitters()``; Dr.Jit copies as attributes with the same names).

    Attributes (``N`` emitters):
        kind: ``KIND_LOCAL`` | ``KIND_DISTANT`` | ``KIND_INFINITE``.
        center, radius: bounding sphere of a local light (m).
        axis: unit emission axis (local lights: flat lights' normal, spots' direction) or
            the unit direction *towards* a directional light, or ``a/|a|`` of an
            environment.
        theta_o, theta_e: emission cone half-angle about ``axis`` and the fall-off spread
            beyond it (radians; ``theta_o = π`` emits everywhere).
        one_sided: flat one-sided emitters (zero behind their plane).
        intensity: ``J`` (local, W/sr), ``E`` (directional, W/m²) or ``π L̄`` (infinite).
        linear: ``2π/3 |a|`` of an infinite emitter (W/m²), else 0.
        cap: largest irradiance a local light can give (``π L`` for area lights, W/m²;
            ``inf`` for points).
        power: the global power estimate of ``selection="power"`` (W).
    """

    def __init__(self, scene: mi.Scene, shapes: dict[int, mi.Shape], ids: np.ndarray):
        emitters = list(scene.emitters())
        n = len(emitters)
        bbox = scene.bbox()
        radius_scene = float(dr.norm(bbox.max - bbox.min)) / 2 if bbox.valid() else 1.0
        self.kind = np.zeros(n, np.uint32)
        self.center = np.zeros((n, 3))
        self.radius = np.zeros(n)
        self.axis = np.zeros((n, 3))
        self.axis[:, 2] = 1.0
        self.theta_o = np.full(n, math.pi)
        self.theta_e = np.full(n, math.pi / 2)
        self.one_sided = np.zeros(n, bool)
        self.intensity = np.zeros(n)
        self.linear = np.zeros(n)
        self.cap = np.full(n, np.inf)
        self.power = np.ones(n)
        for i, (em, reg) in enumerate(zip(emitters, ids, strict=True)):
            sh = shapes.get(int(reg))
            self._describe(i, em, sh)
            env_mean = self.intensity[i] / math.pi if self.kind[i] == KIND_INFINITE else None
            self.power[i] = max(emitter_power(em, sh, max(radius_scene, 1e-3), env_mean), 0.0)

    def _describe(self, i: int, em: mi.Emitter, sh: mi.Shape | None) -> None:
        name = em.class_name()
        p = mi.traverse(em)
        if name == "AreaLight" and sh is not None:
            lum = _lum(_value(p, "radiance.value")) if "radiance.value" in p else 1.0
            area = float(dr.sum(sh.surface_area())[0])
            b = sh.bbox()
            lo, hi = np.array(b.min, np.float64).ravel(), np.array(b.max, np.float64).ravel()
            self.center[i] = 0.5 * (lo + hi)
            self.radius[i] = 0.5 * float(np.linalg.norm(hi - lo))
            self.cap[i] = math.pi * lum
            cls = sh.class_name()
            if cls in ("Rectangle", "Disk"):
                m = _matrix(mi.traverse(sh))
                nrm = np.linalg.inv(m[:3, :3]).T @ np.array([0.0, 0.0, 1.0])
                self.axis[i] = nrm / np.linalg.norm(nrm)
                self.theta_o[i], self.theta_e[i] = 0.0, math.pi / 2
                self.one_sided[i] = True
                self.intensity[i] = lum * area
            elif cls == "Sphere":
                self.intensity[i] = lum * area / 4  # L·πr²
            else:  # a mesh: no emission cone, projected area at most half its area
                self.intensity[i] = lum * area / 2
        elif name in ("PointLight", "SpotLight"):
            self.intensity[i] = _lum(_value(p, "intensity.value"))
            if name == "PointLight":
                self.center[i] = np.array(p["position"], np.float64).ravel()[:3]
            else:
                m = _matrix(p)
                self.center[i] = m[:3, 3]
                ax = m[:3, :3] @ np.array([0.0, 0.0, 1.0])
                self.axis[i] = ax / np.linalg.norm(ax)
                beam, cut = _spot_angles(em)
                self.theta_o[i], self.theta_e[i] = beam, cut - beam
        elif name == "DirectionalEmitter":
            self.kind[i] = KIND_DISTANT
            m = _matrix(p)
            d = m[:3, :3] @ np.array([0.0, 0.0, 1.0])
            self.axis[i] = -d / np.linalg.norm(d)
            self.intensity[i] = _lum(_value(p, "irradiance.value"))
        elif name in ("ConstantBackgroundEmitter", "EnvironmentMapEmitter"):
            self.kind[i] = KIND_INFINITE
            mean, a = environment_moments(em)
            norm_a = float(np.linalg.norm(a))
            if norm_a > 0:
                self.axis[i] = a / norm_a
            self.intensity[i] = math.pi * mean
            self.linear[i] = 2 * math.pi / 3 * norm_a
        else:  # unknown emitter: treated as infinite with a unit weight (still unbiased)
            self.kind[i] = KIND_INFINITE
            self.intensity[i] = 1.0

    def importance(self, p: np.ndarray, n: np.ndarray | None = None) -> np.ndarray:
        """The importance of every light at points ``p`` (M, 3) with normals ``n`` (M, 3;
        zero or None: no orientation) as an (M, N) NumPy array in float64 — the reference
        the Dr.Jit version (:meth:`LightSampler.importance`) is tested against."""
        p = np.atleast_2d(np.asarray(p, np.float64))
        n = np.zeros_like(p) if n is None else np.atleast_2d(np.asarray(n, np.float64))
        has_n = np.linalg.norm(n, axis=1) > 0
        out = np.zeros((len(p), len(self.kind)))
        for i, k in enumerate(self.kind):
            if k == KIND_DISTANT:
                c = np.abs(n @ self.axis[i])
                out[:, i] = self.intensity[i] * np.where(has_n, c, 1.0)
                continue
            if k == KIND_INFINITE:
                c = np.abs(n @ self.axis[i])
                out[:, i] = self.intensity[i] + self.linear[i] * np.where(has_n, c, 1.0)
                continue
            v = p - self.center[i]
            d2 = np.einsum("ij,ij->i", v, v)
            dist = np.sqrt(d2)
            r = self.radius[i]
            with np.errstate(divide="ignore", invalid="ignore"):
                wo = v / dist[:, None]
                theta_b = np.where(dist > r, np.arcsin(np.clip(r / dist, 0, 1)), math.pi)
            theta_w = np.arccos(np.clip(wo @ self.axis[i], -1, 1))
            theta_x = np.maximum(theta_w - self.theta_o[i] - theta_b, 0.0)
            emit = np.where(theta_x <= self.theta_e[i], np.cos(np.minimum(theta_x, math.pi / 2)),
                            0.0)
            if self.one_sided[i]:
                emit = np.where(v @ self.axis[i] > 0, emit, 0.0)
            theta_i = np.arccos(np.clip(np.abs(np.einsum("ij,ij->i", n, wo)), 0, 1))
            recv = np.where(has_n, np.cos(np.maximum(theta_i - theta_b, 0.0)), 1.0)
            d2c = np.maximum(d2, max(r * r, 1e-12))
            out[:, i] = np.minimum(self.intensity[i] * emit * recv / d2c, self.cap[i])
        return out


def light_context(si: mi.SurfaceInteraction3f) -> mi.Interaction3f:
    """The shading context of a surface vertex for light selection: its position and its
    geometric normal turned towards the side the path arrived from (``si.wi``)."""
    it = mi.Interaction3f(si)
    it.n = _arrival_normal(si)
    return it


def _arrival_normal(it: mi.Interaction3f) -> mi.Vector3f:
    if isinstance(it, mi.SurfaceInteraction3f):
        w = it.to_world(it.wi)
        return dr.select(dr.dot(it.n, w) < 0, -it.n, it.n)
    return mi.Vector3f(it.n)


def spherical_rectangle(o: mi.Point3f, s: mi.Point3f, ex: mi.Vector3f, ey: mi.Vector3f,
                        u: mi.Point2f) -> tuple[mi.Point3f, mi.Float]:
    """Ureña et al. 2013 Alg. 1: a point on the rectangle ``s + a·ex + b·ey`` (orthogonal
    edges), uniform in the solid angle seen from ``o``; returns (point, solid angle S)."""
    exl, eyl = dr.norm(ex), dr.norm(ey)
    x, y = ex / exl, ey / eyl
    z = dr.cross(x, y)
    d = s - o
    z0 = dr.dot(d, z)
    flip = z0 > 0
    z = dr.select(flip, -z, z)
    z0 = dr.select(flip, -z0, z0)
    x0, y0 = dr.dot(d, x), dr.dot(d, y)
    x1, y1 = x0 + exl, y0 + eyl
    # z components of the normals of the four sides of the spherical rectangle
    n0z = -y0 / dr.sqrt(z0 * z0 + y0 * y0)
    n1z = x1 / dr.sqrt(z0 * z0 + x1 * x1)
    n2z = y1 / dr.sqrt(z0 * z0 + y1 * y1)
    n3z = -x0 / dr.sqrt(z0 * z0 + x0 * x0)
    g0 = dr.safe_acos(-n0z * n1z)
    g1 = dr.safe_acos(-n1z * n2z)
    g2 = dr.safe_acos(-n2z * n3z)
    g3 = dr.safe_acos(-n3z * n0z)
    k = 2.0 * dr.pi - g2 - g3
    solid = g0 + g1 - k
    b0, b1 = n0z, n2z
    au = u.x * solid + k
    fu = (dr.cos(au) * b0 - b1) / dr.sin(au)
    cu = dr.mulsign(dr.rsqrt(fu * fu + b0 * b0), fu)
    cu = dr.clip(cu, -1.0, 1.0)
    xu = -(cu * z0) / dr.safe_sqrt(1.0 - cu * cu)
    xu = dr.clip(xu, x0, x1)
    dd = dr.sqrt(xu * xu + z0 * z0)
    h0 = y0 / dr.sqrt(dd * dd + y0 * y0)
    h1 = y1 / dr.sqrt(dd * dd + y1 * y1)
    hv = h0 + u.y * (h1 - h0)
    hv2 = hv * hv
    yv = dr.select(hv2 < 1.0 - 1e-6, hv * dd / dr.safe_sqrt(1.0 - hv2), y1)
    return o + xu * x + yv * y + z0 * z, solid


def rectangle_solid_angle(o: mi.Point3f, s: mi.Point3f, ex: mi.Vector3f,
                          ey: mi.Vector3f) -> mi.Float:
    """Solid angle (sr) of the rectangle seen from ``o`` (the ``S`` of
    :func:`spherical_rectangle`, computed the same way)."""
    return spherical_rectangle(o, s, ex, ey, mi.Point2f(0.5, 0.5))[1]


def _padded(a: np.ndarray) -> np.ndarray:
    """``a`` with one zero row appended. Every per-light table is at least two entries wide:
    a one-entry Dr.Jit array is read as a scalar, and the kernels' hash then depends on how
    that scalar's buffer was allocated, so each newly built scene compiled the tracer anew
    (seconds per frame; issue #35). The extra row is never selected."""
    a = np.asarray(a)
    return np.concatenate([a, np.zeros((1, *a.shape[1:]), a.dtype)])


def _f32(a: np.ndarray) -> mi.Float:
    return mi.Float(np.ascontiguousarray(_padded(a), np.float32))


def _v3(a: np.ndarray, cls=mi.Vector3f):
    return cls(*(_f32(a[:, c]) for c in range(3)))


MAX_UNROLLED = 16
"""Up to this many lights the importance selection evaluates each light by its own code:
its kind picks the formula when the kernel is built, and its bounds are scalars instead of
per-lane table reads (``LightSampler.importances``). More lights: one loop over the table."""


@dataclass
class Bounds:
    """Light bounds in Dr.Jit (the columns of :class:`LightTable`): one entry per light
    (the whole table, or one light's opaque scalars), or gathered per lane."""

    kind: mi.UInt32
    center: mi.Point3f
    axis: mi.Vector3f
    radius: mi.Float
    cos_o: mi.Float
    sin_o: mi.Float
    cos_e: mi.Float
    one_sided: mi.Bool
    intensity: mi.Float
    linear: mi.Float
    cap: mi.Float

    @staticmethod
    def of(t: LightTable, row: int | None = None) -> Bounds:
        """Row ``row`` of ``t`` as opaque Dr.Jit scalars, or (None) the whole table padded
        to two wide (:func:`_padded`) as opaque arrays: not compiled into the kernels, so a
        rebuilt or moved light reuses them."""
        if row is None:
            f = lambda a: mi.Float(np.ascontiguousarray(_padded(a), np.float32))  # noqa: E731
            u = lambda a: mi.UInt32(_padded(a))  # noqa: E731
            flag = lambda a: mi.Bool(_padded(a))  # noqa: E731
        else:
            f = lambda a: dr.opaque(mi.Float, float(np.asarray(a)[row]))  # noqa: E731
            u = lambda a: dr.opaque(mi.UInt32, int(np.asarray(a)[row]))  # noqa: E731
            flag = lambda a: dr.opaque(mi.Bool, bool(np.asarray(a)[row]))  # noqa: E731
        v = lambda a, cls=mi.Vector3f: cls(*(f(a[:, c]) for c in range(3)))  # noqa: E731
        b = Bounds(kind=u(t.kind), center=v(t.center, mi.Point3f), axis=v(t.axis),
                   radius=f(t.radius), cos_o=f(np.cos(t.theta_o)), sin_o=f(np.sin(t.theta_o)),
                   cos_e=f(np.cos(t.theta_e)), one_sided=flag(t.one_sided),
                   intensity=f(t.intensity), linear=f(t.linear),
                   cap=f(np.minimum(t.cap, 3e38)))
        dr.make_opaque(*(getattr(b, k) for k in b.__dataclass_fields__))
        return b

    def gather(self, i: mi.UInt32, active: mi.Bool | bool) -> Bounds:
        """The bounds of light ``i`` per lane."""
        return Bounds(**{k: dr.gather(type(getattr(self, k)), getattr(self, k), i, active)
                         for k in self.__dataclass_fields__})


def bounds_importance(b: Bounds, p: mi.Point3f, n: mi.Vector3f, kind: int | None = None
                      ) -> mi.Float:
    """Importance of the light(s) ``b`` at ``p`` with normal ``n`` (zero: unoriented): the
    irradiance bound of the module docstring (:meth:`LightTable.importance` in Dr.Jit).
    ``kind`` (a ``KIND_*``): the light's kind known when the kernel is built, so only its
    formula is traced; None: all three, chosen per lane by ``b.kind``."""
    has_n = dr.squared_norm(n) > 0
    out = None
    if kind in (None, KIND_DISTANT, KIND_INFINITE):
        c_n = dr.select(has_n, dr.abs(dr.dot(n, b.axis)), 1.0)
        distant = b.intensity * c_n
        infinite = b.intensity + b.linear * c_n
        out = {KIND_DISTANT: distant, KIND_INFINITE: infinite}.get(kind)
    if kind in (None, KIND_LOCAL):
        r = b.radius
        v = p - b.center
        d2 = dr.squared_norm(v)
        dist = dr.sqrt(d2)
        wo = v / dr.maximum(dist, 1e-30)
        # angles without trigonometric calls (pbrt-v4's cosSubClamped / sinSubClamped):
        # θ_b subtended by the bounding sphere (π inside it), θ_x = max(0, θ_w − θ_o − θ_b)
        outside = dist > r
        sin_b = dr.select(outside, r / dr.maximum(dist, 1e-30), 0.0)
        cos_b = dr.select(outside, dr.safe_sqrt(1.0 - sin_b * sin_b), -1.0)
        cos_w = dr.dot(wo, b.axis)
        sin_w = dr.safe_sqrt(1.0 - cos_w * cos_w)
        inside_o = cos_w > b.cos_o
        cos_wo = dr.select(inside_o, 1.0, cos_w * b.cos_o + sin_w * b.sin_o)
        sin_wo = dr.select(inside_o, 0.0, sin_w * b.cos_o - cos_w * b.sin_o)
        cos_x = dr.select(cos_wo > cos_b, 1.0, cos_wo * cos_b + sin_wo * sin_b)
        emit = dr.select(cos_x >= b.cos_e, dr.maximum(cos_x, 0.0), 0.0)
        emit = dr.select(b.one_sided & (dr.dot(v, b.axis) <= 0), 0.0, emit)
        cos_i = dr.abs(dr.dot(n, wo))
        sin_i = dr.safe_sqrt(1.0 - cos_i * cos_i)
        recv = dr.select(has_n, dr.select(cos_i > cos_b, 1.0, cos_i * cos_b + sin_i * sin_b),
                         1.0)
        d2c = dr.maximum(d2, dr.maximum(r * r, 1e-12))
        local = dr.minimum(b.intensity * emit * recv / d2c, b.cap)
        out = local if kind == KIND_LOCAL else dr.select(
            b.kind == KIND_DISTANT, distant, dr.select(b.kind == KIND_INFINITE, infinite, local))
    return dr.maximum(out, 0.0)


class LightSampler:
    """Emitter selection and light sampling for one scene (see the module docstring).

    Args:
        scene: the Mitsuba scene whose emitters are sampled.
        selection: ``"importance"`` | ``"power"`` | ``"uniform"``.
        solid_angle: sample rectangular area lights by solid angle (False: by area, as
            Mitsuba).
        uniform_mix: share of the importance selection spread evenly (``"importance"``;
            default :data:`UNIFORM_MIX`).
        env_cosine: share of an environment map's samples drawn cosine-weighted (a constant
            emitter's are all cosine-weighted; ``"importance"`` only; default
            :data:`ENV_COSINE`).
        min_solid_angle: below this solid angle (sr) a rectangle is sampled by area.
    """

    def __init__(self, scene: mi.Scene, selection: str = "importance", solid_angle: bool = True,
                 uniform_mix: float | None = None, env_cosine: float | None = None,
                 min_solid_angle: float = MIN_SOLID_ANGLE):
        if selection not in SELECTIONS:
            raise ValueError(f"unknown light selection {selection!r} (expected one of "
                             f"{SELECTIONS})")
        self.scene = scene
        self.selection = selection
        # the module's constants read at construction (benchmarks/tune_light_selection.py
        # sets them on training worlds)
        self.uniform_mix = float(UNIFORM_MIX if uniform_mix is None else uniform_mix)
        self.env_cosine = float(ENV_COSINE if env_cosine is None else env_cosine)
        self.min_solid_angle = float(min_solid_angle)
        emitters = list(scene.emitters())
        self.n = len(emitters)
        ids = np.array(dr.reinterpret_array(mi.UInt32, scene.emitters_dr()), dtype=np.int64)
        self.ptrs = dr.reinterpret_array(mi.EmitterPtr, mi.UInt32(_padded(ids.astype(np.uint32))))
        shapes = {}
        for sh in scene.shapes():
            if sh.is_emitter():
                shapes[int(np.array(dr.reinterpret_array(mi.UInt32,
                                                         mi.EmitterPtr(sh.emitter())))[0])] = sh
        self.table = LightTable(scene, shapes, ids)
        self._rectangles(emitters, ids, shapes, solid_angle)
        power = self.table.power if selection == "power" else np.ones(self.n)
        if not np.any(power > 0):
            power = np.ones(self.n)
        self.pmf_np = power / power.sum() if self.n else power
        self.distr = mi.DiscreteDistribution(_f32(self.pmf_np)) if self.n else None
        self.pmf = _f32(self.pmf_np)
        t = self.table
        self.bounds = Bounds.of(t)
        self.kind = self.bounds.kind
        self.unrolled = selection == "importance" and 1 < self.n <= MAX_UNROLLED
        # per light: its kind (a Python int: picks the formula) and its opaque scalars
        self.light_bounds = [(int(t.kind[i]), Bounds.of(t, i)) for i in range(self.n)
                             ] if self.unrolled else []
        self.constant = mi.Bool(_padded(np.array(
            [e.class_name() == "ConstantBackgroundEmitter" for e in emitters], bool)))
        size = max(int(ids.max()) + 1 if self.n else 1, 2)
        index = np.zeros(size, np.uint32)
        index[ids] = np.arange(self.n, dtype=np.uint32)
        self.index_of = mi.UInt32(index)
        # Opaque, not literals: a one-light scene's tables (and its emitter pointer, which
        # differs each time the scene is built) would otherwise be baked into the kernels
        # as constants, and every rebuilt scene would compile the tracer anew (seconds).
        dr.make_opaque(self.ptrs, self.pmf, self.constant, self.index_of, self.is_rect,
                       self.s, self.ex, self.ey, self.normal)

    def _rectangles(self, emitters, ids, shapes, solid_angle: bool) -> None:
        n = self.n
        rect = np.zeros(n, bool)
        s, ex, ey, normal = (np.zeros((n, 3)) for _ in range(4))
        for i, reg in enumerate(ids):
            sh = shapes.get(int(reg))
            if solid_angle and sh is not None and sh.class_name() == "Rectangle":
                m = _matrix(mi.traverse(sh))
                a, b = m[:3, 0] * 2.0, m[:3, 1] * 2.0
                if abs(a @ b) <= 1e-4 * np.linalg.norm(a) * np.linalg.norm(b):
                    rect[i] = True
                    s[i] = m[:3, 3] - m[:3, 0] - m[:3, 1]
                    ex[i], ey[i] = a, b
                    nrm = np.linalg.inv(m[:3, :3]).T @ np.array([0.0, 0.0, 1.0])
                    normal[i] = nrm / np.linalg.norm(nrm)  # Mitsuba's emitting side
        self.rect_np = rect
        self.is_rect = mi.Bool(_padded(rect))
        self.s, self.ex, self.ey = _v3(s, mi.Point3f), _v3(ex), _v3(ey)
        self.normal = _v3(normal)

    # -- selection ------------------------------------------------------------------------

    def importance(self, i: mi.UInt32, p: mi.Point3f, n: mi.Vector3f,
                   active: mi.Bool | bool = True) -> mi.Float:
        """Importance of light ``i`` (per lane) at ``p`` with normal ``n`` (zero: unoriented):
        :func:`bounds_importance` of the gathered bounds."""
        return dr.select(active, bounds_importance(self.bounds.gather(i, active), p, n), 0.0)

    def importances(self, it: mi.Interaction3f, active: mi.Bool | bool = True
                    ) -> list[mi.Float]:
        """The importance of every light at the shading context ``it`` (a surface
        interaction or its :func:`light_context`), each light by its own code
        (``unrolled``: ``1 < N ≤`` :data:`MAX_UNROLLED` under ``"importance"``); ``[]``
        otherwise. A tracer may keep them with the vertex and hand them back to
        :meth:`sample` and, at the next vertex, to :meth:`pdf` (the same context): the
        selection is then evaluated once per vertex."""
        n = _arrival_normal(it)
        return [dr.select(active, bounds_importance(b, it.p, n, kind), 0.0)
                for kind, b in self.light_bounds]

    def _pmf(self, imp: mi.Float, total: mi.Float) -> mi.Float:
        """Selection probability of a light of importance ``imp``: ``(1 − ε) imp / Σ + ε / N``
        (uniform where no light has importance)."""
        mix = self.uniform_mix
        return dr.select(total > 0, (1.0 - mix) * imp / dr.maximum(total, 1e-30)
                         + mix / self.n, 1.0 / self.n)

    @staticmethod
    def _reservoir_step(i, imp, total, idx, imp_idx, imp_u, u, idx_u):
        """Light ``i`` of importance ``imp`` offered to the reservoir: it replaces the choice
        with probability ``imp / Σ_{j≤i} imp_j`` and ``u`` is rescaled to stay uniform."""
        total = total + imp
        prob = dr.select(total > 0, imp / dr.maximum(total, 1e-30), 0.0)
        take = (imp > 0) & (u < prob)
        u = dr.select(take, u / dr.maximum(prob, 1e-30),
                      dr.select(imp > 0, (u - prob) / dr.maximum(1.0 - prob, 1e-30), u))
        idx = dr.select(take, i, idx)
        imp_idx = dr.select(take, imp, imp_idx)
        imp_u = dr.select(i == idx_u, imp, imp_u)
        return total, idx, imp_idx, imp_u, dr.clip(u, 0.0, 0.99999994)

    def _select(self, it: mi.Interaction3f, n: mi.Vector3f, ux: mi.Float, active: mi.Bool,
                imps: list[mi.Float] | None = None) -> tuple[mi.UInt32, mi.Float, mi.Float]:
        """(light index, its selection probability, ``ux`` reused) per lane: with probability
        ``ε`` a uniform choice, else one weighted-reservoir pass over the lights
        (:meth:`_reservoir_step`). ``imps``: :meth:`importances` at ``it``, when known."""
        if self.selection != "importance" or self.n == 1:
            idx, u_re, pmf = self.distr.sample_reuse_pmf(ux, active)
            return idx, pmf, u_re
        mix, count = self.uniform_mix, float(self.n)
        uniform = ux < mix
        ui = dr.select(uniform, ux / mix, (ux - mix) / (1.0 - mix)) * count
        idx_u = mi.UInt32(dr.minimum(mi.UInt32(ui), self.n - 1))
        u_uni = ui - mi.Float(idx_u)
        u_imp = dr.select(uniform, 0.5, (ux - mix) / (1.0 - mix))
        width = dr.width(it.p)
        zero = dr.zeros(mi.Float, width)
        state = (zero, dr.full(mi.UInt32, NO_LIGHT, width), zero, zero, mi.Float(u_imp))
        if self.unrolled:
            for i, imp in enumerate(imps or self.importances(it, active)):
                state = self._reservoir_step(mi.UInt32(i), imp, *state, idx_u)
            total, idx, imp_idx, imp_u, u = state
        else:
            def body(i, *st):
                imp = self.importance(i, it.p, n, active)
                return i + 1, *self._reservoir_step(i, imp, *st, idx_u)

            _, total, idx, imp_idx, imp_u, u = dr.while_loop(
                state=(mi.UInt32(0), *state), cond=lambda i, *_: i < self.n, body=body,
                label="light_select")
        by_uniform = uniform | (total <= 0)  # no light has importance: the uniform choice
        idx = dr.select(by_uniform, idx_u, idx)
        imp = dr.select(by_uniform, imp_u, imp_idx)
        u_re = dr.select(by_uniform, u_uni, u)
        if_active = active & (idx != NO_LIGHT)
        pmf = dr.select(if_active, self._pmf(imp, total), 0.0)
        return dr.select(if_active, idx, 0), pmf, dr.clip(u_re, 0.0, 0.99999994)

    def selection_pmf(self, it: mi.Interaction3f, idx: mi.UInt32, active: mi.Bool,
                      imps: list[mi.Float] | None = None) -> mi.Float:
        """Probability that :meth:`sample` chooses light ``idx`` in the shading context
        ``it``; ``imps``: :meth:`importances` there, when known."""
        if self.selection != "importance" or self.n == 1:  # one light: always chosen
            return dr.gather(mi.Float, self.pmf, idx, active)
        zero = dr.zeros(mi.Float, dr.width(it.p))
        if self.unrolled:
            total, imp = zero, zero
            for i, imp_i in enumerate(imps or self.importances(it, active)):
                total, imp = total + imp_i, dr.select(idx == i, imp_i, imp)
        else:
            n = _arrival_normal(it)

            def body(i, total, imp_idx):  # Σ imp and light idx's own, in one pass
                imp = self.importance(i, it.p, n, active)
                return i + 1, total + imp, dr.select(i == idx, imp, imp_idx)

            _, total, imp = dr.while_loop(state=(mi.UInt32(0), zero, zero),
                                          cond=lambda i, *_: i < self.n, body=body,
                                          label="light_pmf")
        return dr.select(active, self._pmf(imp, total), 0.0)

    # -- sampling -------------------------------------------------------------------------

    def _index(self, emitter: mi.EmitterPtr, active: mi.Bool) -> mi.UInt32:
        reg = dr.reinterpret_array(mi.UInt32, emitter)
        return dr.gather(mi.UInt32, self.index_of, reg, active)

    def _rect(self, idx: mi.UInt32, active: mi.Bool):
        return (dr.gather(mi.Point3f, self.s, idx, active),
                dr.gather(mi.Vector3f, self.ex, idx, active),
                dr.gather(mi.Vector3f, self.ey, idx, active))

    def _cosine_share(self, idx: mi.UInt32, n: mi.Vector3f, active: mi.Bool) -> mi.Float:
        """Share of an infinite emitter's samples drawn cosine-weighted about ``n``."""
        if self.selection != "importance":
            return dr.zeros(mi.Float, dr.width(n))
        inf = active & (dr.gather(mi.UInt32, self.kind, idx, active) == KIND_INFINITE) \
            & (dr.squared_norm(n) > 0)
        const = dr.gather(mi.Bool, self.constant, idx, active)
        return dr.select(inf, dr.select(const, 1.0, self.env_cosine), 0.0)

    def sample(self, it: mi.Interaction3f, u: mi.Point2f, active: mi.Bool,
               imps: list[mi.Float] | None = None
               ) -> tuple[mi.DirectionSample3f, mi.Spectrum]:
        """Like ``scene.sample_emitter_direction(it, u, False, active)``: a direction sample
        (``pdf`` in solid angle, selection included) and the weight ``L / pdf`` (no
        visibility test). ``it``: a surface interaction (its normal is turned towards
        ``wi``) or a context from :func:`light_context`; ``imps``: :meth:`importances` at
        ``it``, when already evaluated."""
        if self.n == 0:
            return dr.zeros(mi.DirectionSample3f), dr.zeros(mi.Spectrum)
        n = _arrival_normal(it)
        ctx = mi.Interaction3f(it)
        idx, pmf, ux = self._select(ctx, n, u.x, active, imps)
        active = active & (pmf > 0)
        emitter = dr.gather(mi.EmitterPtr, self.ptrs, idx, active)
        # environments: cosine-weighted about n with probability c, else their own sampling
        c = self._cosine_share(idx, n, active)
        cosine = active & (ux < c)
        ux = dr.select(cosine, ux / dr.maximum(c, 1e-30),
                       dr.select(c > 0, (ux - c) / dr.maximum(1.0 - c, 1e-30), ux))
        ux = dr.clip(ux, 0.0, 0.99999994)
        u2 = mi.Point2f(ux, u.y)
        rect = active & dr.gather(mi.Bool, self.is_rect, idx, active)
        s, ex, ey = self._rect(idx, rect)
        p, solid = spherical_rectangle(ctx.p, s, ex, ey, u2)
        rect &= solid >= self.min_solid_angle
        other = active & ~rect
        ds, w = emitter.sample_direction(ctx, u2, other)
        # the rectangle lanes: direction, emitter radiance, solid-angle pdf
        d = p - ctx.p
        dist = dr.norm(d)
        d = d / dist
        nl = dr.gather(mi.Vector3f, self.normal, idx, rect)
        si = dr.zeros(mi.SurfaceInteraction3f)
        si.p, si.t = p, dist
        si.n = nl
        si.sh_frame = mi.Frame3f(nl)
        si.wi = si.sh_frame.to_local(-d)
        le = emitter.eval(si, rect)
        ds_r = dr.zeros(mi.DirectionSample3f)
        ds_r.p, ds_r.n, ds_r.d, ds_r.dist = p, nl, d, dist
        ds_r.pdf = dr.select(solid > 0, 1.0 / solid, 0.0)
        ds_r.delta = mi.Bool(False)
        ds_r.emitter = emitter
        ds = dr.select(rect, ds_r, ds)
        w = dr.select(rect, le * solid, w)
        # the cosine lanes: a direction about n, the environment's radiance along it
        mixture = active & (c > 0)
        d_cos = mi.Frame3f(dr.normalize(dr.select(mixture, n, mi.Vector3f(0, 0, 1)))).to_world(
            mi.warp.square_to_cosine_hemisphere(u2))
        ds.d = dr.select(cosine, d_cos, ds.d)
        ds.p = dr.select(cosine, ctx.p + ds.d * ds.dist, ds.p)
        ds.n = dr.select(cosine, -ds.d, ds.n)
        si_e = dr.zeros(mi.SurfaceInteraction3f)
        si_e.wi = -ds.d
        le_env = emitter.eval(si_e, mixture)
        pdf_env = dr.select(c < 1.0, emitter.pdf_direction(ctx, ds, mixture), 0.0)
        pdf_mix = c * dr.maximum(dr.dot(ds.d, n), 0.0) * dr.inv_pi + (1.0 - c) * pdf_env
        ds.pdf = dr.select(mixture, pdf_mix, ds.pdf)
        w = dr.select(mixture, dr.select(pdf_mix > 0, le_env / pdf_mix, 0.0), w)
        ds.pdf = ds.pdf * pmf
        w = dr.select(pmf > 0, w / pmf, 0.0)
        return ds, dr.select(active, w, 0.0)

    def pdf(self, it: mi.Interaction3f, ds: mi.DirectionSample3f, active: mi.Bool,
            imps: list[mi.Float] | None = None) -> mi.Float:
        """Like ``scene.pdf_emitter_direction(it, ds, active)`` for this sampler, in the
        same context ``it`` that :meth:`sample` was given (``imps``: the
        :meth:`importances` it was given, if any)."""
        if self.n == 0:
            return dr.zeros(mi.Float)
        active = active & (dr.reinterpret_array(mi.UInt32, ds.emitter) != 0)
        idx = self._index(ds.emitter, active)
        n = _arrival_normal(it)
        ctx = mi.Interaction3f(it)
        pmf = self.selection_pmf(ctx, idx, active, imps)
        rect = active & dr.gather(mi.Bool, self.is_rect, idx, active)
        s, ex, ey = self._rect(idx, rect)
        solid = rectangle_solid_angle(ctx.p, s, ex, ey)
        rect &= solid >= self.min_solid_angle
        pdf_other = ds.emitter.pdf_direction(ctx, ds, active & ~rect)
        c = self._cosine_share(idx, n, active)
        pdf_other = dr.select(c > 0, c * dr.maximum(dr.dot(ds.d, n), 0.0) * dr.inv_pi
                              + (1.0 - c) * dr.select(c < 1.0, pdf_other, 0.0), pdf_other)
        pdf = dr.select(rect, dr.select(solid > 0, 1.0 / solid, 0.0), pdf_other)
        return dr.select(active, pdf * pmf, 0.0)


__all__ = ["Bounds", "ENV_COSINE", "LightSampler", "LightTable", "MAX_UNROLLED",
           "MIN_SOLID_ANGLE", "SELECTIONS", "UNIFORM_MIX", "bounds_importance",
           "emitter_power", "environment_moments", "light_context", "rectangle_solid_angle",
           "spherical_rectangle"]
