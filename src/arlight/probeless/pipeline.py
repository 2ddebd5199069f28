"""Per-frame radiance transfer, light estimation and SH differential shading (Gruber 2014).

One :class:`Pipeline` runs a sequence of frames against the Mitsuba views of a world (the
reconstruction as the real proxy, plus virtual objects):

1. primary hits of the camera (positions, normals, albedo, role) in the mixed scene;
2. samples: the regular grid of spacing ``n`` (Gruber §3.1), plus — adaptive variants — dense
   samples at virtual silhouettes and creases and at real surfaces hit by visibility rays
   from virtual points;
3. transfer (E3) of every sample, ``T_real`` and ``T_mix``. Interleaved variants cast only the
   direction subset ``f mod k`` in frame ``f`` and fuse the other ``k−1`` subsets from the
   image-space caches of the last frames by reprojection (nearest cache cell, rejected when
   the cached depth or normal differs: then that subset is cast again now). Points in voxels
   of the visibility-state cache flagged *free* get the analytic unoccluded transfer (E6) and
   no rays; when the world changes (:meth:`Pipeline.set_views`) cache validation cameras
   (one overhead, one at the user's pose) clear flags within ``max_distance`` of any change
   of the scene's depth;
4. light: E5 over the regular samples on real surfaces (where the sensor depth agrees),
   including the real surfaces behind virtual objects (the frame shows them);
5. shading (E7): virtual pixels ``a_v/π T_mix·l`` (+ a Phong lobe along the dominant
   direction for Phong materials), real pixels ``delta = a/π (T_mix − T_real)·l`` (or the
   ratio form ``I_c (T_mix·l / T_real·l − 1)``), upsampled from the samples.

Variants (Gruber Table 1 / Fig. 5): ``RM`` every pixel, all 81 directions; ``REG4``/``REG8``
regular spacing 4/8, all directions, naive bilinear upsampling; ``ART1``/``ART4``/``ART8``
adaptive sampling at spacing 1/4/8, interleaving over 4 frames, visibility-state cache,
geometry-aware upsampling. Every acceleration is a field of :class:`Variant`, so each can be
switched on its own.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.camera_rays import opaque, rays_from_samples
from arlight.backend.mitsuba_scene import ROLE_MISS, ROLE_REAL, ROLE_VIRTUAL, SceneViews
from arlight.probeless.directions import N_COEFFS, DirectionSet, unoccluded_transfer
from arlight.probeless.estimate import DEFAULT_RIDGE, SHLightFit, estimate_light
from arlight.probeless.transfer import (
    MAX_DISTANCE,
    Transfer,
    compute_transfer,
    compute_transfers,
    real_hits_from,
)
from arlight.realtime.gbuffer import facing, surface_albedo
from arlight.scene.camera import Camera, look_at
from arlight.scene.model import Shape
from arlight.sphere import sh as SH


@dataclass(frozen=True)
class Variant:
    """Which accelerations run.

    Attributes:
        name: label (the paper's names for the presets).
        spacing: regular image-space sample spacing ``n`` in pixels (1: every pixel).
        adaptive: dense samples at virtual edges and virtual-shadow receivers, and
            geometry-aware upsampling (else naive bilinear upsampling of the grid).
        interleave: ``k``: frames over which the directions are interleaved (1: all 81 rays
            every frame, no caches).
        state_cache: world-space visibility-state cache with cache validation cameras.
    """

    name: str
    spacing: int = 4
    adaptive: bool = True
    interleave: int = 4
    state_cache: bool = True


VARIANTS: dict[str, Variant] = {
    "RM": Variant("RM", 1, False, 1, False),
    "REG4": Variant("REG4", 4, False, 1, False),
    "REG8": Variant("REG8", 8, False, 1, False),
    "ART1": Variant("ART1", 1, True, 4, True),
    "ART4": Variant("ART4", 4, True, 4, True),
    "ART8": Variant("ART8", 8, True, 4, True),
}
"""The variants compared by Gruber et al. (Fig. 5, Table 1)."""


@dataclass(frozen=True)
class Settings:
    """Parameters the paper does not fix (digest §6: "inferred: choose and expose").

    Attributes:
        max_distance: visibility ray length (m), :data:`~arlight.probeless.transfer.MAX_DISTANCE`.
        ray_offset: ray origins moved off the surface along the normal (m).
        depth_reject: relative camera-depth difference above which a reprojected cache entry
            is rejected and rebuilt (and a sensor depth disagrees with the proxy).
        normal_reject: minimum cosine between a sample's and a cache entry's normal.
        free_fraction: a point whose blocked share of rays is at most this is *free*.
        state_voxel: edge of a visibility-state voxel (m); 2 m / 268 as Gruber's TSDF.
        cvc_size: resolution (px, square) of the cache validation cameras.
        cvc_threshold: depth change (m) that invalidates the state cache around a CVC pixel.
        ridge: Tikhonov weight of E5 relative to ``σ_max²``.
        ratio: real pixels by the ratio form of E7 instead of the additive one.
        edge_depth: relative depth jump that makes a virtual pixel an edge (adaptive).
        edge_normal: normal cosine below which neighbouring virtual pixels are a crease.
        plane_reject: upsampling: a grid sample further than this times the pixel's depth
            from the pixel's tangent plane is on another surface and is not used.
    """

    max_distance: float = MAX_DISTANCE
    ray_offset: float = 2e-3
    depth_reject: float = 0.03
    normal_reject: float = 0.9
    free_fraction: float = 0.0
    state_voxel: float = 2.0 / 268
    cvc_size: int = 64
    cvc_threshold: float = 0.01
    ridge: float = DEFAULT_RIDGE
    ratio: bool = False
    edge_depth: float = 0.03
    edge_normal: float = 0.9
    plane_reject: float = 0.01


# ----------------------------------------------------------------------------- primary hits


@dataclass
class Hits:
    """Per-pixel first hits ``(H, W, ...)`` of one camera in one scene view (NumPy)."""

    position: np.ndarray
    normal: np.ndarray
    albedo: np.ndarray
    role: np.ndarray
    shape: np.ndarray
    z: np.ndarray  # camera-space depth (m), inf on a miss

    @property
    def valid(self) -> np.ndarray:
        return self.role != ROLE_MISS


def primary_hits(views: SceneViews, camera: Camera, mixed: bool = True,
                 pixels: np.ndarray | None = None) -> Hits:
    """One ray per pixel centre into the mixed (or real) view: position, shading normal on
    the camera's side of the surface, diffuse albedo, role, shape index and camera-space
    depth; ``(H, W, ...)``, or ``(1, P, ...)`` for the flat pixel indices ``pixels``
    (``row·W + column``)."""
    view = views.mixed if mixed else views.real
    h, w = camera.height, camera.width
    if pixels is not None:
        h, w = 1, len(pixels)
    # pixel centres, the lens centre (a pinhole ray), generated in the kernel: building
    # 307k rays in NumPy took longer than tracing them
    centre = mi.Point2f(0.5, 0.5)
    index = (dr.arange(mi.UInt32, h * w) if pixels is None
             else mi.UInt32(np.asarray(pixels, np.uint32)))
    ray = mi.Ray3f(rays_from_samples(camera, index, centre, centre))
    si = view.scene.ray_intersect(ray)
    valid = si.is_valid()
    # the side facing the camera from the geometric normal; the shading normal on that side
    # (flipping the shading normal itself by the view turns silhouette pixels of smooth
    # meshes inside the object: their visibility rays start blocked and they shade black)
    ng = facing(mi.Vector3f(si.n), -ray.d)
    n = facing(mi.Vector3f(si.sh_frame.n), ng)
    alb = surface_albedo(si, valid)
    role = view.hit_role(si)
    shape = view.hit_shape(si)
    forward = mi.Vector3f(*(opaque(c) for c in camera.world_from_camera[:3, 2]))
    zf = si.t * dr.dot(ray.d, forward)
    dr.eval(si.p, n, alb, role, shape, zf)
    role_np = np.array(role, np.int32).reshape(h, w)
    zf_np = np.array(zf, np.float64)
    z = np.where(np.isfinite(zf_np) & (role_np.ravel() != ROLE_MISS), zf_np, np.inf)
    return Hits(position=np.array(si.p, np.float64).T.reshape(h, w, 3),
                normal=np.array(n, np.float64).T.reshape(h, w, 3),
                albedo=np.array(alb, np.float64).T.reshape(h, w, 3),
                role=role_np, shape=np.array(shape, np.int32).reshape(h, w),
                z=z.reshape(h, w))


# ----------------------------------------------------------------------------- caches


@dataclass
class PhaseCache:
    """Image-space cache of one interleave phase: the partial transfer of its direction
    subset at the regular grid of the frame that filled it, with that frame's camera."""

    camera: Camera
    spacing: int
    real: np.ndarray      # (Hs, Ws, 16)
    mixed: np.ndarray     # (Hs, Ws, 16)
    cast: np.ndarray      # (Hs, Ws)
    blocked: np.ndarray   # (Hs, Ws)
    z: np.ndarray         # (Hs, Ws) camera depth of the cell's point
    normal: np.ndarray    # (Hs, Ws, 3)
    position: np.ndarray  # (Hs, Ws, 3) world point of the cell's sample
    valid: np.ndarray     # (Hs, Ws) bool

    @staticmethod
    def empty(camera: Camera, spacing: int) -> PhaseCache:
        hs = -(-camera.height // spacing)
        ws = -(-camera.width // spacing)
        return PhaseCache(camera, spacing, np.zeros((hs, ws, N_COEFFS)),
                          np.zeros((hs, ws, N_COEFFS)), np.zeros((hs, ws), np.int64),
                          np.zeros((hs, ws), np.int64), np.full((hs, ws), np.inf),
                          np.zeros((hs, ws, 3)), np.zeros((hs, ws, 3)),
                          np.zeros((hs, ws), bool))

    def lookup(self, points: np.ndarray, normals: np.ndarray, depth_reject: float,
               normal_reject: float) -> tuple[np.ndarray, np.ndarray]:
        """Reproject world ``points`` into this cache's camera and take, of the 2×2 cells
        around the projection, the valid one whose stored point is nearest in 3D (Gruber's
        nearest-neighbour lookup, made robust at the cache's coarse grid). A hit needs the
        cell's depth within ``depth_reject`` (relative) of the point's depth in that camera
        and agreeing normals. Returns (hit mask ``(M,)``, flat cell index ``(M,)``)."""
        uv, z = self.camera.project(points)
        hs, ws = self.valid.shape
        s = self.spacing
        with np.errstate(invalid="ignore"):
            fi = np.floor((uv[:, 1] - 0.5) / s)
            fj = np.floor((uv[:, 0] - 0.5) / s)
        finite = (z > 0) & np.isfinite(fi) & np.isfinite(fj)
        fi = np.where(finite, fi, -10).astype(np.int64)
        fj = np.where(finite, fj, -10).astype(np.int64)
        # the 2×2 candidates as one (4, M) evaluation (one NumPy pass instead of four, issue
        # #33's ART timing); the first of equal distances wins, as a loop in (di, dj) order
        i = fi[None] + np.array([0, 0, 1, 1])[:, None]
        j = fj[None] + np.array([0, 1, 0, 1])[:, None]
        inside = finite[None] & (i >= 0) & (i < hs) & (j >= 0) & (j < ws)
        c = np.where(inside, i * ws + j, 0)
        ok = inside & self.valid.reshape(-1)[c]
        with np.errstate(invalid="ignore"):
            ok &= np.abs(self.z.reshape(-1)[c] - z[None]) <= depth_reject * np.maximum(z, 1e-6)
        ok &= np.einsum("kij,ij->ki", self.normal.reshape(-1, 3)[c], normals) >= normal_reject
        dist = np.linalg.norm(self.position.reshape(-1, 3)[c] - points[None], axis=2)
        dist = np.where(ok, dist, np.inf)
        first = np.argmin(dist, axis=0)
        cols = np.arange(len(points))
        best = dist[first, cols]
        cell = np.where(np.isfinite(best), c[first, cols], 0)
        return np.isfinite(best), cell


MAX_STATE_CELLS = 1 << 27
"""Most voxels of the visibility-state grid (one byte each, 128 MiB); a larger scene gets a
grid of this size around its centre, and points outside it are never flagged free."""


class StateGrid:
    """Gruber's world-space visibility-state cache (§3.3): one Boolean per voxel, *free* =
    "no occluder within ``max_distance``, skip the visibility rays", as a dense grid over the
    scene's bounding box (Gruber: 268³ bits over the TSDF's 2 m cube).

    Lookups and updates are index arithmetic, ``O(M)`` for ``M`` points, with no sorting or
    hashing (a sorted set of voxel keys cost ~70 ms per 640×480 frame on 2 CPU cores).

    Args:
        lo, hi: corners of the scene's bounding box (world, m).
        voxel: voxel edge (m).
    """

    def __init__(self, lo: np.ndarray, hi: np.ndarray, voxel: float) -> None:
        lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
        self.voxel = float(voxel)
        dims = np.ceil((hi - lo) / voxel).astype(np.int64) + 3
        while int(np.prod(dims)) > MAX_STATE_CELLS:  # keep the centre, shrink the reach
            dims = np.maximum(1, (dims * 0.9).astype(np.int64))
        centre = (lo + hi) / 2
        self.origin = centre - dims * voxel / 2
        self.dims = dims
        self.flags = np.zeros(int(np.prod(dims)), bool)

    def index(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Flat voxel index ``(M,)`` of each point and whether it lies in the grid."""
        q = np.floor((np.asarray(points, np.float64) - self.origin) / self.voxel)
        inside = np.all((q >= 0) & (q < self.dims), axis=1)
        q = np.where(inside[:, None], q, 0).astype(np.int64)
        return (q[:, 0] * self.dims[1] + q[:, 1]) * self.dims[2] + q[:, 2], inside

    def lookup(self, points: np.ndarray) -> np.ndarray:
        """Whether each point's voxel is flagged free ``(M,)``."""
        idx, inside = self.index(points)
        return inside & self.flags[idx]

    def update(self, points: np.ndarray, is_free: np.ndarray) -> None:
        """Flag the voxels of ``points`` whose samples this frame were all free; a voxel with
        any blocked sample stays (or becomes) not free."""
        idx, inside = self.index(points)
        is_free = np.asarray(is_free, bool)
        self.flags[idx[inside & is_free]] = True
        self.flags[idx[inside & ~is_free]] = False

    def clear_near(self, points: np.ndarray, radius: float) -> None:
        """Clear the free voxels whose centre is within ``radius`` (+ half a voxel diagonal)
        of any of ``points`` (the changed surface seen by a validation camera)."""
        free = np.flatnonzero(self.flags)
        if len(points) == 0 or len(free) == 0:
            return
        from scipy.spatial import cKDTree

        ijk = np.stack(np.unravel_index(free, tuple(self.dims)), axis=1)
        centres = self.origin + (ijk + 0.5) * self.voxel
        dist, _ = cKDTree(points).query(centres, k=1)
        self.flags[free[dist <= radius + self.voxel * np.sqrt(3) / 2]] = False

    @property
    def free_count(self) -> int:
        """Number of voxels flagged free."""
        return int(np.count_nonzero(self.flags))


def _cvc_depths(views: SceneViews, cameras: list[Camera]
                ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per camera: ray distance ``(P,)`` (inf on a miss), ray origins and directions, of all
    ``cameras`` in one batch (one kernel launch for all the validation cameras)."""
    rays = []
    for camera in cameras:
        v, u = np.mgrid[0:camera.height, 0:camera.width]
        rays.append(camera.pixel_rays(np.stack([u.ravel() + 0.5, v.ravel() + 0.5], axis=1)))
    o = np.concatenate([r[0] for r in rays])
    d = np.concatenate([r[1] for r in rays])
    oo = np.ascontiguousarray(o.T, np.float32)
    dd = np.ascontiguousarray(d.T, np.float32)
    si = views.mixed.scene.ray_intersect(mi.Ray3f(mi.Point3f(*oo), mi.Vector3f(*dd)))
    dr.eval(si.t)
    t = np.array(si.t, np.float64)
    t[~np.isfinite(t)] = np.inf
    out, a = [], 0
    for ro, rd in rays:
        out.append((t[a:a + len(ro)], ro, rd))
        a += len(ro)
    return out


def overhead_camera(views: SceneViews, size: int) -> Camera:
    """A camera above the scene's bounding box looking down (−Y) at all of it."""
    bb = views.mixed.scene.bbox()
    lo, hi = np.array(bb.min, np.float64), np.array(bb.max, np.float64)
    centre = (lo + hi) / 2
    half = max(float(np.max(hi - lo)) / 2, 0.05)
    fov = 60.0
    height = half / np.tan(np.radians(fov / 2)) * 1.2 + (hi[1] - centre[1])
    eye = centre + np.array([0.0, height, 0.0])
    pose = look_at(eye, centre, up=(0.0, 0.0, -1.0))
    return Camera.from_fov(size, size, fov, world_from_camera=pose)


# ----------------------------------------------------------------------------- results


@dataclass
class FrameResult:
    """What one frame produced.

    Attributes:
        fit: the light estimate of this frame (E5).
        regular: the fused transfer of the regular samples (row-major grid order).
        observations: ``(T_real, b, albedo)`` rows that entered E5 (to fit several frames).
        mixed, delta, mask: shading layers ``(H, W, 3)``/``(H, W)`` when shading was asked.
        stats: ``rays`` (visibility rays cast), ``samples`` (regular + dense),
            ``dense_samples``, ``hidden_samples`` (grid pixels a virtual object covers,
            traced in the real view for E5), ``free_samples`` (state cache), ``cache_hits`` /
            ``cache_misses`` (reprojection), ``time_rt`` (everything before E5, of which
            ``time_hits``: the primary hits),
            ``time_estimate``, ``time_shade`` (s).
    """

    fit: SHLightFit
    regular: Transfer | None = None
    observations: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    mixed: np.ndarray | None = None
    delta: np.ndarray | None = None
    mask: np.ndarray | None = None
    stats: dict[str, float] = field(default_factory=dict)


def _regular_mask(h: int, w: int, s: int) -> np.ndarray:
    m = np.zeros((h, w), bool)
    m[::s, ::s] = True
    return m


def _dilate(mask: np.ndarray, r: int) -> np.ndarray:
    out = mask.copy()
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            out |= np.roll(np.roll(mask, dy, axis=0), dx, axis=1)
    return out


def virtual_edges(hits: Hits, depth_jump: float, normal_cos: float) -> np.ndarray:
    """Visible virtual pixels at a depth or normal discontinuity or at the silhouette
    (a neighbour of another role), dilated by one pixel (Gruber §3.1: edge detection on the
    depth and normal buffers; operator not given, ours is a 4-neighbour test)."""
    virt = hits.role == ROLE_VIRTUAL
    z = np.where(np.isfinite(hits.z), hits.z, 1e30)
    edge = np.zeros_like(virt)
    for axis in (0, 1):
        for step in (1, -1):
            zn = np.roll(z, step, axis=axis)
            rn = np.roll(hits.role, step, axis=axis)
            nn = np.roll(hits.normal, step, axis=axis)
            edge |= rn != hits.role
            edge |= np.abs(zn - z) > depth_jump * z
            edge |= np.einsum("hwc,hwc->hw", nn, hits.normal) < normal_cos
    return _dilate(edge & virt, 1) & virt


# ----------------------------------------------------------------------------- pipeline


class Pipeline:
    """The per-frame probeless pipeline over one world (see the module docstring).

    Args:
        views: Mitsuba views of the world (``views.real``: the reconstruction / proxy).
        variant: a :class:`Variant` or a name of :data:`VARIANTS`.
        settings: :class:`Settings`.
        shapes: the world's shapes (index as in the views), for Phong parameters.
        directions: the direction set (default 81 directions, ``k`` of the variant).
    """

    def __init__(self, views: SceneViews, variant: Variant | str = "ART4",
                 settings: Settings | None = None, shapes: list[Shape] | None = None,
                 directions: DirectionSet | None = None) -> None:
        self.variant = VARIANTS[variant] if isinstance(variant, str) else variant
        self.settings = settings or Settings()
        self.views = views
        self.shapes = shapes or []
        self.directions = directions or DirectionSet(k=self.variant.interleave)
        if self.directions.k != self.variant.interleave:
            raise ValueError(f"direction set interleave {self.directions.k} != variant's "
                             f"{self.variant.interleave}")
        self.frame_index = 0
        self.caches: list[PhaseCache | None] = [None] * self.variant.interleave
        self.dense_caches: list[PhaseCache | None] = [None] * self.variant.interleave
        self.state: StateGrid | None = None
        self._last_camera: Camera | None = None

    # ------------------------------------------------------------------ state cache

    def set_views(self, views: SceneViews) -> None:
        """The world changed (a reconstruction update, a moved virtual object): later
        frames trace ``views``.

        The cache validation cameras (Gruber §3.3: one overhead over the whole scene, one at
        the user's pose) cast the old and the new world; free voxels within ``max_distance``
        of every pixel whose depth changed by more than ``cvc_threshold`` are cleared.
        Gruber casts them every frame, comparing with the depth maps of the last cast (the
        user's camera with ping-pong buffers), because KinectFusion changes the TSDF
        without telling anyone; here the world changes only through this call, so they are
        cast only then, old against new, and cost nothing per frame."""
        st = self.settings
        if self.state is not None and self.state.free_count:
            cams = [overhead_camera(views, st.cvc_size)]
            if self._last_camera is not None:
                c = self._last_camera
                cams.append(c.resized(st.cvc_size,
                                      max(1, round(st.cvc_size * c.height / c.width))))
            changed: list[np.ndarray] = []
            for (t0, o, d), (t1, _, _) in zip(_cvc_depths(self.views, cams),
                                              _cvc_depths(views, cams), strict=True):
                moved = np.abs(np.where(np.isfinite(t1), t1, 1e9)
                               - np.where(np.isfinite(t0), t0, 1e9)) > st.cvc_threshold
                for t in (t0, t1):
                    sel = moved & np.isfinite(t)
                    changed.append(o[sel] + t[sel, None] * d[sel])
            self.state.clear_near(np.concatenate(changed), st.max_distance)
        self.views = views

    # ------------------------------------------------------------------ transfer

    def _full(self, p: np.ndarray, n: np.ndarray, need_real: np.ndarray) -> Transfer:
        st = self.settings
        return compute_transfer(self.views, p, n, self.directions, None, need_real,
                                st.max_distance, st.ray_offset)

    def _interleaved(self, p: np.ndarray, n: np.ndarray, need_real: np.ndarray,
                     camera: Camera, grid_cells: np.ndarray, caches: list[PhaseCache | None],
                     spacing: int, stats: dict[str, float]) -> Transfer:
        """Fused transfer of samples: the current phase cast now (and stored in its cache
        of ``caches``, an image grid of ``spacing``), the other phases reprojected from
        their caches or rebuilt on a miss. The rays of the current phase and of every
        phase's misses go to Mitsuba as one batch (:func:`compute_transfers`)."""
        st, k = self.settings, self.variant.interleave
        phase = self.frame_index % k
        out = Transfer.zeros(len(p))
        new = PhaseCache.empty(camera, spacing)
        found: list[tuple[np.ndarray, np.ndarray] | None] = []  # per phase: (hit, cell)
        todos: list[np.ndarray] = []
        for c in range(k):
            todo = np.ones(len(p), bool)
            cache = caches[c]
            hit = None
            if c != phase and cache is not None:
                hit = cache.lookup(p, n, st.depth_reject, st.normal_reject)
                todo = ~hit[0]
                stats["cache_hits"] += float(hit[0].sum())
                stats["cache_misses"] += float(todo.sum())
            elif c != phase:
                stats["cache_misses"] += float(len(p))
            found.append(hit)
            todos.append(todo)
        cast = [c for c in range(k) if np.any(todos[c])]
        parts = dict(zip(cast, compute_transfers(
            self.views, [(p[todos[c]], n[todos[c]], self.directions.subset(c),
                          need_real[todos[c]]) for c in cast], self.directions,
            st.max_distance, st.ray_offset), strict=True))
        for c in range(k):  # phases added in order: the sums are those of one phase at a time
            if found[c] is not None:
                hit, cell = found[c]
                cache = caches[c]
                out.real[hit] += cache.real.reshape(-1, N_COEFFS)[cell[hit]]
                out.mixed[hit] += cache.mixed.reshape(-1, N_COEFFS)[cell[hit]]
                out.cast[hit] += cache.cast.reshape(-1)[cell[hit]]
                out.blocked[hit] += cache.blocked.reshape(-1)[cell[hit]]
            if c not in parts:
                continue
            todo, part = todos[c], parts[c]
            out.real[todo] += part.real
            out.mixed[todo] += part.mixed
            out.cast[todo] += part.cast
            out.blocked[todo] += part.blocked
            out.rays += part.rays
            if c == phase:
                cells = grid_cells
                new.real.reshape(-1, N_COEFFS)[cells] = part.real
                new.mixed.reshape(-1, N_COEFFS)[cells] = part.mixed
                new.cast.reshape(-1)[cells] = part.cast
                new.blocked.reshape(-1)[cells] = part.blocked
                new.valid.reshape(-1)[cells] = True
        new.z.reshape(-1)[grid_cells] = camera.project(p)[1]
        new.normal.reshape(-1, 3)[grid_cells] = n
        new.position.reshape(-1, 3)[grid_cells] = p
        caches[phase] = new
        return out

    def _sample_transfer(self, p: np.ndarray, n: np.ndarray, need_real: np.ndarray,
                         dense: bool, camera: Camera, grid_cells: np.ndarray,
                         stats: dict[str, float]) -> Transfer:
        """Transfer of samples, through the state cache (free points: E6, no rays) and, for
        interleaved variants, the reprojection caches: the regular grid's, or for
        ``dense`` samples per-pixel caches (``grid_cells``: row·width + column)."""
        v = self.variant
        out = Transfer.zeros(len(p))
        free = np.zeros(len(p), bool)
        if v.state_cache:
            if self.state is None:
                bb = self.views.mixed.scene.bbox()
                self.state = StateGrid(np.array(bb.min, np.float64),
                                       np.array(bb.max, np.float64), self.settings.state_voxel)
            free = self.state.lookup(p)
            if np.any(free):
                t0 = unoccluded_transfer(n[free])
                out.real[free] = t0
                out.mixed[free] = t0
            stats["free_samples"] += float(free.sum())
        todo = ~free
        if np.any(todo):
            if v.interleave > 1:
                caches, spacing = ((self.dense_caches, 1) if dense
                                   else (self.caches, v.spacing))
                part = self._interleaved(p[todo], n[todo], need_real[todo], camera,
                                         grid_cells[todo], caches, spacing, stats)
            else:
                part = self._full(p[todo], n[todo], need_real[todo])
            out.real[todo] = part.real
            out.mixed[todo] = part.mixed
            out.cast[todo] = part.cast
            out.blocked[todo] = part.blocked
            out.rays += part.rays
            if self.state is not None:
                frac = part.blocked / np.maximum(part.cast, 1)
                self.state.update(p[todo], (frac <= self.settings.free_fraction)
                                  & (part.cast > 0))
        return out

    # ------------------------------------------------------------------ frame

    def process(self, camera: Camera, frame: np.ndarray | None, depth: np.ndarray | None = None,
                shade: bool = True) -> FrameResult:
        """Run one frame: transfer of the samples, light estimate, and (``shade``) the
        mixed / delta / mask layers. ``frame``: linear RGB ``(H, W, 3)`` (the observed
        ``b`` of E5); ``depth``: optional sensor depth (m, 0/NaN unknown) that gates which
        samples may observe the light."""
        v, st = self.variant, self.settings
        h, w = camera.height, camera.width
        stats: dict[str, float] = {"rays": 0.0, "samples": 0.0, "dense_samples": 0.0,
                                   "free_samples": 0.0, "cache_hits": 0.0,
                                   "cache_misses": 0.0}
        t0 = time.perf_counter()
        self._last_camera = camera
        hits = primary_hits(self.views, camera)
        stats["time_hits"] = time.perf_counter() - t0
        reg = _regular_mask(h, w, v.spacing) & hits.valid
        virt = hits.role == ROLE_VIRTUAL
        dense = np.zeros((h, w), bool)
        if v.adaptive and shade and np.any(virt):  # dense samples serve only the shading
            dense |= virtual_edges(hits, st.edge_depth, st.edge_normal) & ~reg
        # regular samples (cached path)
        rr, cc = np.nonzero(reg)
        pr, nr = hits.position[rr, cc], hits.normal[rr, cc]
        need_r = hits.role[rr, cc] == ROLE_REAL
        ws = -(-w // v.spacing)
        cells = (rr // v.spacing) * ws + cc // v.spacing
        t_reg = self._sample_transfer(pr, nr, need_r, False, camera, cells, stats)
        stats["rays"] += t_reg.rays
        # adaptive: real surfaces hit by visibility rays from virtual points
        if v.adaptive and shade and np.any(virt):  # dense samples serve only the shading
            vsel = virt & (reg | dense)
            vr, vc = np.nonzero(vsel)
            sub = self.directions.subset(self.frame_index % v.interleave)
            pts, n_rays = real_hits_from(self.views, hits.position[vr, vc],
                                         hits.normal[vr, vc], self.directions, sub,
                                         st.max_distance, st.ray_offset)
            stats["rays"] += n_rays
            if len(pts):
                uv, z = camera.project(pts)
                ok = (z > 0) & np.all(np.isfinite(uv), axis=1)
                u = np.floor(uv[ok, 0]).astype(np.int64)
                vv = np.floor(uv[ok, 1]).astype(np.int64)
                inside = (u >= 0) & (u < w) & (vv >= 0) & (vv < h)
                mark = np.zeros((h, w), bool)
                mark[vv[inside], u[inside]] = True
                r = max(1, v.spacing // 2)
                dense |= _dilate(mark, r) & (hits.role == ROLE_REAL) & ~reg
        if v.adaptive and shade:  # pixels that no grid sample can serve: their own sample
            dense |= self.unserved(hits, reg) & ~reg
        dr_, dc_ = np.nonzero(dense)
        t_dense = self._sample_transfer(hits.position[dr_, dc_], hits.normal[dr_, dc_],
                                        hits.role[dr_, dc_] == ROLE_REAL, True, camera,
                                        dr_ * w + dc_, stats)
        stats["rays"] += t_dense.rays
        stats["samples"] = float(len(rr) + len(dr_))
        stats["dense_samples"] = float(len(dr_))
        if frame is None:
            raise ValueError("process needs the frame: its pixels are the observations of E5")
        # E5's observations are the frame's pixels, and the frame shows the real scene also
        # where a virtual object will be drawn: those grid pixels are traced in the real view
        # (all directions, no cache; they are few)
        pix = rr * w + cc
        obs_t, obs_px = [t_reg.real[need_r]], [pix[need_r]]
        obs_a, obs_z = [hits.albedo[rr, cc][need_r]], [hits.z[rr, cc][need_r]]
        hidden = pix[hits.role[rr, cc] == ROLE_VIRTUAL]
        if len(hidden):
            hr = primary_hits(self.views, camera, mixed=False, pixels=hidden)
            ok = hr.role[0] == ROLE_REAL
            if np.any(ok):
                t_h = self._full(hr.position[0][ok], hr.normal[0][ok],
                                 np.ones(int(ok.sum()), bool))
                stats["rays"] += t_h.rays
                stats["hidden_samples"] = float(ok.sum())
                obs_t.append(t_h.real)
                obs_px.append(hidden[ok])
                obs_a.append(hr.albedo[0][ok])
                obs_z.append(hr.z[0][ok])
        t1 = time.perf_counter()
        # light estimate (E5) over the regular real samples
        T_obs, px_obs = np.concatenate(obs_t), np.concatenate(obs_px)
        use = np.ones(len(px_obs), bool)
        if depth is not None:
            ds = np.asarray(depth, np.float64).reshape(-1)[px_obs]
            zs = np.concatenate(obs_z)
            with np.errstate(invalid="ignore"):
                use &= np.isfinite(ds) & (ds > 0) & (np.abs(ds - zs) <= 0.05 * zs)
        obs = (T_obs[use], np.asarray(frame, np.float64).reshape(-1, 3)[px_obs[use]],
               np.concatenate(obs_a)[use])
        fit = estimate_light(*obs, ridge=st.ridge)
        t2 = time.perf_counter()
        stats["time_rt"] = t1 - t0
        stats["time_estimate"] = t2 - t1
        result = FrameResult(fit=fit, regular=t_reg, observations=obs, stats=stats)
        if shade:
            self._shade(result, hits, frame, camera, (rr, cc, t_reg), (dr_, dc_, t_dense))
            stats["time_shade"] = time.perf_counter() - t2
        self.frame_index += 1
        return result

    # ------------------------------------------------------------------ shading (E7)

    def _phong(self, hits: Hits, camera: Camera, sh: np.ndarray) -> np.ndarray:
        """Phong lobe ``k_s (n+2)/(2π) cos^n α · E_d · max(0, n·d)`` along the dominant
        direction ``d`` for virtual Phong pixels; ``E_d = 4π/3 (a_c·d)``: the irradiance of
        the directional light with the same linear band ``a_c`` (per channel)."""
        out = np.zeros(hits.position.shape)
        shape_ids = {i for i, s in enumerate(self.shapes)
                     if s.is_virtual and s.material.type == "phong"}
        if not shape_ids:
            return out
        d = SH.dominant_direction(sh)
        e_d = np.clip(4 * np.pi / 3 * (SH.linear_band_vector(sh).T @ d), 0, None)  # (3,)
        view_dir = camera.position[None, None, :] - hits.position
        view_dir /= np.maximum(np.linalg.norm(view_dir, axis=-1, keepdims=True), 1e-12)
        n = hits.normal
        refl = 2 * (n @ d)[..., None] * n - d
        cos_a = np.clip(np.einsum("hwc,hwc->hw", refl, view_dir), 0, None)
        cos_i = np.clip(n @ d, 0, None)
        for i in shape_ids:
            sel = hits.shape == i
            p = self.shapes[i].material.params
            ks, ex = np.asarray(p.get("ks", [0, 0, 0]), np.float64), float(p.get("exponent",
                                                                              20.0))
            lobe = (ex + 2) / (2 * np.pi) * cos_a[sel] ** ex * cos_i[sel]
            out[sel] = lobe[:, None] * ks[None] * e_d[None]
        return out

    def _shade(self, res: FrameResult, hits: Hits, frame: np.ndarray, camera: Camera,
               reg, dense) -> None:
        """Per-sample E7 values, upsampled to every pixel."""
        h, w = hits.role.shape
        sh = res.fit.sh
        val = np.zeros((h, w, 3))
        own = np.zeros((h, w), bool)
        for rr, cc, t in (reg, dense):
            val[rr, cc] = self._e7(hits, frame, rr, cc, t, sh)
            own[rr, cc] = True
        full, fill_rays, fill_samples = self._upsample(val, own, hits, frame, sh)
        res.stats["rays"] += fill_rays  # pixels no grid sample could serve
        res.stats["samples"] += fill_samples
        res.stats["fill_samples"] = float(fill_samples)
        virt = hits.role == ROLE_VIRTUAL
        mixed = np.where(virt[..., None], full + self._phong(hits, camera, sh), 0.0)
        delta = np.where((hits.role == ROLE_REAL)[..., None], full, 0.0)
        bg = np.asarray(frame, np.float64)
        mixed = np.where(virt[..., None], mixed, bg + delta)
        res.mixed, res.delta = mixed.astype(np.float32), delta.astype(np.float32)
        res.mask = virt.astype(np.float32)

    def _e7(self, hits: Hits, frame: np.ndarray, rr: np.ndarray, cc: np.ndarray,
            t: Transfer, sh: np.ndarray) -> np.ndarray:
        """E7 at samples: virtual ``a_v/π T_mix·l``; real additive ``a/π (T_mix−T_real)·l``
        or ratio ``I_c (T_mix·l / T_real·l − 1)``.

        The model has no interreflection, so an occluder can only remove light: where the
        truncated SH rings negative in the blocked directions the delta would come out
        positive; it is clamped to ≤ 0 (ratio ≤ 1), and virtual radiance to ≥ 0."""
        a = hits.albedo[rr, cc]
        virt = (hits.role[rr, cc] == ROLE_VIRTUAL)[:, None]
        lm = t.mixed @ sh
        lr = t.real @ sh
        if self.settings.ratio:
            ic = np.asarray(frame, np.float64)[rr, cc]
            with np.errstate(divide="ignore", invalid="ignore"):
                ratio = np.where(lr > 1e-12, np.clip(lm / lr, 0.0, 1.0), 1.0)
            same = np.all(t.mixed == t.real, axis=1)[:, None]  # no change: exactly 0
            real = np.where(same, 0.0, ic * (ratio - 1.0))
        else:
            real = np.minimum(a / np.pi * ((t.mixed - t.real) @ sh), 0.0)
        return np.where(virt, np.maximum(a / np.pi * lm, 0.0), real)

    def _grid_weights(self, hits: Hits, nodes: np.ndarray
                      ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Per pixel, the 4 surrounding regular-grid nodes and their weights: bilinear ×
        (node is a sample of the same role); adaptive variants also require the node on the
        pixel's tangent plane (``plane_reject`` × depth) with agreeing normals. Returns
        ``[(node_row, node_col, weight)]`` ``(H, W)`` each."""
        s, st = self.variant.spacing, self.settings
        h, w = nodes.shape
        py, px = np.mgrid[0:h, 0:w]
        i0, j0 = py // s, px // s
        fy, fx = (py - i0 * s) / s, (px - j0 * s) / s
        out = []
        for di, dj, wt in ((0, 0, (1 - fy) * (1 - fx)), (0, 1, (1 - fy) * fx),
                           (1, 0, fy * (1 - fx)), (1, 1, fy * fx)):
            ny, nx = (i0 + di) * s, (j0 + dj) * s
            ok = (ny < h) & (nx < w)
            ny_, nx_ = np.minimum(ny, h - 1), np.minimum(nx, w - 1)
            ok &= nodes[ny_, nx_] & (hits.role[ny_, nx_] == hits.role)
            if self.variant.adaptive:
                off = np.einsum("hwc,hwc->hw", hits.position[ny_, nx_] - hits.position,
                                hits.normal)
                with np.errstate(invalid="ignore"):
                    ok &= np.abs(off) <= st.plane_reject * hits.z
                ok &= np.einsum("hwc,hwc->hw", hits.normal[ny_, nx_], hits.normal) \
                    >= st.normal_reject
            out.append((ny_, nx_, np.where(ok, wt + 1e-9, 0.0)))
        return out

    def unserved(self, hits: Hits, regular: np.ndarray) -> np.ndarray:
        """Valid pixels that no regular-grid sample may be interpolated into (adaptive:
        across a depth or normal edge): they get their own (dense) sample."""
        if self.variant.spacing == 1:
            return np.zeros_like(regular)
        wsum = sum(wt for _, _, wt in self._grid_weights(hits, regular))
        return hits.valid & ~regular & (wsum == 0)

    def _upsample(self, val: np.ndarray, own: np.ndarray, hits: Hits, frame: np.ndarray,
                  sh: np.ndarray) -> tuple[np.ndarray, int, int]:
        """Bilinear interpolation of the regular grid (:meth:`_grid_weights`) for pixels
        without their own sample. Adaptive variants gave every pixel no grid node serves a
        dense sample already (:meth:`unserved`); any left (naive variants: none is traced)
        gets its own sample here. Returns the image and the rays and samples those cost."""
        if self.variant.spacing == 1:
            return val, 0, 0
        acc = np.zeros(val.shape)
        wsum = np.zeros(own.shape)
        for ny_, nx_, wt in self._grid_weights(hits, own):
            acc += wt[..., None] * val[ny_, nx_]
            wsum += wt
        out = np.where(own[..., None], val, acc / np.maximum(wsum, 1e-300)[..., None])
        hole = ~own & (wsum == 0) & hits.valid
        if np.any(hole) and self.variant.adaptive:
            hr, hc = np.nonzero(hole)
            t = self._full(hits.position[hr, hc], hits.normal[hr, hc],
                           hits.role[hr, hc] == ROLE_REAL)
            out[hr, hc] = self._e7(hits, frame, hr, hc, t, sh)
            return out, t.rays, len(hr)
        return out, 0, 0


__all__ = ["MAX_STATE_CELLS", "VARIANTS", "FrameResult", "Hits", "PhaseCache", "Pipeline",
           "Settings", "StateGrid", "Variant", "primary_hits", "virtual_edges"]
