"""AR Object Occlusion Fields (Franke thesis §5.2, [FKOJ11]; after Zhou et al. 2005's object
occlusion fields) and the real-surface relighting that the ``ibl`` and ``prt`` methods share
(:func:`shade_real`; their whole frame: :func:`render_layers`).

**Precomputation** (:func:`build_field`). Around the virtual object (centre ``c``, bounding
radius ``R``) lie ``shells`` concentric spheres of radii ``r_s = r_min · g^s`` from
``r_min = inner · R`` to ``r_max = outer · R`` (geometric spacing: the occlusion of a compact
object falls off like ``1/r²``). Each shell is sampled on a ``rows × cols`` latitude-longitude
grid (poles included, the column ``cols`` repeats column 0 so that the interpolation wraps).
At every sample ``q`` the *binary occlusion function* of the object, ``O_q(ω) = 1`` where a ray
from ``q`` along ``ω`` hits the object, is projected onto real SH up to ``order``
(Franke Eq. 4.8: ``O_j = ∫ O Φ_j dω``) with a product quadrature and one batched
``ray_test`` against a scene that holds the virtual shapes alone.

**Lookup** (:meth:`OcclusionField.occluded_irradiance`, thesis §5.2 runtime steps 1–6). Per
real pixel: radius test; trilinear interpolation of ``O`` (shell, latitude, longitude); the
real surface's diffuse transfer ``T_k(n) = Â_l y_k(n)`` (clamped cosine, Eqs. 5.10–5.11 with
``f = ρ/π`` left out: the ratio below cancels it) taken from a cache indexed by the (quantised)
normal; the triple product (Eqs. 5.1–5.8) ``(O·T)_i = Σ_jk C_ijk O_j T_k`` and the double
product with the light (Eq. 5.9) ``E_occ = Σ_i L_i (O·T)_i``: the irradiance the object takes
away. We fold the light into the tensor once per frame, ``M_jk = Σ_i C_ijk L_i``, so a pixel
costs ``Σ_j O_j (T(n)·M)_j``; normals are deduplicated first (planar proxies have a handful).

**Relighting** (:func:`shadow_factor`): the real pixel is multiplied by

    f = (E_dir,mixed + E_amb − E_occ) / (E_dir,real + E_amb),   clipped to [0, 1],

with ``E_dir`` the reduced lights' irradiance behind shadow rays in the mixed and the real
view and ``E_amb`` the SH ambient remainder's irradiance. ``delta = B · (f − 1)``: a
multiplicative darkening of the camera frame, as in the thesis ("a per-pixel shadow
attenuation factor multiplied into the background color"); it cannot brighten.

Units: positions and radii metres; SH coefficients of radiance in W/(sr·m²); irradiance W/m².
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from types import SimpleNamespace
from typing import Any, Protocol, TypeAlias

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.mitsuba_scene import (
    ROLE_VIRTUAL,
    SceneView,
    SceneViews,
    describe_geometry,
    describe_shape,
    geometry_params,
    load_scene,
    load_view,
)
from arlight.backend.rays import np3
from arlight.jit import aligned, columns
from arlight.layers import Layers
from arlight.realtime.gbuffer import GBuffer, assemble, render_gbuffer
from arlight.realtime.light_reduction import LightSet
from arlight.realtime.shading import ambient_irradiance_dr, direct_irradiance, on_active
from arlight.scene.model import FrameView, World
from arlight.scene.schema import Field
from arlight.sphere.points import fibonacci_sphere
from arlight.sphere.sh import (
    band_of_each_coeff,
    clamped_cosine_band,
    n_coeffs,
    rotate,
    sh_basis,
    triple_product_tensor,
)

RAY_CHUNK = 1 << 21
"""Rays per batched ``ray_test`` call in the precomputations."""


def virtual_scene(world: World) -> mi.Scene | None:
    """A Mitsuba scene of the world's virtual shapes alone (None without any): the occluder
    of the occlusion field and of the virtual objects' ambient occlusion. Loaded as the
    methods' views are (:func:`~arlight.backend.mitsuba_scene.load_view`), so that
    :func:`move_virtual_scene` moves its shapes bitwise to where a new one would load them."""
    objects = {str(i): describe_shape(s) for i, s in enumerate(world.shapes) if s.is_virtual}
    if not objects:
        return None
    return load_view({"objects": objects}, dict.fromkeys(objects, ROLE_VIRTUAL)).scene


class PosedOccluder:
    """The virtual occluder of a world with one virtual shape under a similarity transform
    (:func:`object_frame`): that shape loaded at the identity pose, tested by rays taken
    into its frame. Moving the object swaps the frame (:meth:`posed`); no Mitsuba scene is
    updated. Duck-types the ``ray_test`` of ``mi.Scene`` that the occluder's users call.

    Attributes:
        scene: the shape alone at the identity pose.
        frame: world from object, 4×4 (m).
    """

    def __init__(self, scene: mi.Scene, frame: np.ndarray) -> None:
        self.scene = scene
        self.frame = np.asarray(frame, np.float64)
        inv = np.linalg.inv(self.frame)
        self._inv = [[dr.opaque(mi.Float, float(inv[r, c])) for c in range(4)]
                     for r in range(3)]  # opaque: one kernel for every pose

    def posed(self, frame: np.ndarray) -> PosedOccluder:
        """The same object in another pose (nothing loaded or rebuilt)."""
        return PosedOccluder(self.scene, frame)

    def _local(self, ray: mi.Ray3f) -> mi.Ray3f:
        """``ray`` in the object's frame: origin and direction taken through the inverse
        pose, the direction not renormalised, so the parameter ``t`` and ``maxt`` keep their
        meaning."""
        m = self._inv
        o = mi.Point3f(*[m[r][0] * ray.o.x + m[r][1] * ray.o.y + m[r][2] * ray.o.z + m[r][3]
                         for r in range(3)])
        d = mi.Vector3f(*[m[r][0] * ray.d.x + m[r][1] * ray.d.y + m[r][2] * ray.d.z
                          for r in range(3)])
        local = mi.Ray3f(o, d)
        local.maxt = ray.maxt
        return local

    def ray_test(self, ray: mi.Ray3f, active: mi.Bool | bool = True) -> mi.Bool:
        """Whether each ray hits the object before ``ray.maxt`` (:meth:`_local`)."""
        return self.scene.ray_test(self._local(ray), active)

    def ray_intersect_preliminary(self, ray: mi.Ray3f, active: mi.Bool | bool = True
                                  ) -> mi.PreliminaryIntersection3f:
        """The first hit of each ray (:meth:`_local`): ``t`` is the world ray's parameter
        (the nearfield client's shadow maps, issue #32); the primitive fields are the
        object-space scene's."""
        return self.scene.ray_intersect_preliminary(self._local(ray), active=active)

    def bounding_sphere(self) -> tuple[np.ndarray, float]:
        """A sphere around the posed object (centre m, radius m): the object-space bounding
        box's circumsphere taken through the pose (a similarity: radius × its scale), so it
        does not grow as the object turns."""
        c, r = _bounding_sphere(self.scene)
        scale = float(np.cbrt(abs(np.linalg.det(self.frame[:3, :3]))))
        return self.frame[:3, :3] @ c + self.frame[:3, 3], r * scale


Occluder: TypeAlias = "mi.Scene | PosedOccluder"
"""What tests rays against the virtual shapes alone: a world-space scene
(:func:`virtual_scene`) or an object-space one looked up through the pose."""


def _object_scene(world: World) -> mi.Scene:
    """The one virtual shape of ``world`` alone, at the identity pose."""
    shape = replace(world.virtual_shapes[0], to_world=np.eye(4))
    return load_scene({"objects": {"0": describe_shape(shape)}})


def make_occluder(world: World) -> Occluder | None:
    """The virtual occluder of ``world`` (None without virtual shapes): object-space
    (:class:`PosedOccluder`) when :func:`object_frame` has a frame, else
    :func:`virtual_scene`."""
    frame = object_frame(world)
    if frame is not None:
        return PosedOccluder(_object_scene(world), frame)
    return virtual_scene(world)


def move_occluder(occluder: Occluder | None, before: World, after: World
                  ) -> tuple[bool, Occluder | None]:
    """The occluder of ``before`` for ``after`` (the same world posed otherwise; incremental
    pose, issue #32): an object-space one re-posed, a world-space one with its shapes moved
    in place. ``(False, None)`` when the kind would change (the new pose is no similarity):
    prepare again."""
    if occluder is None:
        return True, None
    frame = object_frame(after)
    if isinstance(occluder, PosedOccluder):
        return (True, occluder.posed(frame)) if frame is not None else (False, None)
    if frame is not None:
        return False, None
    move_virtual_scene(occluder, before, after)
    return True, occluder


def move_virtual_scene(scene: mi.Scene, before: World, after: World) -> None:
    """Move the shapes of a :func:`virtual_scene` of ``before`` in place to where they are
    in ``after`` (the same world posed otherwise): bitwise where ``virtual_scene(after)``
    loads them; one acceleration-structure rebuild, none when nothing moved."""
    moved = {str(i): geometry_params(describe_geometry(b)) for i, (a, b) in
             enumerate(zip(before.shapes, after.shapes, strict=True))
             if b.is_virtual and not np.array_equal(a.to_world, b.to_world)}
    if moved:
        SceneView(scene, mi.Int32(0), mi.Int32(0)).set_geometry(moved)


def occlusion_rays(scene: mi.Scene, origins: np.ndarray, dirs: np.ndarray,
                   chunk: int = RAY_CHUNK, progress=None) -> np.ndarray:
    """Binary occlusion ``(P, K)`` (1.0: the ray from ``origins[p]`` along ``dirs[k]`` hits
    ``scene``), all ``P × K`` rays in batched ``ray_test`` calls of about ``chunk`` rays.
    ``progress(done, total)`` is called after each batch."""
    o = np.asarray(origins, np.float32)
    d = np.asarray(dirs, np.float32)
    P, K = len(o), len(d)
    out = np.empty((P, K), np.float32)
    per = max(1, chunk // max(K, 1))
    for p0 in range(0, P, per):
        oc = np.repeat(o[p0:p0 + per], K, axis=0)
        dc = np.tile(d, (len(oc) // K, 1))
        ray = mi.Ray3f(mi.Point3f(oc[:, 0], oc[:, 1], oc[:, 2]),
                       mi.Vector3f(dc[:, 0], dc[:, 1], dc[:, 2]))
        hit = scene.ray_test(ray)
        out[p0:p0 + per] = np.asarray(hit, np.float32).reshape(-1, K)
        if progress is not None:
            progress(min(p0 + per, P), P)
    return out


def cosine_transfer(normals: np.ndarray, order: int) -> np.ndarray:
    """SH of the clamped cosine about each unit normal, ``T_k(n) = Â_l y_k(n)`` ``(N, n)``
    (Ramamoorthi & Hanrahan 2001 Eq. 8–9; Franke Eq. 5.11 without ``ρ/π``)."""
    a = np.array([clamped_cosine_band(int(l)) for l in band_of_each_coeff(order)])
    return sh_basis(np.asarray(normals, np.float64), order) * a


@dataclass
class OcclusionField:
    """SH occlusion of the environment by a rigid object, sampled on concentric shells.

    Attributes:
        centre: world centre of the shells (m) ``(3,)``.
        radii: shell radii (m) ``(S,)``, geometric.
        coeffs: ``(S, rows, cols + 1, n)`` float32 occlusion SH per sample (column ``cols``
            repeats column 0).
        order: SH order of ``coeffs``.
    """

    centre: np.ndarray
    radii: np.ndarray
    coeffs: np.ndarray
    order: int
    frame: np.ndarray | None = None
    """World from field frame, 4×4 (a rotation, a uniform scale and a translation): the
    field was sampled in the object's own space (AR-OOF, Franke §5.2: precomputed once per
    object, looked up through its pose) and ``centre``, ``radii`` are in that space; None:
    sampled in world space."""

    @property
    def r_max(self) -> float:
        """Outermost shell radius in the field's frame."""
        return float(self.radii[-1])

    @property
    def world_centre(self) -> np.ndarray:
        """Centre of the shells in world space, m."""
        if self.frame is None:
            return np.asarray(self.centre, np.float64)
        return self.frame[:3, :3] @ self.centre + self.frame[:3, 3]

    @property
    def world_r_max(self) -> float:
        """Outermost shell radius in world space, m."""
        return self.r_max * (1.0 if self.frame is None else similarity(self.frame)[0])

    def __post_init__(self) -> None:
        self._flat = mi.Float(np.ascontiguousarray(self.coeffs, np.float32).reshape(-1))
        self._cache: dict = {}  # per-light tables (the light is usually static across frames)

    def posed(self, frame: np.ndarray) -> OcclusionField:
        """This object-space field looked up through another pose ``frame`` (world from
        object, 4×4 similarity): the samples and their upload are shared, nothing is
        traced again."""
        out = copy.copy(self)
        out.frame = np.asarray(frame, np.float64)
        out._cache = {}
        return out

    def _to_field(self, light_sh: np.ndarray, p: mi.Point3f, n: mi.Vector3f
                  ) -> tuple[np.ndarray, mi.Point3f, mi.Vector3f]:
        """Light SH, points and normals in the field's frame: ``p`` through the inverse
        pose, ``n`` and the light through its rotation (opaque values: one kernel for every
        pose)."""
        if self.frame is None:
            return light_sh, p, n
        scale, rot = similarity(self.frame)
        inv = np.linalg.inv(self.frame)
        m = [[dr.opaque(mi.Float, float(inv[r, c])) for c in range(4)] for r in range(3)]
        q = mi.Point3f(*[m[r][0] * p.x + m[r][1] * p.y + m[r][2] * p.z + m[r][3]
                         for r in range(3)])
        rt = [[dr.opaque(mi.Float, float(rot[c, r])) for c in range(3)] for r in range(3)]
        v = mi.Vector3f(*[rt[r][0] * n.x + rt[r][1] * n.y + rt[r][2] * n.z for r in range(3)])
        light = rotate(np.asarray(light_sh, np.float64), rot.T)
        return light, q, dr.normalize(v)

    def light_table(self, light_sh: np.ndarray, order: int,
                    nodes: np.ndarray | None = None) -> np.ndarray:
        """Per frame: the light folded into the triple-product tensor and the real surface's
        clamped-cosine transfer, tabulated over normals (thesis §5.2 step 4, "a cache of
        diffuse transfer vectors … indexed by sampled normal directions"): row ``b`` holds
        ``W_jc(n_b) = Σ_k T_k(n_b) Σ_i C_ijk L_ic`` ``(k, 3)`` for the normal ``n_b`` of node
        ``b`` of an octahedral grid of ``NORMAL_GRID²`` nodes (:func:`octahedral_normals`)
        → ``(NORMAL_GRID², k, 3)``; with ``nodes``, the rows of those nodes only."""
        k = n_coeffs(order)
        light = np.zeros((k, 3))
        m = min(k, np.asarray(light_sh).shape[0])
        light[:m] = np.asarray(light_sh, np.float64)[:m]
        m_jkc = np.einsum("ijk,ic->jkc", _tensor(order), light)
        t = _normal_transfer(order)  # (B, k)
        if nodes is not None:
            t = t[nodes]
        # einsum, not ``@``: no BLAS, whose thread pool takes ~15 ms to wake on a loaded
        # machine for this ~1 ms product (once per moving frame: the light rotates); in the
        # two-operand matrix form, which einsum runs ~10x faster than "bk,jkc->bjc"
        m_kx = np.ascontiguousarray(m_jkc.transpose(1, 0, 2).reshape(k, -1))
        return np.einsum("bk,kx->bx", t, m_kx).reshape(len(t), k, 3)

    def occluded_irradiance(self, light_sh: np.ndarray, p: mi.Point3f, n: mi.Vector3f,
                            order: int | None = None) -> mi.Color3f:
        """Irradiance (W/m²) that the object blocks at points ``p`` with unit normals ``n``
        under radiance SH ``light_sh`` (Franke Eqs. 5.8–5.9); 0 outside the outermost shell,
        faded out linearly over the outer quarter of the radius (no visible edge).

        One Dr.Jit kernel: radius test, trilinear interpolation (shell, latitude,
        longitude) of the occlusion SH dotted with the normal's row of :meth:`light_table`.
        When the lanes' normals fall in at most ``FEW_NORMALS`` nodes of the normal grid (the
        planes of a real proxy) the dot products are taken once per shell sample and node
        and the lanes interpolate RGB (the same sum in another order, 8 gathers a lane
        instead of ``8·(L+1)²``).

        Raises:
            ValueError: ``order`` above the field's precomputed order.
        """
        order = self.order if order is None else int(order)
        if order > self.order:
            raise ValueError(f"SH order {order} requested, but the occlusion field was "
                             f"precomputed to order {self.order}; rebuild it with "
                             f"order >= {order}")
        light_sh, p, n = self._to_field(light_sh, p, n)
        k, kf = n_coeffs(order), self.coeffs.shape[3]
        S, H, W1, _ = self.coeffs.shape
        rel = p - mi.Point3f(*[float(x) for x in self.centre])
        r = dr.maximum(dr.norm(rel), 1e-12)
        inside = r < self.r_max
        fade = dr.clip((self.r_max - r) / (0.25 * self.r_max), 0.0, 1.0)
        g = math.log(self.radii[1] / self.radii[0])
        fs = dr.clip(dr.log(dr.maximum(r, float(self.radii[0])) / float(self.radii[0])) / g,
                     0.0, S - 1.0)
        fi = dr.acos(dr.clip(rel.y / r, -1.0, 1.0)) * ((H - 1) / math.pi)
        ph = dr.atan2(rel.x, -rel.z) * (0.5 / math.pi)
        fj = (ph - dr.floor(ph)) * (W1 - 1.0)
        axes = []
        for f, top in ((fs, S - 1), (fi, H - 1), (fj, W1 - 1)):
            i0 = dr.minimum(mi.UInt32(dr.floor(f)), max(top - 1, 0))
            axes.append((i0, dr.minimum(i0 + 1, top), f - mi.Float(i0)))
        (s0, s1, ts), (i0, i1, ti), (j0, j1, tj) = axes
        corners = []  # (sample index, weight) of the 8 corners
        for s_, ws in ((s0, 1.0 - ts), (s1, ts)):
            for i_, wi in ((i0, 1.0 - ti), (i1, ti)):
                for j_, wj in ((j0, 1.0 - tj), (j1, tj)):
                    corners.append(((s_ * H + i_) * W1 + j_, ws * wi * wj))
        node = octahedral_index(n, NORMAL_GRID)
        dr.eval(node)
        used = np.flatnonzero(np.bincount(np.asarray(node, np.int64),
                                          minlength=NORMAL_GRID ** 2))
        key = (np.asarray(light_sh, np.float64).tobytes(), order)
        if self._cache.get("key") != key or not np.array_equal(self._cache["used"], used):
            # the light (a moving object's rotates) or the normals changed: new tables, for
            # the normal-grid nodes the lanes use only
            table = self.light_table(light_sh, order, used)  # (U, k, 3)
            slot = np.zeros(NORMAL_GRID ** 2, np.uint32)
            slot[used] = np.arange(len(used))
            self._cache = {"key": key, "used": used, "slot": mi.UInt32(slot)}
            rows = mi.Float(aligned(table.reshape(-1), np.float32))
            if len(used) <= FEW_NORMALS:
                self._cache.update(per=self._per_node(rows, len(used), k), q=S * H * W1)
            else:
                self._cache["rows"] = rows
        c = self._cache
        slot = dr.gather(mi.UInt32, c["slot"], node)
        out = mi.Color3f(0.0)
        if len(used) <= FEW_NORMALS:
            base = slot * c["q"]
            for q, w in corners:
                out += w * dr.gather(mi.Color3f, c["per"], base + q, inside)
        else:
            for j in range(k):
                o = mi.Float(0.0)
                for q, w in corners:
                    o += w * dr.gather(mi.Float, self._flat, q * kf + j, inside)
                out += o * dr.gather(mi.Color3f, c["rows"], slot * k + j, inside)
        return dr.select(inside, out * fade, mi.Color3f(0.0))

    def _per_node(self, rows: mi.Float, nodes: int, k: int) -> mi.Float:
        """Blocked irradiance per shell sample and normal node, ``P_qbc = Σ_j O_qj W_jc(n_b)``
        (Franke Eq. 5.9 with the light folded in, :meth:`light_table`) from the table
        ``rows`` ``(nodes, k, 3)`` flattened → evaluated ``(nodes, Q, 3)`` flattened, ``Q``
        the samples of :attr:`coeffs` (RGB W/m² per unit occlusion weight).

        One Dr.Jit kernel over the ``nodes·Q·3`` entries (``k`` products each) instead of a
        NumPy ``@``: that is a BLAS call whose threads wake late on a loaded machine (~15 ms
        for ~2 ms of work), and it runs on every frame the object moves (its light rotates).
        """
        kf = self.coeffs.shape[3]
        q_count = int(np.prod(self.coeffs.shape[:3]))
        i = dr.arange(mi.UInt32, nodes * q_count * 3)
        c = i % 3
        q = (i // 3) % q_count
        b = i // (3 * q_count)
        out = mi.Float(0.0)
        for j in range(k):
            out += (dr.gather(mi.Float, self._flat, q * kf + j)
                    * dr.gather(mi.Float, rows, (b * k + j) * 3 + c))
        dr.eval(out)
        return out

    def occluded_irradiance_np(self, light_sh: np.ndarray, p: np.ndarray, n: np.ndarray,
                               order: int | None = None) -> np.ndarray:
        """:meth:`occluded_irradiance` for NumPy points and normals ``(N, 3)`` → ``(N, 3)``."""
        e = self.occluded_irradiance(light_sh, mi.Point3f(*columns(p, np.float32)),
                                     mi.Vector3f(*columns(n, np.float32)), order)
        return np3(e)


FEW_NORMALS = 16
"""Most normal-grid nodes for which :meth:`OcclusionField.occluded_irradiance` tabulates the
field per node instead of per lane."""
NORMAL_GRID = 65
"""Nodes per side of the octahedral normal grid of :meth:`OcclusionField.light_table` (odd,
so that the axis directions are nodes)."""


def octahedral_normals(grid: int) -> np.ndarray:
    """Unit normals ``(grid², 3)`` of the nodes of an octahedral map (+Y hemisphere in the
    inner diamond; node ``(a, b)`` at ``u = −1 + 2a/(grid−1)``, ``v = −1 + 2b/(grid−1)``, row
    ``b·grid + a``)."""
    t = np.linspace(-1.0, 1.0, grid)
    u, v = np.meshgrid(t, t)
    u, v = u.ravel(), v.ravel()
    y = 1.0 - np.abs(u) - np.abs(v)
    x = np.where(y >= 0, u, (1.0 - np.abs(v)) * np.sign(u))
    z = np.where(y >= 0, v, (1.0 - np.abs(u)) * np.sign(v))
    d = np.stack([x, y, z], 1)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def octahedral_index(n: mi.Vector3f, grid: int) -> mi.UInt32:
    """Row of :func:`octahedral_normals` nearest to each unit normal ``n``."""
    s = dr.abs(n.x) + dr.abs(n.y) + dr.abs(n.z)
    px, pz = n.x / s, n.z / s
    lower = n.y < 0.0
    u = dr.select(lower, (1.0 - dr.abs(pz)) * dr.sign(px), px)
    v = dr.select(lower, (1.0 - dr.abs(px)) * dr.sign(pz), pz)
    h = 0.5 * (grid - 1)
    a = mi.UInt32(dr.clip(dr.round((u + 1.0) * h), 0, grid - 1))
    b = mi.UInt32(dr.clip(dr.round((v + 1.0) * h), 0, grid - 1))
    return b * grid + a


_TENSORS: dict[int, np.ndarray] = {}
_NORMAL_TRANSFERS: dict[int, np.ndarray] = {}


def _normal_transfer(order: int) -> np.ndarray:
    """:func:`cosine_transfer` of the normal grid's nodes ``(NORMAL_GRID², k)``, computed
    once per order (a moving object's field rotates its light every frame, so
    :meth:`OcclusionField.light_table` runs per frame)."""
    if order not in _NORMAL_TRANSFERS:
        _NORMAL_TRANSFERS[order] = cosine_transfer(octahedral_normals(NORMAL_GRID), order)
    return _NORMAL_TRANSFERS[order]


def _tensor(order: int) -> np.ndarray:
    if order not in _TENSORS:
        _TENSORS[order] = triple_product_tensor(order)
    return _TENSORS[order]


def shell_samples(centre: np.ndarray, radii: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """World sample positions ``(S, rows, cols, 3)`` of the shells (latitude rows from the
    +Y pole to the −Y pole, both included; longitudes ``φ = 2π j/cols`` in the angles of
    ``docs/conventions.md``)."""
    theta = np.linspace(0.0, np.pi, rows)
    phi = np.arange(cols) * (2 * np.pi / cols)
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    d = np.stack([st * np.sin(phi), np.broadcast_to(ct, (rows, cols)), -st * np.cos(phi)], -1)
    return centre + radii[:, None, None, None] * d[None]


def build_field(scene: mi.Scene, centre: np.ndarray, radius: float, order: int = 4,
                shells: int = 24, rows: int = 17, cols: int = 32, inner: float = 0.25,
                outer: float = 8.0, directions: int = 1024, progress=None) -> OcclusionField:
    """Precompute the occlusion field of the shapes in ``scene`` (see the module docstring).

    Args:
        centre, radius: bounding sphere of the object (m).
        order: SH order of the stored occlusion (``(order+1)²`` coefficients).
        shells, rows, cols: sample layout.
        inner, outer: first and last shell radius in units of ``radius``.
        directions: rays per sample, on a Fibonacci sphere with equal weights ``4π/K`` (a
            product quadrature lines its rings up with the edges of occluders centred on its
            pole and was 2 % off under a sphere; the spiral is not aligned with anything).
    """
    if shells < 2 or rows < 2 or cols < 3:
        raise ValueError("an occlusion field needs >= 2 shells, >= 2 rows and >= 3 columns")
    c = np.asarray(centre, np.float64)
    radii = inner * radius * (outer / inner) ** (np.arange(shells) / (shells - 1))
    q = shell_samples(c, radii, rows, cols).reshape(-1, 3)
    dirs = fibonacci_sphere(directions)
    occ = occlusion_rays(scene, q, dirs, progress=progress)
    coeffs = occ @ (sh_basis(dirs, order) * (4 * np.pi / len(dirs))).astype(np.float32)
    coeffs = coeffs.reshape(shells, rows, cols, -1)
    coeffs = np.concatenate([coeffs, coeffs[:, :, :1]], axis=2)
    return OcclusionField(c, radii, np.ascontiguousarray(coeffs, np.float32), order)


def similarity(m: np.ndarray) -> tuple[float, np.ndarray]:
    """``(s, R)`` of a 4×4 transform whose linear part is ``s·R`` (uniform scale ``s > 0``,
    proper rotation ``R``); ValueError for anything else (shear, non-uniform scale, mirror)."""
    a = np.asarray(m, np.float64)[:3, :3]
    g = a.T @ a
    s2 = float(np.trace(g)) / 3.0
    if s2 <= 0.0 or np.max(np.abs(g - s2 * np.eye(3))) > 1e-6 * s2 or np.linalg.det(a) <= 0:
        raise ValueError("not a similarity transform")
    s = math.sqrt(s2)
    return s, a / s


def object_frame(world: World) -> np.ndarray | None:
    """The frame an object-space occlusion field of ``world``'s virtual shapes is sampled
    in: the ``to_world`` of its one virtual shape when that is a similarity (then the field
    depends on the shape alone, not on its pose); None otherwise (several virtual shapes or
    a shear: the field is sampled in world space, and a pose samples it again)."""
    virtual = world.virtual_shapes
    if len(virtual) != 1:
        return None
    try:
        similarity(virtual[0].to_world)
    except ValueError:
        return None
    return np.asarray(virtual[0].to_world, np.float64)


def occluder_sphere(occluder: Occluder) -> tuple[np.ndarray, float]:
    """Centre (m) and radius (m) of a sphere around an occluder (:func:`make_occluder`):
    a world-space scene's bounding-box circumsphere, an object-space one's through its pose
    (:meth:`PosedOccluder.bounding_sphere`)."""
    if isinstance(occluder, PosedOccluder):
        return occluder.bounding_sphere()
    return _bounding_sphere(occluder)


def _bounding_sphere(scene: mi.Scene) -> tuple[np.ndarray, float]:
    b = scene.bbox()
    lo = np.array([b.min.x, b.min.y, b.min.z], np.float64)
    hi = np.array([b.max.x, b.max.y, b.max.z], np.float64)
    return (lo + hi) / 2.0, float(np.linalg.norm(hi - lo) / 2.0)


def field_for_world(world: World, order: int = 4, **kw) -> OcclusionField | None:
    """The occlusion field of all virtual shapes of ``world`` together (None without any):
    sampled in the object's own space when :func:`object_frame` has a frame (one virtual
    shape: its shape at the identity pose, looked up through its ``to_world``), else in world
    space."""
    frame = object_frame(world)
    if frame is not None:
        scene = _object_scene(world)
        return build_field(scene, *_bounding_sphere(scene), order=order, **kw).posed(frame)
    scene = virtual_scene(world)
    if scene is None:
        return None
    return build_field(scene, *_bounding_sphere(scene), order=order, **kw)


def virtual_moved(before: World, after: World) -> bool:
    """Whether a virtual shape of ``after`` (``before`` posed otherwise) stands elsewhere."""
    return not all(np.array_equal(a.to_world, b.to_world)
                   for a, b in zip(before.shapes, after.shapes, strict=True) if b.is_virtual)


def pose_field(field: OcclusionField | None, world: World, options,
               before: World | None = None) -> OcclusionField | None:
    """``field`` (of ``before``, this world in another pose) for ``world``: the object-space
    field looked up through the new pose, or, for a world-space field, sampled again
    (:func:`field_from_options`) — kept as it is when no virtual shape moved (the first
    frame of a fresh state with several virtual shapes re-sampled it: about 1 s). Bitwise
    the field :func:`field_from_options` makes of ``world``."""
    if field is None:
        return None
    if field.frame is None and before is not None and not virtual_moved(before, world):
        return field
    frame = object_frame(world)
    if field.frame is not None and frame is not None:
        return field.posed(frame)
    return field_from_options(world, options)


OOF_OPTIONS: dict[str, Field] = {
    "oof": Field("bool", True, "AR object occlusion field: the virtual objects' shadow of the "
                 "SH ambient light on real surfaces (Franke §5.2)"),
    "oof_order": Field("int", 4, "SH order of the occlusion field ((L+1)² coefficients per "
                       "sample)", "", min=1, max=8),
    "oof_shells": Field("int", 24, "concentric shells of the occlusion field", "", min=2,
                        max=128),
    "oof_directions": Field("int", 1024, "rays per shell sample (Fibonacci sphere)", "",
                            min=16, max=65536),
    "oof_outer": Field("float", 4.0, "outermost shell radius / the objects' bounding radius "
                       "(beyond it the ambient occlusion is dropped)", "", min=1.0,
                       max=100.0),
}
"""The real-surface relighting settings of the ``ibl`` and ``prt`` methods."""


def field_from_options(world: World, options) -> OcclusionField | None:
    """:func:`field_for_world` with the :data:`OOF_OPTIONS` of a method (None when off)."""
    if not options.oof:
        return None
    return field_for_world(world, order=options.oof_order, shells=options.oof_shells,
                           directions=options.oof_directions, outer=options.oof_outer)


def shadow_factor(mixed: SceneView, real: SceneView, occluder: Occluder | None,
                  lights: LightSet, field: OcclusionField | None, p: mi.Point3f,
                  n: mi.Vector3f, active: mi.Bool) -> mi.Color3f:
    """Per-lane multiplicative factor ``f ∈ [0, 1]`` (RGB) of the real surface's light
    (module docstring): shadow rays to the reduced lights in both views, and the occlusion
    field for the SH ambient part; 1 on inactive lanes.

    Only *affected* lanes pay for the two views' shadow rays and the field lookup: those
    inside the outermost shell and those whose ray to some light hits a virtual shape
    (tested first against ``occluder``, the virtual shapes alone); elsewhere ``f = 1``
    exactly."""
    f = dr.full(mi.Color3f, 1.0, dr.width(p))
    idx = dr.compress(active)
    if dr.width(idx) == 0 or occluder is None:
        return f
    pc = dr.gather(mi.Point3f, p, idx)
    nc = dr.gather(mi.Vector3f, n, idx)
    on = mi.Bool(True)
    blocked = dr.zeros(mi.Bool, dr.width(idx))
    if lights.lights:
        occ_view = SimpleNamespace(scene=occluder)
        free = direct_irradiance(occ_view, lights, pc, nc, on, shadows=False)
        occl = direct_irradiance(occ_view, lights, pc, nc, on, shadows=True)
        blocked = dr.any(occl < free)
    affected = mi.Bool(blocked)
    if field is not None:  # opaque: one kernel for every pose of the field
        c = [dr.opaque(mi.Float, float(x)) for x in field.world_centre]
        affected |= dr.norm(pc - mi.Point3f(*c)) < dr.opaque(mi.Float, field.world_r_max)
    sub = dr.compress(affected)
    if dr.width(sub) == 0:
        return f
    ps, ns = dr.gather(mi.Point3f, pc, sub), dr.gather(mi.Vector3f, nc, sub)
    e_real = direct_irradiance(real, lights, ps, ns, on)
    e_mix = e_real
    if lights.lights:
        # a ray that misses the virtual shapes sees the same in both views: the mixed view's
        # shadow rays are traced on the lanes that the occluder blocked only
        b_sub = dr.gather(mi.Bool, blocked, sub)
        e_mix = dr.select(b_sub, on_active(
            lambda q, m: direct_irradiance(mixed, lights, q, m, on), ps, ns, b_sub), e_real)
    num, den = mi.Color3f(e_mix), mi.Color3f(e_real)
    amb = np.asarray(lights.ambient_sh, np.float64)
    if np.any(amb):
        e_amb = dr.maximum(ambient_irradiance_dr(lights, ns), 0.0)
        num += e_amb
        den += e_amb
        if field is not None:
            e_occ = field.occluded_irradiance(amb, ps, ns)
            num -= dr.clip(e_occ, 0.0, e_amb)
    ratio = dr.select(den > 1e-12, num / dr.maximum(den, 1e-12), 1.0)
    dr.scatter(f, dr.clip(ratio, 0.0, 1.0), dr.gather(mi.UInt32, idx, sub))
    return f


# --------------------------------------------------------------------------------------------
# The frame of the OOF-relit methods (ibl, prt)
# --------------------------------------------------------------------------------------------

class RelitState(Protocol):
    """What :func:`shade_real` and :func:`render_layers` read of a prepared world: the world,
    its Mitsuba views, the reduced lights, the virtual occluder (None: no virtual shape) and
    its occlusion field (None: off)."""

    world: World
    views: SceneViews
    lights: LightSet
    occluder: Occluder | None
    field: OcclusionField | None


class GBufferOptions(Protocol):
    """The option :func:`render_layers` reads (``arlight.methods.fragments.GBUFFER_OPTIONS``)."""

    gbuffer_spp: int


ShadeVirtual = Callable[[Any, GBuffer, FrameView, Any, int], tuple[mi.Color3f, mi.UInt32]]
"""``shade(data, gb, view, options, seed) -> (radiance, lanes)`` of the virtual lanes."""


def shade_real(data: RelitState, gb: GBuffer, frame: np.ndarray) -> mi.Color3f:
    """Delta ``B (f − 1)`` on the real lanes (zero elsewhere), ``f`` from
    :func:`shadow_factor`."""
    real = gb.valid & ~gb.virtual
    f = shadow_factor(data.views.mixed, data.views.real, data.occluder, data.lights,
                      data.field, gb.position, gb.normal, real)
    b = dr.gather(mi.Color3f, mi.Float(aligned(np.reshape(frame, -1), np.float32)), gb.pixel)
    delta = dr.select(real, b * (f - 1.0), mi.Color3f(0.0))
    dr.eval(delta)
    return delta


def render_layers(data: RelitState, view: FrameView, options: GBufferOptions, seed: int,
                  timer, shade: ShadeVirtual) -> Layers:
    """One frame of ``ibl`` and ``prt``: the G-buffer (``options.gbuffer_spp`` samples per
    pixel), ``shade(data, gb, view, options, seed) -> (radiance, lanes)`` on the virtual
    lanes, the AR-OOF darkening on the real ones (:func:`shade_real`), assembly. ``timer``:
    an :class:`arlight.timing.StageTimer` (stages ``gbuffer``, ``shade_virtual``,
    ``shade_real``, ``assemble``)."""
    with timer.stage("gbuffer"):
        gb = render_gbuffer(data.views.mixed, view.camera, options.gbuffer_spp, seed)
    with timer.stage("shade_virtual"):
        rad, lanes = shade(data, gb, view, options, seed)
    with timer.stage("shade_real"):
        width = dr.width(gb.position)
        delta = (shade_real(data, gb, view.frame) if data.occluder is not None
                 else dr.zeros(mi.Color3f, width))
    with timer.stage("assemble"):
        mixed = dr.zeros(mi.Color3f, width)
        if dr.width(lanes):
            dr.scatter(mixed, rad, lanes)
        stats = {"lights": float(len(data.lights.lights)),
                 "virtual_lanes": float(dr.width(lanes))}
        layers = assemble(gb, view.frame, mixed, delta, stats)
    if not data.world.has_virtual:
        assert not np.any(layers.delta), "delta must vanish without virtual objects"
    return layers


__all__ = ["OOF_OPTIONS", "GBufferOptions", "OcclusionField", "Occluder", "PosedOccluder",
           "occluder_sphere",
           "RAY_CHUNK", "RelitState", "ShadeVirtual", "build_field", "cosine_transfer",
           "field_for_world", "field_from_options", "make_occluder", "move_occluder",
           "move_virtual_scene",
           "object_frame", "occlusion_rays", "octahedral_index", "octahedral_normals",
           "pose_field", "render_layers", "shade_real", "shadow_factor", "shell_samples",
           "similarity", "virtual_moved", "virtual_scene"]
