"""Next-event light sampling: emitters chosen by estimated power, rectangles by solid angle.

Replaces Mitsuba's ``Scene.sample_emitter_direction`` / ``pdf_emitter_direction`` pair for a
path tracer (the two must agree for MIS):

* **Selection by power** (pbrt-v4's ``PowerLightSampler``): emitter ``i`` is chosen with
  probability ∝ its estimated power Φ_i (luminance): one-sided area light ``π A L``, sphere
  ``4π² r² L``, point ``4π I``, spot ``2π (1 − cos θ) I`` (θ the mean of cutoff and beam
  width), directional ``π R² E`` and constant / environment ``4π² R² L̄`` with ``R`` the
  scene's bounding radius and ``L̄`` the map's solid-angle mean; Mitsuba picks uniformly.
* **Spherical rectangles** (Ureña, Fajardo & King, *An Area-Preserving Parametrization for
  Spherical Rectangles*, EGSR 2013, Alg. 1): a rectangular area light (``rectangle`` shape
  with an ``area`` emitter and orthogonal edges) is sampled uniformly in the solid angle it
  subtends, pdf ``1/S``, instead of uniformly in area (pdf ``d²/(A cos θ_l)``, which varies
  wildly across a large light close to the shading point). Where the solid angle is tiny
  (``S < min_solid_angle``: the float32 angle sum ``S = Σγ_i − 2π`` loses precision) the
  emitter's own area sampling is used; the choice depends only on the reference point and
  the light, so sampling and pdf agree.
* Other emitters (spheres — Mitsuba samples their cone already —, point, spot, directional,
  constant, envmap with its importance sampling) use the emitter's ``sample_direction`` /
  ``pdf_direction``.
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

MIN_SOLID_ANGLE = 1e-2
"""Solid angle (sr) below which a rectangle falls back to area sampling (see module doc)."""


def _lum(rgb) -> float:
    c = np.asarray(rgb, np.float64).reshape(-1)
    if c.size == 1:
        return float(c[0])
    return float(0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2])


def _value(params: mi.SceneParameters, key: str):
    return np.array(params[key], dtype=np.float64) if key in params else None


def emitter_power(emitter: mi.Emitter, shape: mi.Shape | None, radius: float) -> float:
    """Estimated power (luminance, W) of one emitter (see the module docstring)."""
    name = emitter.class_name()
    p = mi.traverse(emitter)
    if name == "AreaLight" and shape is not None:
        lum = _lum(_value(p, "radiance.value")) if "radiance.value" in p else 1.0
        area = float(dr.sum(shape.surface_area())[0]) if hasattr(shape, "surface_area") else 1.0
        return math.pi * area * lum
    if name == "PointLight":
        return 4 * math.pi * _lum(_value(p, "intensity.value"))
    if name == "SpotLight":
        inten = _lum(_value(p, "intensity.value"))
        text = str(emitter)
        cut = _parse(text, "cutoff_angle", 20.0)
        beam = _parse(text, "beam_width", cut * 0.75)
        return 2 * math.pi * (1 - math.cos(math.radians(0.5 * (cut + beam)))) * inten
    if name == "DirectionalEmitter":
        return math.pi * radius**2 * _lum(_value(p, "irradiance.value"))
    if name == "ConstantBackgroundEmitter":
        return 4 * math.pi**2 * radius**2 * _lum(_value(p, "radiance.value"))
    if name == "EnvironmentMapEmitter":
        data = np.array(p["data"], dtype=np.float64) if "data" in p else None
        scale = float(np.array(p["scale"]).reshape(-1)[0]) if "scale" in p else 1.0
        if data is None:
            return 4 * math.pi**2 * radius**2
        h = data.shape[0]
        sin_t = np.sin((np.arange(h) + 0.5) / h * math.pi)[:, None]
        rgb = data[..., :3] if data.ndim == 3 else data[..., None]
        mean = (rgb * sin_t[..., None]).sum(axis=(0, 1)) / (sin_t.sum() * data.shape[1])
        return 4 * math.pi**2 * radius**2 * scale * _lum(mean)
    return 1.0  # unknown emitter: a neutral weight (still unbiased)


def _parse(text: str, key: str, default: float) -> float:
    for line in text.splitlines():
        if key in line and "=" in line:
            try:
                return float(line.split("=")[1].strip().rstrip(","))
            except ValueError:
                return default
    return default


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


class LightSampler:
    """Emitter selection by power and solid-angle sampling of rectangles for one scene.

    Args:
        scene: the Mitsuba scene whose emitters are sampled.
        solid_angle: sample rectangular area lights by solid angle (False: by area, as
            Mitsuba).
        by_power: choose emitters by estimated power (False: uniformly, as Mitsuba).
        pmf: selection probabilities to use instead (e.g. another view's, for identical
            sampling of the same lights; ignored when the emitter count differs).
    """

    def __init__(self, scene: mi.Scene, solid_angle: bool = True, by_power: bool = True,
                 min_solid_angle: float = MIN_SOLID_ANGLE, pmf: np.ndarray | None = None):
        self.scene = scene
        self.min_solid_angle = float(min_solid_angle)
        emitters = list(scene.emitters())
        self.n = len(emitters)
        self.ptrs = scene.emitters_dr()
        ids = np.array(dr.reinterpret_array(mi.UInt32, self.ptrs), dtype=np.int64)
        shapes = {}
        for sh in scene.shapes():
            if sh.is_emitter():
                shapes[int(np.array(dr.reinterpret_array(mi.UInt32,
                                                         mi.EmitterPtr(sh.emitter())))[0])] = sh
        bbox = scene.bbox()
        radius = float(dr.norm(bbox.max - bbox.min)) / 2 if bbox.valid() else 1.0
        power = np.ones(self.n)
        rect = np.zeros(self.n, bool)
        s = np.zeros((self.n, 3))
        ex = np.zeros((self.n, 3))
        ey = np.zeros((self.n, 3))
        normal = np.zeros((self.n, 3))
        for i, (em, reg) in enumerate(zip(emitters, ids, strict=True)):
            sh = shapes.get(int(reg))
            power[i] = max(emitter_power(em, sh, max(radius, 1e-3)), 0.0)
            if solid_angle and sh is not None and sh.class_name() == "Rectangle":
                m = np.array(mi.traverse(sh)["to_world"].matrix, dtype=np.float64)
                m = m.reshape(4, 4) if m.size == 16 else m[..., 0]
                a, b = m[:3, 0] * 2.0, m[:3, 1] * 2.0
                if abs(a @ b) <= 1e-4 * np.linalg.norm(a) * np.linalg.norm(b):
                    rect[i] = True
                    s[i] = m[:3, 3] - m[:3, 0] - m[:3, 1]
                    ex[i], ey[i] = a, b
                    nrm = np.linalg.inv(m[:3, :3]).T @ np.array([0.0, 0.0, 1.0])
                    normal[i] = nrm / np.linalg.norm(nrm)  # Mitsuba's emitting side
        if not by_power or not np.any(power > 0):
            power = np.ones(self.n)
        power = np.where(power > 0, power, 0.0)
        if pmf is not None and len(pmf) == self.n:
            power = np.asarray(pmf, np.float64)
        self.pmf_np = power / power.sum() if self.n else power
        self.rect_np = rect
        self.distr = mi.DiscreteDistribution(mi.Float(self.pmf_np.astype(np.float32))) \
            if self.n else None
        self.pmf = mi.Float(self.pmf_np.astype(np.float32))
        self.is_rect = mi.Bool(rect)
        self.s = mi.Point3f(*(s[:, c].astype(np.float32) for c in range(3)))
        self.ex = mi.Vector3f(*(ex[:, c].astype(np.float32) for c in range(3)))
        self.ey = mi.Vector3f(*(ey[:, c].astype(np.float32) for c in range(3)))
        self.normal = mi.Vector3f(*(normal[:, c].astype(np.float32) for c in range(3)))
        size = int(ids.max()) + 1 if self.n else 1
        table = np.zeros(size, np.uint32)
        table[ids] = np.arange(self.n, dtype=np.uint32)
        self.index_of = mi.UInt32(table)

    def _index(self, emitter: mi.EmitterPtr, active: mi.Bool) -> mi.UInt32:
        reg = dr.reinterpret_array(mi.UInt32, emitter)
        return dr.gather(mi.UInt32, self.index_of, reg, active)

    def _rect(self, idx: mi.UInt32, active: mi.Bool):
        return (dr.gather(mi.Point3f, self.s, idx, active),
                dr.gather(mi.Vector3f, self.ex, idx, active),
                dr.gather(mi.Vector3f, self.ey, idx, active))

    def sample(self, it: mi.Interaction3f, u: mi.Point2f, active: mi.Bool
               ) -> tuple[mi.DirectionSample3f, mi.Spectrum]:
        """Like ``scene.sample_emitter_direction(it, u, False, active)``: a direction sample
        (``pdf`` in solid angle, selection included) and the weight ``L / pdf`` (no
        visibility test)."""
        if self.n == 0:
            return dr.zeros(mi.DirectionSample3f), dr.zeros(mi.Spectrum)
        idx, ux, pmf = self.distr.sample_reuse_pmf(u.x, active)
        u2 = mi.Point2f(ux, u.y)
        emitter = dr.gather(mi.EmitterPtr, self.ptrs, idx, active)
        rect = active & dr.gather(mi.Bool, self.is_rect, idx, active)
        s, ex, ey = self._rect(idx, rect)
        p, solid = spherical_rectangle(it.p, s, ex, ey, u2)
        rect &= solid >= self.min_solid_angle
        other = active & ~rect
        ds, w = emitter.sample_direction(it, u2, other)
        # the rectangle lanes: direction, emitter radiance, solid-angle pdf
        d = p - it.p
        dist = dr.norm(d)
        d = d / dist
        n = dr.gather(mi.Vector3f, self.normal, idx, rect)
        si = dr.zeros(mi.SurfaceInteraction3f)
        si.p, si.t = p, dist
        si.n = n
        si.sh_frame = mi.Frame3f(n)
        si.wi = si.sh_frame.to_local(-d)
        le = emitter.eval(si, rect)
        ds_r = dr.zeros(mi.DirectionSample3f)
        ds_r.p, ds_r.n, ds_r.d, ds_r.dist = p, n, d, dist
        ds_r.pdf = dr.select(solid > 0, 1.0 / solid, 0.0)
        ds_r.delta = mi.Bool(False)
        ds_r.emitter = emitter
        ds = dr.select(rect, ds_r, ds)
        w = dr.select(rect, le * solid, w)
        ds.pdf = ds.pdf * pmf
        w = dr.select(pmf > 0, w / pmf, 0.0)
        return ds, dr.select(active, w, 0.0)

    def pdf(self, it: mi.Interaction3f, ds: mi.DirectionSample3f, active: mi.Bool
            ) -> mi.Float:
        """Like ``scene.pdf_emitter_direction(it, ds, active)`` for this sampler."""
        if self.n == 0:
            return dr.zeros(mi.Float)
        active = active & (dr.reinterpret_array(mi.UInt32, ds.emitter) != 0)
        idx = self._index(ds.emitter, active)
        pmf = dr.gather(mi.Float, self.pmf, idx, active)
        rect = active & dr.gather(mi.Bool, self.is_rect, idx, active)
        s, ex, ey = self._rect(idx, rect)
        solid = rectangle_solid_angle(it.p, s, ex, ey)
        rect &= solid >= self.min_solid_angle
        pdf_other = ds.emitter.pdf_direction(it, ds, active & ~rect)
        pdf = dr.select(rect, dr.select(solid > 0, 1.0 / solid, 0.0), pdf_other)
        return dr.select(active, pdf * pmf, 0.0)


__all__ = ["LightSampler", "MIN_SOLID_ANGLE", "emitter_power", "rectangle_solid_angle",
           "spherical_rectangle"]
