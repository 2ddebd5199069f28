"""Voxel volumes and cone tracing (Franke thesis §5.4, after Crassin et al. 2011 [CNS+11]).

* :func:`shape_triangles` — world-space triangles of a scene shape (meshes as they are;
  rectangles, disks, boxes and spheres tessellated).
* :func:`voxelize` — **conservative** voxelisation (every cell a triangle touches is marked,
  so thin geometry is never lost; the exact triangle/box separating-axis test of
  Akenine-Möller 2001, which is what Schwarz & Seidel's [SS10] conservative surface
  voxelisation computes): occupancy ``α ∈ {0, 1}`` and the area-weighted mean geometric
  normal per cell (``V_η``, thesis §5.4.2 "Scene Voxelization").
* :class:`MipVolume` / :func:`build_mips` — a packed Dr.Jit buffer of ``C`` channels per cell
  holding every level of the mip chain ``n³, (n/2)³, …, 1`` (box filter of 2×2×2 children,
  thesis §5.4.1 "Filtering": "hardware mipmapping", α included).
* :func:`trace_cones` — one Dr.Jit ``while_loop`` (a single kernel) that marches cones through
  the mip chains with front-to-back accumulation (Eq. 5.18–5.19 in the standard form, see
  below), returning the gathered radiance and two occlusions.

Radiometry of a cone sample (ours; the thesis gives the accumulation only). Level ``l`` has
cells of size ``s_l = s_0 2^l``; a cell of level ``l`` stores the mean of its ``8^l`` finest
cells. A surface crossing a block touches about ``4^l`` of them, so the block's coverage of
a ray is about ``2^l · mean α`` and the radiance it shows is its total intensity over its face
area, ``c_l = Σ I / s_l² = 2^l · mean I / s_0²`` (W sr⁻¹ m⁻²): for a lit plane of radiosity
``B`` both give ``α = 1`` and ``c = B/π`` at every level. A closed surface crosses a block
twice (front and back) while it covers it once, so the coverage used is
``α_l = min(1, max(1, 2^(l−1)) · mean α)`` (:data:`SHELLS`; only the lit side injects
light, so ``c_l`` keeps ``2^l``). Intensities are injected
as ``I = Φ/π`` (Eq. 5.17). Seen from behind its mean normal ``n̄`` (length ≤ 1 after
filtering) a cell's radiance is attenuated (``d`` the cone's
travel direction) by ``max(0, 1 − 4 <n̄, d>+)`` when the cones are given the normals: a lit
plane is dark from below, a cell with mixed normals is nearly isotropic.

Front-to-back accumulation, standard form ([CNS+11]; the thesis prints
``c = α₀c₀ + (1 − α₀)α_v c_v`` (Eq. 5.18), whose ``α₀`` factor on ``c₀`` would fade light
already gathered — the digest flags it as a probable typo, we use the standard form):

    c ← c + (1 − α) α_v c_v          α ← α + (1 − α) α_v

where ``α_v c_v`` is the premultiplied radiance ``c_l`` above. The cone's diameter at distance
``t`` is ``d(t) = max(s_0, 2 t tan(θ/2))``, its mip level ``l = log2(d / s_0) − 1``
(:data:`LEVEL_BIAS`; quadrilinear: trilinear in the two nearest levels, linear between
them), and the step is the cell size of that level, ``s_0 2^l = d/2`` (thesis §5.4.1: "the
step size coincides with the current voxel size"). Both from the cone's geometry (issue #33):

* **level**: a sample of level ``l`` sees the box filter of the mip chain (width ``s_l``,
  variance ``s_l²/12`` per axis) convolved with trilinear interpolation's tent (variance
  ``s_l²/6``): footprint variance ``s_l²/4``. The cone's cross-section, a disk of diameter
  ``d``, has the variance ``d²/16`` per axis; equal when ``s_l = d/2``, one level finer
  than the diameter's.
* **step**: the trilinear weights of a thin sheet at the samples ``t_k`` sum to 1 for any
  phase only when samples are one cell of the sampled level apart (a partition of unity);
  a step of ``d = 2 s_l`` (before issue #33) summed to 0–1 by phase — a lit plane read
  0.4–1.07 of its radiance and a 60° cone could step over it — while ``s_l`` reads
  0.83–1.0 (tested).

Occlusion is accumulated twice, against ``α_all`` (real + virtual geometry) and ``α_real``
(real geometry alone), and a third product keeps what the virtual objects take away from
the space the real geometry leaves free: ``k ← k · (1 − α_all)/(1 − α_real)`` per sample
(1 where ``α_real ≈ 1``). ``1 − k`` is the occlusion the virtual objects *add*. Unlike
``a_all − a_real`` it is not lost when a wide cone's coarse samples see the receiving
surface itself (self-occlusion saturates both ``a``'s, but cancels sample by sample in
``k``). Whether a real occluder already shadows the point is the caller's question (the
shadows of real occluders are in the photograph already).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.errors import InputError
from arlight.jit import aligned, opaque
from arlight.realtime.sh_volume import Grid
from arlight.scene.model import Shape

BYTES_PER_VOXEL = 4 * 11 * 3
"""Memory per finest cell while a frame is built (11 float32 channels: α_all, α_real,
normal, V_Δ, V_ρ; the mip chain adds 1/7; temporaries about 2×), bytes."""

BACK_FALLOFF = 4.0
"""A cell seen from behind its mean normal ``n̄`` shows ``max(0, 1 − 4 <n̄, d>+)`` of its
radiance: a clean surface goes dark 14° behind its plane, a cell of mixed normals
(``|n̄|`` small) stays nearly isotropic."""

FAR_START = 8.0
"""Cones attenuated by the virtual occlusion only (``alpha_for_light`` 2) also stop where
the whole scene is opaque (``a_all`` > ``stop_alpha``) beyond this many cells: near the
start ``a_all`` is the receiving surface's own false occlusion, farther on it is real
geometry in the way (no light through walls, and fewer steps)."""

SHELLS = 0.5
"""Coverage scale of a block of level ``l``: ``α_l = min(1, max(1, SHELLS · 2^l) · mean α)``
(ours; ``dvct`` option ``shells``). The derivation brackets it without fixing it: a sheet
seen at normal incidence covers ``2^l · mean α`` of the block (1), a sheet at a random
orientation half of that on average (|cos| averages 1/2), a closed convex body smaller than
the block a quarter (Cauchy: mean projected area = surface area / 4); 0.5, the middle of
that range, stays chosen on training worlds (issue #33: 1 lost 0.2 dB of median
changed_psnr on 6 training worlds with the derived step). Closed
objects cross a block twice, so 0.5 (bunny-box 32.3 → 33.3 dB, red-paper 28.7 → 31.3 dB:
Lucy's soft shadow had come out opaque). Re-chosen on 16 training worlds (issue #30,
``benchmarks/tune_realtime.py``): 0.25 won there, lost on the held-out worlds, and 0.5
stays (docs/methods/dvct.md)."""

LEVEL_BIAS = 1.0
"""Mip levels finer than ``log2(d / s_0)`` at which a cone of diameter ``d`` samples, derived
(module docstring): the box filter of the mip chain and the trilinear tent give a sample the
footprint variance ``s_l²/4``, the cone's disk ``d²/16``, equal at ``s_l = d/2``. (On
bunny-box the diameter's own level made the soft shadow 3× too deep in the mean; floor-shadow
RMSE 0.044 → 0.028 against ray tracing with the bias.)
``dvct`` option ``level_bias``; re-chosen on 16 training worlds (issue #30): 0 (with
``SHELLS`` 0.25) won there, lost on the held-out worlds, and 1 stays."""

ALPHA_CHANNELS = 2
"""``V_η`` occupancy channels: ``α_all`` (real + virtual), ``α_real``."""

COVER_CHANNELS = 6
"""Channels per cell of a directional occupancy volume: ``cover`` (:class:`Voxels`) of all
geometry (x, y, z) and of the real geometry (x, y, z)."""
ANISO_CHANNELS = 18
"""Channels per cell of an anisotropic radiance volume: RGB intensity emitted towards each
of the 6 axis directions ``+x, −x, +y, −y, +z, −z`` (slot ``2a + negative``), W/sr."""


# --------------------------------------------------------------------------------------------
# Triangles
# --------------------------------------------------------------------------------------------

def _unit_triangles(kind: str, segments: int = 32) -> np.ndarray:
    """Triangles ``(F, 3, 3)`` of Mitsuba's canonical primitives: rectangle and box span
    [−1, 1], disk and sphere have radius 1 (the frames of
    :data:`arlight.backend.mitsuba_scene._PRIMITIVE_CANONICAL`)."""
    if kind == "rectangle":
        q = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float64)
        return q[[[0, 1, 2], [0, 2, 3]]]
    if kind == "disk":
        a = np.linspace(0.0, 2.0 * math.pi, segments + 1)
        rim = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], 1)
        c = np.zeros((segments, 3))
        return np.stack([c, rim[:-1], rim[1:]], 1)
    if kind == "box":
        out = []
        for axis in range(3):
            for sign in (-1.0, 1.0):
                u, v = [(axis + 1) % 3, (axis + 2) % 3]
                quad = np.zeros((4, 3))
                quad[:, axis] = sign
                quad[:, u] = [-1, 1, 1, -1]
                quad[:, v] = [-1, -1, 1, 1]
                out += [quad[[0, 1, 2]], quad[[0, 2, 3]]]
        return np.array(out)
    if kind == "sphere":
        th = np.linspace(0.0, math.pi, segments // 2 + 1)
        ph = np.linspace(0.0, 2.0 * math.pi, segments + 1)
        t, p = np.meshgrid(th, ph, indexing="ij")
        v = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1)
        a, b = v[:-1, :-1], v[:-1, 1:]
        c, d = v[1:, 1:], v[1:, :-1]
        return np.concatenate([np.stack([a, b, c], 2).reshape(-1, 3, 3),
                               np.stack([a, c, d], 2).reshape(-1, 3, 3)])
    raise ValueError(f"no tessellation for shape type {kind!r}")


def _local_frame(shape: Shape) -> tuple[np.ndarray, np.ndarray]:
    """``(points, m)``: the shape's points in its own frame — a mesh's vertices ``(V, 3)``, a
    primitive's canonical triangles ``(F, 3, 3)`` — and the 4×4 ``m`` that takes them to
    world space (metres)."""
    m = np.asarray(shape.to_world, np.float64)
    if shape.type == "mesh":
        assert shape.mesh is not None
        return np.asarray(shape.mesh.vertices, np.float64), m
    from arlight.backend.mitsuba_scene import _PRIMITIVE_CANONICAL

    return _unit_triangles(shape.type), m @ _PRIMITIVE_CANONICAL[shape.type](shape.params)


def shape_triangles(shape: Shape) -> np.ndarray:
    """World-space triangles ``(F, 3, 3)`` float64 of ``shape`` (metres)."""
    pts, m = _local_frame(shape)
    tri = pts[np.asarray(shape.mesh.faces, np.int64)] if shape.type == "mesh" else pts
    return tri @ m[:3, :3].T + m[:3, 3]


def frame_box(shape: Shape) -> tuple[np.ndarray, float]:
    """``(centre, edge)`` of ``shape``'s bounding box in its own frame (metres): the centre
    of the box of its points (mesh vertices, canonical primitive) taken to world space, and
    the box's largest edge as the world sees it, ``max_k |m e_k| (hi_k − lo_k)`` (``m`` the
    shape's linear map). A rigid motion moves the centre with the shape and leaves the edge
    unchanged (up to rounding), unlike the edge of the world-axis bounding box, which
    changes as the shape turns (issue #32)."""
    pts, m = _local_frame(shape)
    pts = pts.reshape(-1, 3)
    lo, hi = pts.min(0), pts.max(0)
    centre = m[:3, :3] @ ((lo + hi) / 2.0) + m[:3, 3]
    return centre, float(np.max(np.linalg.norm(m[:3, :3], axis=0) * (hi - lo)))


# --------------------------------------------------------------------------------------------
# Conservative voxelisation
# --------------------------------------------------------------------------------------------

def check_memory(n: int, extra_channels: int = 0) -> None:
    """InputError (field ``options.volume_size``) when the volumes of ``n³`` cells would not
    fit in the available memory (``MemAvailable`` of ``/proc/meminfo``); ``extra_channels``
    float32 channels per cell beyond :data:`BYTES_PER_VOXEL`'s 11 (anisotropic radiance,
    directional occupancy)."""
    need = (BYTES_PER_VOXEL + 4 * 3 * extra_channels) * n ** 3 * 8 / 7
    try:
        with open("/proc/meminfo") as f:
            avail = next(int(x.split()[1]) * 1024 for x in f if x.startswith("MemAvailable:"))
    except (OSError, StopIteration):  # pragma: no cover - not Linux
        return
    if need > avail:
        raise InputError(f"volumes of {n}³ cells need about {need / 2**30:.1f} GiB; "
                         f"{avail / 2**30:.1f} GiB available", field="options.volume_size")


def _overlaps(v0: mi.Vector3f, v1: mi.Vector3f, v2: mi.Vector3f, h: float) -> mi.Bool:
    """Separating-axis test (Akenine-Möller 2001) of triangles given relative to the centres
    of axis-aligned boxes of half size ``h`` (one Dr.Jit lane per triangle/box pair): True
    where they overlap (touching counts, with a relative tolerance of 1e-6 so that faces on
    cell borders mark both cells)."""
    r_box = h * (1.0 + 1e-6)
    ok = mi.Bool(True)
    for ax in range(3):  # the box's face normals
        lo = dr.minimum(dr.minimum(v0[ax], v1[ax]), v2[ax])
        hi = dr.maximum(dr.maximum(v0[ax], v1[ax]), v2[ax])
        ok &= (lo <= r_box) & (hi >= -r_box)
    e = (v1 - v0, v2 - v1, v0 - v2)
    nrm = dr.cross(e[0], e[1])
    ok &= dr.abs(dr.dot(nrm, v0)) <= r_box * (dr.abs(nrm.x) + dr.abs(nrm.y) + dr.abs(nrm.z))
    for ei in e:  # the 9 axes e_i × unit axis: components (u, w) = (e_w, −e_u)
        for ax in range(3):
            u, w = (ax + 1) % 3, (ax + 2) % 3
            au, aw = ei[w], -ei[u]
            p0 = au * v0[u] + aw * v0[w]
            p1 = au * v1[u] + aw * v1[w]
            p2 = au * v2[u] + aw * v2[w]
            rr = r_box * (dr.abs(au) + dr.abs(aw))
            ok &= (dr.minimum(dr.minimum(p0, p1), p2) <= rr) & (
                dr.maximum(dr.maximum(p0, p1), p2) >= -rr)
    return ok


@dataclass
class Voxels:
    """A voxelised surface on a grid, sparse: the occupied cells' flat indices ``index (k,)``
    (sorted, unique; cell ``(i, j, l)`` at ``i + n (j + n l)``, x fastest) and
    ``normal_sum (k, 3)`` float64, the area-weighted sum of the geometric normals of the
    triangles touching each (``α = 1`` there, 0 elsewhere)."""

    grid: Grid
    index: np.ndarray
    normal_sum: np.ndarray
    cover: np.ndarray | None = None

    @staticmethod
    def empty(grid: Grid, with_cover: bool = False) -> Voxels:
        return Voxels(grid, np.zeros(0, np.int64), np.zeros((0, 3)),
                      np.zeros((0, 3)) if with_cover else None)

    @staticmethod
    def from_hits(grid: Grid, flat: np.ndarray, normals: np.ndarray,
                  covers: np.ndarray | None = None, with_cover: bool = False) -> Voxels:
        """Cells of ``flat`` (with repeats), their ``normals (m, 3)`` summed; with
        ``with_cover`` also the directional occupancy ``cover`` (k, 3): per axis ``a`` the
        largest ``|n_a|`` of the unit normals of the surfaces touching the cell
        (``covers (m, 3)``, by default from ``normals``) — the coverage of the cell's face
        ``⊥ e_a`` by a sheet crossing it; a ray along ``ω`` sees ``Σ_a |ω_a| cover_a``,
        exactly ``|<n, ω>|`` for an axis-aligned sheet, 1 along either axis of a cell
        holding two faces of a box. (Optional: it costs a sort of the hits.)"""
        idx, inv = np.unique(flat, return_inverse=True)
        ns = np.stack([np.bincount(inv, weights=normals[:, c], minlength=len(idx))
                       for c in range(3)], 1) if len(idx) else np.zeros((0, 3))
        cov = None
        if with_cover:
            if covers is None:
                length = np.linalg.norm(normals, axis=1, keepdims=True)
                covers = np.where(length > 0, np.abs(normals) / np.maximum(length, 1e-30),
                                  0.0)
            cov = np.zeros((len(idx), 3))
            if len(idx):
                order = np.argsort(inv, kind="stable")
                starts = np.concatenate([[0], np.cumsum(np.bincount(inv))[:-1]])
                for c in range(3):
                    cov[:, c] = np.maximum.reduceat(np.asarray(covers, np.float64)[order, c],
                                                    starts)
        return Voxels(grid, idx.astype(np.int64), ns, cov)

    def union(self, other: Voxels) -> Voxels:
        """Cells occupied by either; normals summed, covers the larger (kept only when
        both have them)."""
        both = self.cover is not None and other.cover is not None
        return Voxels.from_hits(self.grid, np.concatenate([self.index, other.index]),
                                np.concatenate([self.normal_sum, other.normal_sum]),
                                np.concatenate([self.cover, other.cover]) if both else None,
                                with_cover=both)

    @property
    def alpha(self) -> np.ndarray:
        """Dense occupancy ``(n³,)`` float32."""
        a = np.zeros(self.grid.n ** 3, np.float32)
        a[self.index] = 1.0
        return a

    def unit_normals(self) -> np.ndarray:
        """``normal_sum`` normalised (zero where the sum vanishes), ``(k, 3)``."""
        length = np.linalg.norm(self.normal_sum, axis=1, keepdims=True)
        return np.where(length > 0, self.normal_sum / np.maximum(length, 1e-30), 0.0)

    @property
    def occupied(self) -> int:
        return len(self.index)


def lattice_index(grid: Grid) -> np.ndarray:
    """The integer index ``k`` (3,) of a grid whose origin lies on its own cell lattice,
    ``origin = k · cell`` (ValueError otherwise)."""
    k = np.rint(np.asarray(grid.origin, np.float64) / grid.cell)
    if not np.allclose(k * grid.cell, grid.origin, rtol=0.0, atol=1e-9 * grid.cell):
        raise ValueError(f"grid origin {grid.origin} is not a multiple of its cell {grid.cell}")
    return k.astype(np.int64)


def voxelize(triangles: np.ndarray, grid: Grid, chunk: int = 1 << 20,
             with_cover: bool = False, lattice: bool = False) -> Voxels:
    """Conservative voxelisation of world-space triangles ``(F, 3, 3)`` into ``grid`` (thesis
    §5.4.2; [SS10]): every cell whose closed box the triangle touches is occupied (``α = 1``),
    and gets the triangle's area-weighted normal added (orientation from the winding).
    Triangles outside the grid are clipped away; degenerate ones mark the cells they touch
    with no normal. Candidates are the cells of each triangle's bounding box (NumPy),
    tested ``chunk`` at a time in one Dr.Jit kernel (float32 in cell units relative to
    the cell centre). ``with_cover``: also :attr:`Voxels.cover`.

    ``lattice`` (a grid whose origin is ``k · cell``, :func:`lattice_index`): positions in
    world cell units ``x / cell`` relative to the world cell's centre ``g + ½`` (``g = k + i``
    the world lattice index), so a cell's result does not depend on where the grid starts:
    a grid cut out of a larger one on the same lattice (:class:`LatticeVoxels`) holds
    bitwise what voxelising it directly gives (issue #32)."""
    tri = np.asarray(triangles, np.float64)
    if len(tri) == 0:
        return Voxels.empty(grid, with_cover)
    n, s = grid.n, grid.cell
    if lattice:  # world cell units, candidates relative to the grid's lattice index
        base = lattice_index(grid)
        local = tri / s
    else:  # cell units relative to the grid's origin
        base = np.zeros(3, np.int64)
        local = (tri - grid.origin) / s
    offset = base.astype(np.float64)
    mn, mx = local.min(1), local.max(1)
    lo = np.clip(np.floor(mn - 1e-6).astype(np.int64) - base, 0, n - 1)
    hi = np.clip(np.floor(mx + 1e-6).astype(np.int64) - base, 0, n - 1)
    inside = np.all(mx >= base - 1e-6, 1) & np.all(mn <= base + n + 1e-6, 1)
    tri, local, lo, hi = tri[inside], local[inside], lo[inside], hi[inside]
    ext = hi - lo + 1
    count = ext.prod(1)
    area_n = 0.5 * np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    starts = np.concatenate([[0], np.cumsum(count)])
    total = int(starts[-1])
    flats, norms = [], []
    tri_of = np.repeat(np.arange(len(count)), count)
    # per-column gathers (np.take of contiguous columns): fancy-indexing the (F, 3, 3) and
    # (F, 3) arrays by triangle was most of a frame's voxelisation (50 of 95 ms for 4k
    # triangles at 640×480)
    lo_c = [np.ascontiguousarray(lo[:, c]) for c in range(3)]
    ext_c = [np.ascontiguousarray(ext[:, c]) for c in range(2)]
    local_c = [[np.ascontiguousarray(local[:, j, c]) for c in range(3)] for j in range(3)]
    for a in range(0, total, chunk):
        b = min(total, a + chunk)
        t = tri_of[a:b]
        k = np.arange(a, b) - starts[t]
        ex0, ex1 = (np.take(e, t) for e in ext_c)
        ijk = (np.take(lo_c[0], t) + k % ex0, np.take(lo_c[1], t) + (k // ex0) % ex1,
               np.take(lo_c[2], t) + k // (ex0 * ex1))
        centre = [(ijk[c] + offset[c]) + 0.5 for c in range(3)]  # exact: integers and ½
        corners = [mi.Vector3f(*(aligned((np.take(local_c[j][c], t) - centre[c]), np.float32)
                                 for c in range(3))) for j in range(3)]
        hit = np.array(_overlaps(*corners, 0.5), dtype=bool)
        flats.append((ijk[0] + n * (ijk[1] + n * ijk[2]))[hit])
        norms.append(area_n[t[hit]])
    if not flats:
        return Voxels.empty(grid, with_cover)
    return Voxels.from_hits(grid, np.concatenate(flats), np.concatenate(norms),
                            with_cover=with_cover)


def voxelize_shapes(shapes: list[Shape], grid: Grid, with_cover: bool = False,
                    lattice: bool = False) -> Voxels:
    """:func:`voxelize` of the triangles of several shapes."""
    if not shapes:
        return Voxels.empty(grid, with_cover)
    return voxelize(np.concatenate([shape_triangles(s) for s in shapes]), grid,
                    with_cover=with_cover, lattice=lattice)


@dataclass
class LatticeVoxels:
    """Shapes voxelised once over a window of a world cell lattice (:func:`voxelize` with
    ``lattice``), from which every grid on the same lattice inside the window is cut
    (issue #32: a volume that follows a moving object keeps the real proxy's voxels while
    it stays in the window). ``voxels`` live on ``window``; ``cells`` ``(k, 3)`` int32 are
    their ``(i, j, l)`` in the window (decoded once)."""

    window: Grid
    voxels: Voxels
    cells: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.cells is None:
            i, m = self.voxels.index, self.window.n
            self.cells = np.stack([i % m, (i // m) % m, i // (m * m)], 1).astype(np.int32)

    @staticmethod
    def around(shapes: list[Shape], grid: Grid, with_cover: bool = False,
               margin: int | None = None) -> LatticeVoxels:
        """``shapes`` voxelised over the window of ``grid.n + 2·margin`` cells per edge
        centred on ``grid`` (``margin`` default ``grid.n / 2``: the grid can move half its
        edge each way)."""
        pad = grid.n // 2 if margin is None else int(margin)
        k = lattice_index(grid) - pad
        window = Grid(origin=k * grid.cell, cell=grid.cell, n=grid.n + 2 * pad)
        return LatticeVoxels(window, voxelize_shapes(shapes, window, with_cover, lattice=True))

    def cut(self, grid: Grid) -> Voxels | None:
        """The voxels of ``grid`` (same cell, inside the window; None otherwise): bitwise
        ``voxelize_shapes(shapes, grid, lattice=True)``, since a cell's result depends only
        on its world lattice index and the triangles' order."""
        if grid.cell != self.window.cell:
            return None
        off = lattice_index(grid) - lattice_index(self.window)
        n, m = grid.n, self.window.n
        if np.any(off < 0) or np.any(off + n > m):
            return None
        v = self.voxels
        # the grid's layers of z are one run of the sorted window indices
        a, b = np.searchsorted(v.index, [off[2] * m * m, (off[2] + n) * m * m])
        x, y = self.cells[a:b, 0] - off[0], self.cells[a:b, 1] - off[1]
        sel = np.flatnonzero((x >= 0) & (x < n) & (y >= 0) & (y < n)) + a
        ijk = self.cells[sel].astype(np.int64) - off
        # a box cut keeps the z, y, x order: the flat indices stay sorted
        return Voxels(grid, ijk[:, 0] + n * (ijk[:, 1] + n * ijk[:, 2]), v.normal_sum[sel],
                      None if v.cover is None else v.cover[sel])


BLOCKING_SUB = 2
"""Sub-cells per edge of a geometry-volume cell in :func:`blocking_potential`."""


def blocking_potential(triangles: np.ndarray, grid: Grid, sub: int = BLOCKING_SUB
                       ) -> np.ndarray:
    """[KD10]'s geometry volume (§5.3, "fuzzy occlusion") on the dual lattice of ``grid``:
    ``(n+1, n+1, n+1, 3)`` float32 indexed ``[z, y, x, axis]``, cell ``(i, j, k)`` centred
    on the LPV cell corner ``origin + s (i, j, k)``; per travel axis ``a`` the blocking
    potential ``B_a = min(1, Σ A_i |<n_i, e_a>| / s²)`` of the surfaces inside (KD10:
    ``B(ω) = A_s s⁻² <n_s, ω>``, here in the three axis directions the propagation uses).
    The surface area is measured by conservative voxelisation at ``sub`` × the resolution:
    each occupied sub-cell of unit mean normal ``n̂`` stands for ``(s/sub)²`` of area, so a
    plane crossing a cell perpendicular to ``e_a`` gives ``B_a = 1`` and ``B`` = 0 for
    light travelling parallel to it. Triangles ``(F, 3, 3)`` in world metres."""
    n = grid.n
    fine = Grid(origin=np.asarray(grid.origin, np.float64) - 0.5 * grid.cell,
                cell=grid.cell / sub, n=(n + 1) * sub)
    out = np.zeros(((n + 1) ** 3, 3), np.float64)
    vox = voxelize(triangles, fine)
    if vox.occupied:
        m = fine.n
        i = vox.index
        x, y, z = i % m // sub, (i // m) % m // sub, i // (m * m) // sub
        cell = x + (n + 1) * (y + (n + 1) * z)
        np.add.at(out, cell, np.abs(vox.unit_normals()))
    out = np.minimum(out / (sub * sub), 1.0)
    return out.reshape(n + 1, n + 1, n + 1, 3).astype(np.float32)


# --------------------------------------------------------------------------------------------
# Mip chains
# --------------------------------------------------------------------------------------------

@dataclass
class MipVolume:
    """``C`` channels per cell on every level of a mip chain, one packed Dr.Jit buffer.

    Level ``l`` has ``n_l = n >> l`` cells per edge, its cells start at ``offsets[l]``;
    channel ``c`` of cell ``i`` (flat, x fastest) of level ``l`` is
    ``data[(offsets[l] + i) · C + c]``. Every level is the 2×2×2 box filter of the one below.
    """

    grid: Grid
    channels: int
    data: mi.Float
    offsets: list[int]

    @property
    def levels(self) -> int:
        return len(self.offsets)

    def level(self, lvl: int) -> np.ndarray:
        """Level ``lvl`` as ``(n_l, n_l, n_l, C)`` float32 indexed ``[z, y, x, c]``."""
        n = self.grid.n >> lvl
        a = self.offsets[lvl] * self.channels
        arr = np.asarray(self.data, np.float32)[a:a + n ** 3 * self.channels]
        return arr.reshape(n, n, n, self.channels)


_PACKETS = {1: mi.Float, 2: mi.Vector2f, 3: mi.Vector3f, 4: mi.Vector4f}


def _downsample(src: mi.Float, n: int, channels: int) -> mi.Float:
    """2×2×2 mean of a packed level of ``n³`` cells (one Dr.Jit kernel, one lane per output
    cell, the ``C`` channels of a cell gathered as one packet)."""
    m = n // 2
    cell = dr.arange(mi.UInt32, m ** 3)
    x, y, z = (cell % m) * 2, ((cell // m) % m) * 2, (cell // (m * m)) * 2
    # packets of up to 4 channels; more (anisotropic radiance: 6 directions × RGB) as
    # ``channels / 3`` packets of 3
    width, groups = (channels, 1) if channels in _PACKETS else (3, channels // 3)
    if width * groups != channels:
        raise ValueError(f"mip chains of {channels} channels: not a multiple of 3")
    kind = _PACKETS[width]
    out = dr.zeros(mi.Float, m ** 3 * channels)
    for g in range(groups):
        acc = dr.zeros(kind, m ** 3)
        for dz in (0, 1):
            for dy in (0, 1):
                for dx in (0, 1):
                    child = (x + dx) + n * ((y + dy) + n * (z + dz))
                    acc += dr.gather(kind, src, child * groups + g)
        dr.scatter(out, acc * 0.125, cell * groups + g)
    return out


def build_mips(level0: mi.Float | np.ndarray, grid: Grid, channels: int) -> MipVolume:
    """The mip chain of a packed finest level (``n³ · C`` values, cell-major) down to one
    cell (thesis §5.4.1 "Filtering"). ``grid.n`` must be a power of two."""
    n = grid.n
    if n & (n - 1):
        raise ValueError(f"mip chains need a power-of-two size, got {n}")
    cur = mi.Float(aligned(level0, np.float32)) if isinstance(level0, np.ndarray) else level0
    parts, offsets, off = [cur], [0], 0
    while n > 1:
        off += n ** 3
        cur = _downsample(cur, n, channels)
        dr.eval(cur)
        n //= 2
        parts.append(cur)
        offsets.append(off)
    data = dr.concat(parts) if len(parts) > 1 else parts[0]
    dr.eval(data)
    return MipVolume(grid, channels, data, offsets)


def pack(*arrays: np.ndarray) -> np.ndarray:
    """Cell-major packing of per-cell arrays ``(m,)`` or ``(m, k)`` into one float32
    ``(m · C,)`` buffer."""
    cols = [a.reshape(len(a), -1) for a in arrays]
    return np.ascontiguousarray(np.concatenate(cols, 1), np.float32).ravel()


# --------------------------------------------------------------------------------------------
# Cone tracing
# --------------------------------------------------------------------------------------------

def cover_level0(real: Voxels, virtual: Voxels, both: Voxels | None = None) -> mi.Float:
    """Packed finest level of the directional occupancy (:data:`COVER_CHANNELS`): per cell
    the ``cover`` of real ∪ virtual geometry (``both``, when the caller has it) and of the
    real geometry alone."""
    both = real.union(virtual) if both is None else both
    if both.cover is None or real.cover is None:
        raise ValueError("cover_level0 needs voxels made with_cover")
    out = np.zeros((real.grid.n ** 3, 6), np.float32)
    out[both.index, :3] = both.cover
    out[real.index, 3:] = real.cover
    return mi.Float(aligned(out.ravel(), np.float32))


def eta_level0(real: Voxels, virtual: Voxels, both: Voxels | None = None
               ) -> tuple[mi.Float, mi.Float]:
    """Packed finest levels of ``V_η`` as Dr.Jit buffers: occupancy (2 channels,
    ``α_all = max(α_real, α_virtual)`` and ``α_real``) and the unit mean normal (3);
    ``both``: ``real.union(virtual)`` when the caller has it."""
    both = real.union(virtual) if both is None else both
    m = real.grid.n ** 3
    alpha = dr.zeros(mi.Float, m * 2)
    normal = dr.zeros(mi.Float, m * 3)
    if both.occupied:
        ib = mi.UInt32(aligned(both.index, np.uint32))
        dr.scatter(alpha, 1.0, ib * 2)
        unit = both.unit_normals().astype(np.float32)
        for c in range(3):
            dr.scatter(normal, mi.Float(aligned(unit[:, c], np.float32)), ib * 3 + c)
    if real.occupied:
        dr.scatter(alpha, 1.0, mi.UInt32(aligned(real.index, np.uint32)) * 2 + 1)
    dr.eval(alpha, normal)
    return alpha, normal


@dataclass
class ConeVolumes:
    """What cones read: ``alpha`` (V_η occupancy: ``α_all``, ``α_real``) and, for radiance
    cones, ``light`` (3 channels: V_Δ, V_ρ or V_µ intensities, W/sr) and optionally
    ``normal`` (V_η mean normal, 3 channels: back-face attenuation). All on the same grid."""

    alpha: MipVolume
    normal: MipVolume | None = None
    light: MipVolume | None = None
    occluded: MipVolume | None = None
    cover: MipVolume | None = None


def box_interval(grid: Grid, o: mi.Point3f, d: mi.Vector3f) -> tuple[mi.Float, mi.Float]:
    """Slab test: ``(t_in, t_out)`` of rays ``o + t d`` through the grid's cube (empty when
    ``t_in > t_out``)."""
    lo, hi = grid.lo(), grid.hi()
    t0, t1 = mi.Float(-dr.inf), mi.Float(dr.inf)
    for k in range(3):
        dk = d[k]
        inv = dr.rcp(dr.select(dr.abs(dk) > 1e-12, dk, 1e-12))
        a = (lo[k] - o[k]) * inv
        b = (hi[k] - o[k]) * inv
        t0 = dr.maximum(t0, dr.minimum(a, b))
        t1 = dr.minimum(t1, dr.maximum(a, b))
    return t0, t1


def _level_tables(vol: MipVolume) -> tuple[mi.UInt32, mi.UInt32]:
    return (mi.UInt32(np.asarray(vol.offsets, np.uint32)),
            mi.UInt32(np.array([vol.grid.n >> k for k in range(vol.levels)], np.uint32)))


def aniso_lookup(direction: mi.Vector3f) -> list[tuple[mi.UInt32, mi.Float]]:
    """Per axis ``a``, the slot of an anisotropic radiance volume
    (:data:`ANISO_CHANNELS`) that a cone travelling along ``direction`` sees — the light
    emitted towards ``ω = −direction``, slot ``2a + (ω_a < 0)`` — and its weight ``|ω_a|``
    (module docstring)."""
    return [(dr.select(direction[a] > 0.0, mi.UInt32(2 * a + 1), mi.UInt32(2 * a)),
             dr.abs(direction[a])) for a in range(3)]


def _sample_level(vols: list[MipVolume], tables: tuple[mi.UInt32, mi.UInt32], grid: Grid,
                  p: mi.Point3f, lvl: mi.UInt32, active: mi.Bool,
                  aniso: list[tuple[mi.UInt32, mi.Float]] | None = None) -> list:
    """Trilinear samples (cell centres, zero outside) of level ``lvl`` of every volume in
    ``vols`` at world points ``p``: one value per volume, of ``C`` channels (``mi.Float``,
    ``mi.Vector2f``, ``mi.Vector3f``); an anisotropic radiance volume
    (:data:`ANISO_CHANNELS`) gives the RGB ``Σ_a w_a c_slot(a)`` of ``aniso``
    (:func:`aniso_lookup`)."""
    offsets, sizes = tables
    off = dr.gather(mi.UInt32, offsets, lvl, active)
    n_l = dr.gather(mi.UInt32, sizes, lvl, active)
    nf = mi.Float(n_l)
    inv = nf * grid.inv(grid.size)
    o = grid.lo()
    f = [(p[k] - o[k]) * inv - 0.5 for k in range(3)]
    i0 = [mi.Int32(dr.floor(fk)) for fk in f]
    w1 = [fk - mi.Float(ik) for fk, ik in zip(f, i0, strict=True)]
    ni = mi.Int32(n_l)
    types = {1: mi.Float, 2: mi.Vector2f, 3: mi.Vector3f}
    out = [None] * len(vols)
    for corner in range(8):
        c = [i0[k] + ((corner >> k) & 1) for k in range(3)]
        w = mi.Float(1.0)
        for k in range(3):
            w *= w1[k] if (corner >> k) & 1 else 1.0 - w1[k]
        ok = active & (c[0] >= 0) & (c[1] >= 0) & (c[2] >= 0) & (c[0] < ni) & (c[1] < ni) & (
            c[2] < ni)
        cell = off + mi.UInt32(c[0] + ni * (c[1] + ni * c[2]))
        for j, v in enumerate(vols):
            if v.channels == COVER_CHANNELS:  # projected: (Σ|ω_a| cover_all,a, … real)
                assert aniso is not None, "directional occupancy needs the cone's direction"
                w3 = mi.Vector3f(*(wa for _, wa in aniso))
                ca = dr.gather(mi.Vector3f, v.data, cell * 2, ok)
                cr = dr.gather(mi.Vector3f, v.data, cell * 2 + 1, ok)
                val = mi.Vector2f(dr.dot(ca, w3), dr.dot(cr, w3))
            elif v.channels == ANISO_CHANNELS:
                assert aniso is not None, "anisotropic radiance needs the cone's direction"
                val = mi.Vector3f(0.0)
                for slot, wa in aniso:
                    val += dr.gather(mi.Vector3f, v.data, cell * 6 + slot, ok) * wa
            else:
                val = dr.gather(types[v.channels], v.data, cell, ok)
            out[j] = val * w if out[j] is None else out[j] + val * w
    return out


@dataclass
class ConeResult:
    """Per lane: ``radiance`` (the accumulated ``c``, W sr⁻¹ m⁻², zero for shadow cones),
    ``a_all`` and ``a_real`` (accumulated occlusion by all / by real geometry, in [0, 1])
    and ``keep`` (the transmittance left by the virtual objects alone, module docstring)."""

    radiance: mi.Color3f
    a_all: mi.Float
    a_real: mi.Float
    keep: mi.Float

    @property
    def added(self) -> mi.Float:
        """The occlusion the virtual objects add, ``1 − keep`` in [0, 1]."""
        return 1.0 - self.keep


def trace_cones(vols: ConeVolumes, origin: mi.Point3f, direction: mi.Vector3f,
                tan_half: mi.Float | float, t_max: mi.Float | float, active: mi.Bool,
                t_start: float = 0.0, stop_alpha: float = 0.99,
                alpha_for_light: int = 0, quadrilinear: bool = True,
                level_bias: float = LEVEL_BIAS, shells: float = SHELLS) -> ConeResult:
    """March cones ``origin + t · direction`` of half-angle ``atan(tan_half)`` through the
    mip chains (see the module docstring), from ``max(t_start, box entry)`` to
    ``min(t_max, box exit)``. One symbolic ``dr.while_loop`` (a single kernel for all lanes).

    ``alpha_for_light``: which occlusion attenuates the gathered radiance, 0 ``α_all`` (the
    mixed scene, ``C_ρ`` and ``C_Δ``), 1 ``α_real`` (the real scene, ``C_µ``) or 2 ``keep``
    (the virtual objects' occlusion only). A lane stops
    when both occlusions exceed ``stop_alpha`` (or, for radiance cones, the attenuating one).
    ``quadrilinear`` False samples only the nearest level (half the gathers; for wide cones).
    ``level_bias``: levels finer than the diameter's (:data:`LEVEL_BIAS`); ``shells``: the
    coverage scale of a level-``l`` block, ``α_l = min(1, max(1, shells · 2^l) · mean α)``
    (:data:`SHELLS`).
    """
    alpha = vols.alpha
    grid = alpha.grid
    # the cell as opaque scalars: it changes as the objects turn (with several objects the
    # volume fits their box), and as literals it compiled new cone kernels on every moving
    # frame (issue #32; the same float32 values, so the same results)
    s0 = opaque(grid.cell)
    inv_s0, inv_area = opaque(1.0 / grid.cell), opaque(1.0 / (grid.cell * grid.cell))
    sq_cell = opaque(grid.cell * grid.cell)
    levels = alpha.levels
    t_in, t_out = box_interval(grid, origin, direction)
    t = dr.maximum(t_in, opaque(t_start) if isinstance(t_start, float | int) else t_start)
    t_end = dr.minimum(t_out, t_max)
    tan_h = mi.Float(tan_half)
    # lanes without a direction (G-buffer samples of no surface) never leave their start
    act = mi.Bool(active) & (t < t_end) & (dr.squared_norm(direction) > 0.0)
    c = mi.Color3f(0.0)
    a_all = mi.Float(0.0)
    a_real = mi.Float(0.0)
    keep = mi.Float(1.0)
    tables = _level_tables(alpha)
    light = vols.light
    occ = vols.occluded if light is not None else None
    if occ is not None and int(alpha_for_light) != 2:
        raise ValueError("occluded bounce light needs alpha_for_light 2 (keep)")
    stop = float(stop_alpha)
    light_alpha = int(alpha_for_light)  # 0 α_all, 1 α_real, 2 keep (virtual occlusion only)
    max_lvl = float(levels - 1)
    quad = bool(quadrilinear)
    far_start = opaque(FAR_START * grid.cell)
    cover = vols.cover if light is not None else None
    aniso = aniso_lookup(direction) if light is not None and (
        light.channels == ANISO_CHANNELS or cover is not None) else None
    if occ is not None and occ.channels != light.channels:
        raise ValueError("the occluded volume must have the light volume's channels")
    # opaque: one compiled kernel for every value (benchmarks/tune_realtime.py sweeps them)
    bias = dr.opaque(mi.Float, float(level_bias))
    shell = dr.opaque(mi.Float, float(shells))

    def cond(t, c, a_all, a_real, keep, act):
        return act

    def body(t, c, a_all, a_real, keep, act):
        diam = dr.maximum(s0, 2.0 * t * tan_h)
        lvl_f = dr.clip(dr.log2(diam * inv_s0) - bias, 0.0, max_lvl)
        p = origin + direction * t
        vs = [alpha] if light is None else (
            [alpha if cover is None else cover, light] + ([] if occ is None else [occ])
            + ([] if vols.normal is None else [vols.normal]))
        if quad:
            l0 = mi.UInt32(dr.floor(lvl_f))
            l1 = dr.minimum(l0 + 1, levels - 1)
            fr = lvl_f - mi.Float(l0)
            samples = []
            for lv in (l0, l1):
                s = _sample_level(vs, tables, grid, p, lv, act, aniso)
                scale = dr.exp2(mi.Float(lv))  # 2^l: block coverage / face area (docstring)
                samples.append((s, scale))
            (s_a, k_a), (s_b, k_b) = samples
        else:
            l0 = mi.UInt32(dr.floor(lvl_f + 0.5))
            fr = mi.Float(0.0)
            s_a = s_b = _sample_level(vs, tables, grid, p, l0, act, aniso)
            k_a = k_b = dr.exp2(mi.Float(l0))

        def mix(xa, xb):
            return xa * (1.0 - fr) + xb * fr

        al_a, al_b = s_a[0], s_b[0]
        ka, kb = dr.maximum(k_a * shell, 1.0), dr.maximum(k_b * shell, 1.0)
        al_all = mix(dr.minimum(al_a[0] * ka, 1.0), dr.minimum(al_b[0] * kb, 1.0))
        al_real = mix(dr.minimum(al_a[1] * ka, 1.0), dr.minimum(al_b[1] * kb, 1.0))
        if light is not None:
            rad = mi.Color3f(mix(s_a[1] * k_a, s_b[1] * k_b)) * inv_area
            front = mi.Float(1.0)
            if vols.normal is not None:
                nrm = mix(s_a[-1], s_b[-1])
                front = dr.maximum(1.0 - BACK_FALLOFF * dr.maximum(dr.dot(nrm, direction),
                                                                   0.0), 0.0)
            rad *= front
            vis = (1.0 - a_all) if light_alpha == 0 else (
                (1.0 - a_real) if light_alpha == 1 else keep)
            if occ is None:
                c = dr.select(act, c + rad * vis, c)
            else:  # Δ·keep − (1 − keep)·µ with µ = ρ − Δ (module docstring)
                rad_o = mi.Color3f(mix(s_a[2] * k_a, s_b[2] * k_b)) * (front / sq_cell)
                c = dr.select(act, c + rad - rad_o * (1.0 - keep), c)
        a_all = dr.select(act, a_all + (1.0 - a_all) * al_all, a_all)
        a_real = dr.select(act, a_real + (1.0 - a_real) * al_real, a_real)
        free = 1.0 - al_real
        ratio = dr.select(free > 1e-3, dr.clip((1.0 - al_all) / dr.maximum(free, 1e-3), 0.0,
                                                1.0), 1.0)
        keep = dr.select(act, keep * ratio, keep)
        t = t + dr.maximum(s0, s0 * dr.exp2(lvl_f))  # the sampled level's cell (docstring)
        if light is None:
            done = keep < 1.0 - stop
        else:
            if light_alpha < 2:
                done = (a_all if light_alpha == 0 else a_real) > stop
            else:  # past the start, where self-occlusion fills a_all, the scene blocks too
                done = (keep < 1.0 - stop) | ((a_all > stop) & (t > far_start))
        act = act & (t < t_end) & ~done
        return t, c, a_all, a_real, keep, act

    state = dr.while_loop((t, c, a_all, a_real, keep, act), cond, body,
                          labels=("t", "c", "a_all", "a_real", "keep", "act"), label="cone")
    # the march once, its four outputs in one kernel: left unevaluated, every later
    # evaluation of one of them (each of dvct's block sums, ``added = 1 − keep``) ran the
    # whole loop again — five marches per diffuse_cones call (world-13 at 640×480: the
    # real lanes' cones 0.55 s → 0.18 s of loop kernels)
    dr.eval(*state[1:5])
    return ConeResult(*state[1:5])


__all__ = ["ALPHA_CHANNELS", "ANISO_CHANNELS", "BLOCKING_SUB", "BYTES_PER_VOXEL",
           "COVER_CHANNELS", "ConeResult", "ConeVolumes", "LatticeVoxels", "aniso_lookup",
           "cover_level0", "frame_box", "lattice_index",
           "MipVolume", "Voxels", "blocking_potential", "box_interval", "build_mips",
           "check_memory", "eta_level0", "pack", "shape_triangles", "trace_cones", "voxelize",
           "voxelize_shapes"]
