"""2-band (4-coefficient) RGB spherical-harmonic volumes: light propagation volumes (LPVs).

A volume holds, per cell, the radiant intensity ``I(ω)`` (W/sr) of the light in that cell as
2-band real SH, one coefficient vector per colour channel (Kaplanyan & Dachsbacher 2010,
"Cascaded light propagation volumes" [KD10]; Franke 2013 §4.2, thesis §5.3.1: "three RGBA 3-D
textures"). Coefficients are ordered ``l(l+1)+m`` and use the basis of
:mod:`arlight.sphere.sh` (polar axis +y): ``Y_00 = 0.282095``,
``(Y_1-1, Y_10, Y_11) = 0.488603 · (−x, y, z)``.

* :func:`cosine_lobe` — SH of a clamped cosine lobe ``<d, ω>+`` (the shape of every injected
  VPL, Franke Eq. 12, and of the reprojected face fluxes of [KD10]).
* :func:`inject` — scatter-add lobes of given flux at points (Dr.Jit).
* :func:`propagation_matrices` / :func:`propagate` — [KD10] face-flux propagation as a
  gather: each cell collects, from each of its 6 neighbours, the flux that crosses the 5
  faces of the cell not shared with that neighbour, evaluated from the neighbour's SH towards
  each face centre, multiplied by the face's solid angle and reprojected as a cosine lobe
  through that face. The whole step is linear: one 4×4 matrix per axis direction. Optional
  dampening by the directional derivative of the intensity (Franke §4.4, [KD10]).
  :func:`propagate_numpy` is the plain NumPy peer (same maths, for tests and benchmarks).
* :func:`query_irradiance` — trilinear lookup and the irradiance a surface of normal ``n``
  receives: the SH evaluated "with the inverse normal" (Franke Alg. 1) after convolution with
  the clamped cosine, ``E(n) = Σ_l Â_l Σ_m c_lm Y_lm(−n) / s²`` with ``Â_0 = π``,
  ``Â_1 = 2π/3`` and ``s`` the cell size (radiance ≈ intensity / s², [KD10]).

Units: positions in metres (world), flux in W, intensities in W/sr, irradiance in W/m².
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.jit import FREEZE_LOCK, aligned, opaque
from arlight.realtime.exact_sum import scatter_sum_exact
from arlight.realtime.shading import on_active

Y00 = 0.5 / math.sqrt(math.pi)
"""``Y_00 = 1/(2√π) ≈ 0.282095``."""
Y1 = math.sqrt(3.0 / (4.0 * math.pi))
"""Band-1 normalisation ``√(3/4π) ≈ 0.488603``."""
COS_LOBE_0 = math.sqrt(math.pi) / 2.0
"""SH band-0 coefficient of the clamped cosine ``<d, ω>+``: ``√π/2 ≈ 0.886227``."""
COS_LOBE_1 = math.sqrt(math.pi / 3.0)
"""Band-1 factor of the clamped cosine: ``√(π/3) ≈ 1.023328`` (times ``Y_1m(d)/Y1``)."""
A_HAT = (math.pi, 2.0 * math.pi / 3.0)
"""Clamped-cosine convolution weights ``Â_0 = π``, ``Â_1 = 2π/3`` (Ramamoorthi & Hanrahan)."""

AXES = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]],
                dtype=np.int64)
"""The 6 propagation directions (source → destination offsets), in this order."""


def basis(d: np.ndarray) -> np.ndarray:
    """2-band SH basis ``(..., 4)`` of unit directions ``d (..., 3)`` (NumPy)."""
    d = np.asarray(d, np.float64)
    return np.stack([np.full(d.shape[:-1], Y00), -Y1 * d[..., 0], Y1 * d[..., 1],
                     Y1 * d[..., 2]], axis=-1)


def cosine_lobe(d: np.ndarray) -> np.ndarray:
    """SH coefficients ``(..., 4)`` of ``<d, ω>+`` for unit ``d``; ``∫ <d,ω>+ dω = π``."""
    b = basis(d)
    return np.concatenate([np.full(b.shape[:-1] + (1,), COS_LOBE_0),
                           b[..., 1:] * (COS_LOBE_1 / Y1)], axis=-1)


def rect_solid_angle(dist: float, a: float, b: float) -> float:
    """Solid angle (sr) of an ``2a × 2b`` rectangle centred on the axis at distance ``dist``:
    ``4 atan(ab / (d √(d² + a² + b²)))``."""
    return 4.0 * math.atan(a * b / (dist * math.sqrt(dist * dist + a * a + b * b)))


def face_solid_angles() -> tuple[float, float]:
    """[KD10] solid angles (sr) of the destination cell's faces seen from the source centre:
    the far face at 1.5 cells (``≈ 0.4006697``) and each of the 4 side faces
    (``≈ 0.4234414``); together they subtend the shared face, ``2π/3``."""
    front = rect_solid_angle(1.5, 0.5, 0.5)
    side = (2.0 * math.pi / 3.0 - front) / 4.0
    return front, side


def propagation_matrices() -> np.ndarray:
    """``(6, 4, 4)`` matrices ``M_d``: the coefficients a cell receives from its neighbour at
    ``−AXES[d]`` are ``M_d @ c_neighbour`` ([KD10] §5.2).

    For each of the 5 faces f (far face: evaluation direction ``ω_f = d``, reprojection
    normal ``d``; side face with axis ``s``: ``ω_f = normalize(d + s/2)``, normal ``s``), the
    flux through f is ``Φ_f = Δω_f · I(ω_f)`` (W) and re-enters the destination as the lobe
    ``Φ_f/π · <n_f, ω>+``: ``M_d = Σ_f (Δω_f/π) cosine_lobe(n_f) ⊗ basis(ω_f)``.
    The band-0 row sums to exactly 1 over the 6 directions: flux is conserved.
    """
    front, side = face_solid_angles()
    out = np.zeros((6, 4, 4))
    for k, d in enumerate(AXES.astype(np.float64)):
        out[k] += front / math.pi * np.outer(cosine_lobe(d), basis(d))
        for s in AXES.astype(np.float64):
            if abs(s @ d) > 0.5:
                continue
            w = (d + 0.5 * s) / np.linalg.norm(d + 0.5 * s)
            out[k] += side / math.pi * np.outer(cosine_lobe(s), basis(w))
    return out


LATTICE_BLOCKS = 4
"""Positions of a volume per edge length on the fixed world lattice of
:meth:`Grid.on_lattice`: the origin moves in steps of ``n / LATTICE_BLOCKS`` cells."""


@dataclass(frozen=True)
class Grid:
    """An axis-aligned cubic grid of ``n³`` cells of size ``cell`` (m) from ``origin``."""

    origin: np.ndarray
    cell: float
    n: int

    @property
    def size(self) -> float:
        """Edge length of the volume, metres."""
        return self.cell * self.n

    @property
    def centre(self) -> np.ndarray:
        return self.origin + 0.5 * self.size

    def lo(self) -> list[mi.Float]:
        """The origin as opaque Dr.Jit scalars: a kernel reading it serves the volume
        wherever it moves with its object (a literal compiled a new kernel per position)."""
        return [opaque(x) for x in self.origin]

    def hi(self) -> list[mi.Float]:
        """The far corner (origin + size, summed in float64 as before) as opaque scalars."""
        return [opaque(float(x) + self.size) for x in self.origin]

    def inv(self, length: float) -> mi.Float:
        """``1 / length`` (e.g. the cell or the edge, metres) as an opaque scalar."""
        return opaque(1.0 / length)

    @staticmethod
    def around(lo: np.ndarray, hi: np.ndarray, n: int, scale: float = 2.0) -> Grid:
        """Franke's placement (thesis §4.4.1, §5.3): a cube of edge ``scale`` × the largest
        edge of the bounding box ``[lo, hi]``, world-axis aligned, its centre snapped to the
        cell lattice so that small motions of the object do not shift the cells (the volume
        stays axis-stable)."""
        lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
        edge = max(float(np.max(hi - lo)), 1e-6) * scale
        cell = edge / n
        centre = np.round((lo + hi) / 2.0 / cell) * cell
        return Grid(origin=centre - edge / 2.0, cell=cell, n=int(n))


    @staticmethod
    def on_lattice(lo: np.ndarray, hi: np.ndarray, n: int, scale: float = 2.0,
                   blocks: int = LATTICE_BLOCKS) -> Grid:
        """A volume on a fixed world lattice (issue #32): the cube that :meth:`around`
        would place, its cell size rounded up to ``2^(k/8)`` m (integer ``k``, steps of 9 %)
        and its origin a multiple of ``n/blocks`` cells, the one that centres the bounding
        box ``[lo, hi]`` best. With ``blocks`` = 4 the box (at most ``n/scale`` cells wide)
        keeps a margin of at least ``n (1/2 − 1/scale)/2 − n/(2·blocks)`` cells (``n/8``
        at scale 2), and the volume moves only when the box's centre crosses the middle
        between two lattice positions — every ``n/blocks`` cells of motion, not every cell
        — so moving an object within it keeps the real-only state (voxels, RSMs) valid.
        Depends on the box alone: preparing the posed world places the same volume."""
        lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
        edge = max(float(np.max(hi - lo)), 1e-6) * scale
        cell = 2.0 ** (math.ceil(8.0 * math.log2(edge / n) - 1e-9) / 8.0)
        step = cell * (n // blocks if n >= blocks else 1)
        size = cell * n
        k = np.round(((lo + hi) / 2.0 - size / 2.0) / step)
        return Grid(origin=k * step, cell=cell, n=int(n))


@dataclass
class SHVolume:
    """``n³`` cells × 4 SH coefficients × RGB: ``coeffs[k]`` is a ``mi.Color3f`` of ``n³``
    entries, cell ``(i, j, l)`` at flat index ``i + n (j + n l)`` (x fastest)."""

    grid: Grid
    coeffs: list

    @staticmethod
    def zeros(grid: Grid) -> SHVolume:
        m = grid.n ** 3
        return SHVolume(grid, [dr.zeros(mi.Color3f, m) for _ in range(4)])

    def numpy(self) -> np.ndarray:
        """``(n, n, n, 4, 3)`` float64 array indexed ``[z, y, x, k, c]``."""
        n = self.grid.n
        arr = np.stack([np.array(c, dtype=np.float64).reshape(3, -1).T for c in self.coeffs],
                       axis=1)
        return arr.reshape(n, n, n, 4, 3)

    @staticmethod
    def from_numpy(grid: Grid, arr: np.ndarray) -> SHVolume:
        n = grid.n
        flat = np.asarray(arr, np.float32).reshape(n ** 3, 4, 3)
        return SHVolume(grid, [mi.Color3f(*(np.ascontiguousarray(flat[:, k, c])
                                             for c in range(3))) for k in range(4)])

    def total_flux(self) -> np.ndarray:
        """``∫ I dω`` summed over cells, RGB (W): ``Σ c_00 · √(4π)``."""
        return _channel_sums(self.coeffs[0]) * math.sqrt(4.0 * math.pi)


def _channel_sums(c: mi.Color3f) -> np.ndarray:
    """Sum over lanes of each channel, float64 ``(3,)``."""
    return np.array([float(np.sum(np.array(ch, dtype=np.float64))) for ch in (c.x, c.y, c.z)])


def cell_index(grid: Grid, p: mi.Point3f) -> tuple[mi.UInt32, mi.Bool]:
    """Flat cell index of world points and whether they lie inside the volume."""
    inv = grid.inv(grid.cell)
    o = grid.lo()
    ix = mi.Int32(dr.floor((p.x - o[0]) * inv))
    iy = mi.Int32(dr.floor((p.y - o[1]) * inv))
    iz = mi.Int32(dr.floor((p.z - o[2]) * inv))
    n = grid.n
    inside = (ix >= 0) & (iy >= 0) & (iz >= 0) & (ix < n) & (iy < n) & (iz < n)
    return mi.UInt32(ix + n * (iy + n * iz)), inside


def inject(vol: SHVolume, position: mi.Point3f, direction: mi.Vector3f, flux: mi.Color3f,
           active: mi.Bool, offset: mi.Vector3f | None = None) -> mi.Bool:
    """Add cosine lobes ``flux/π · <direction, ω>+`` (Franke Eq. 12) into ``vol`` (in place).

    Each lobe goes into the cell containing ``position + offset`` (Franke §4.3.1: "half the
    size of a voxel along its normal"); lobes outside the volume are dropped. Negative
    ``flux`` injects antiradiance (Eq. 13: ``R_µ`` texels enter with a minus sign).
    Returns the lanes injected (active and inside the volume); ``dr.count`` them only when
    the number is needed, since a count waits for the kernels (the injection itself is only
    launched).
    """
    p = position if offset is None else position + offset
    idx, inside = cell_index(vol.grid, p)
    act = active & inside
    scale = flux * (1.0 / math.pi)
    c0 = scale * COS_LOBE_0
    f1 = COS_LOBE_1
    vals = [c0, scale * (-f1 * direction.x), scale * (f1 * direction.y),
            scale * (f1 * direction.z)]
    # an ordered (fixed-point) sum: float atomics made the volume depend on thread timing
    # |each coefficient| <= max|flux| / π · max(COS_LOBE_0, COS_LOBE_1): one reduction
    peak = dr.max(dr.select(act, dr.maximum(dr.maximum(dr.abs(flux.x), dr.abs(flux.y)),
                                            dr.abs(flux.z)), 0.0))
    bound = float(peak[0]) / math.pi * max(COS_LOBE_0, COS_LOBE_1)
    sums = scatter_sum_exact([ch for v in vals for ch in (v.x, v.y, v.z)], idx, act,
                             vol.grid.n ** 3, max_abs=bound)
    for k in range(4):
        vol.coeffs[k] = vol.coeffs[k] + mi.Color3f(*sums[3 * k:3 * k + 3])
    dr.eval(vol.coeffs, act)
    return act


@functools.lru_cache(maxsize=8)
def _neighbour_tables(n: int) -> list[tuple[mi.UInt32, mi.Bool]]:
    """Per axis direction d: for each destination cell, the index of the source cell
    ``dest − d`` and whether it exists."""
    m = n ** 3
    lin = dr.arange(mi.UInt32, m)
    x, y, z = mi.Int32(lin % n), mi.Int32((lin // n) % n), mi.Int32(lin // (n * n))
    out = []
    for d in AXES:
        sx, sy, sz = x - int(d[0]), y - int(d[1]), z - int(d[2])
        ok = (sx >= 0) & (sy >= 0) & (sz >= 0) & (sx < n) & (sy < n) & (sz < n)
        idx = mi.UInt32(dr.select(ok, sx + n * (sy + n * sz), 0))
        dr.eval(idx, ok)
        out.append((idx, ok))
    return out


def _luminance(c: mi.Color3f) -> mi.Float:
    return 0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z


def _toward(c: list, a: int) -> mi.Float:
    """``|luminance(Y(d_a) · c)|``: the magnitude of the intensity towards axis ``a`` of the
    SH coefficients ``c`` (4 ``Color3f``), the quantity the dampening compares."""
    t = _TOWARD[a]
    return dr.abs(_luminance(sum((c[k] * float(t[k]) for k in range(4)), mi.Color3f(0.0))))


def _step(cur: list, idxs: list, oks: list, dampening: bool, trans: list | None = None
          ) -> list:
    """One [KD10] gather step (see :func:`propagate`): the coefficients every cell receives
    from its 6 neighbours, as Dr.Jit expressions (one kernel: the dampening factors are
    computed from the gathered neighbour coefficients, not from a separate pass); ``trans``
    (6 per-destination transmittances, :func:`face_transmittance`) attenuates each
    neighbour's contribution by the geometry volume's blocking of the shared face."""
    mats = _MATS
    n_cells = dr.width(cur[0])
    new = [dr.zeros(mi.Color3f, n_cells) for _ in range(4)]
    for a in range(6):
        idx, ok = idxs[a], oks[a]
        src = [dr.gather(mi.Color3f, cur[k], idx, ok) for k in range(4)]
        m = mats[a]
        w = None
        if dampening:
            i_src, i_dst = _toward(src, a), _toward(cur, a)
            den = i_src + i_dst
            g = dr.select(den > 0, (i_dst - i_src) / dr.select(den > 0, den, 1.0), 0.0)
            w = 1.0 - dr.maximum(g, 0.0)
        if trans is not None:
            w = trans[a] if w is None else w * trans[a]
        for r in range(4):
            term = src[0] * float(m[r, 0])
            for k in range(1, 4):
                if m[r, k] != 0.0:
                    term = term + src[k] * float(m[r, k])
            new[r] = new[r] + (term if w is None else term * w)
    return new


_MATS = propagation_matrices()
_TOWARD = [basis(d) for d in AXES.astype(np.float64)]


def propagate(vol: SHVolume, steps: int, dampening: bool = False,
              stats: dict | None = None, transmittance: list | None = None) -> SHVolume:
    """``steps`` iterations of [KD10] propagation; returns the accumulated volume
    ``Σ_{k=0..steps} P^k V_0`` (the injected light plus every propagated step, as the LPV's
    "accumulated result of all iterations", Franke §4.2).

    ``dampening`` (Franke §4.4, thesis §5.3.3; [KD10]'s light-bleeding heuristic, our exact
    reading): the contribution a cell receives from its neighbour along ``d`` is scaled by
    ``1 − max(0, g)`` with ``g = (|Y(d)·c_dst| − |Y(d)·c_src|) / (|Y(d)·c_dst| + |Y(d)·c_src|)``
    (luminance of the intensity towards ``d`` in the current step's wavefront): light that
    would flow towards a cell already carrying more intensity in that direction (back into
    the surface it came from, or across a sharp negative/positive edge) is damped, uniform
    regions pass unchanged. The factor depends on ratios only, so the result still scales
    linearly with the light; without dampening every step is exactly linear.

    One Dr.Jit kernel per step (72 gathers and ~300 multiply-adds per cell, ~100 more
    with dampening). Without ``stats`` the steps run as a frozen function (``dr.freeze``,
    one recording per volume size, step count and dampening): replaying the 32 kernels skips
    Python tracing, which otherwise costs as much as the kernels themselves on 2 CPU cores.
    ``stats`` (optional dict) receives ``flux_per_step``, the total flux of each wavefront.

    ``transmittance`` (optional, [KD10] §5.3 "fuzzy occlusion"): 6 ``mi.Float`` of ``n³``
    (one per propagation direction, indexed by the destination cell), the fraction of the
    neighbour's light that crosses the face it shares with the destination
    (:func:`face_transmittance` of a geometry volume). As [KD10], the first step is not
    blocked (the surface a VPL was injected from would shadow it).
    """
    grid = vol.grid
    tables = _neighbour_tables(grid.n)
    idxs = [t[0] for t in tables]
    oks = [t[1] for t in tables]
    cur = [mi.Color3f(c) for c in vol.coeffs]
    if stats is None:
        with FREEZE_LOCK:  # the studio prepares and renders on several threads
            if transmittance is None:
                return SHVolume(grid, _propagate_frozen(cur, idxs, oks, int(steps),
                                                        bool(dampening), grid.n))
            return SHVolume(grid, _propagate_blocked(cur, idxs, oks, list(transmittance),
                                                     int(steps), bool(dampening), grid.n))
    acc = [mi.Color3f(c) for c in cur]
    fluxes = []
    for i in range(int(steps)):
        cur = _step(cur, idxs, oks, bool(dampening), None if i == 0 else transmittance)
        acc = [acc[k] + cur[k] for k in range(4)]
        dr.eval(cur, acc)
        fluxes.append(_channel_sums(cur[0]) * math.sqrt(4 * math.pi))
    stats["flux_per_step"] = fluxes
    return SHVolume(grid, acc)


@dr.freeze(limit=16, warn_after=64)
def _propagate_frozen(cur: list, idxs: list, oks: list, steps: int, dampening: bool,
                      n: int) -> list:
    """The step loop of :func:`propagate` without statistics, frozen. ``n`` (cells per edge)
    is only part of the recording's key: :func:`_step` bakes the volume's width into its
    kernels, so every size needs its own recording."""
    del n
    acc = [mi.Color3f(c) for c in cur]
    for _ in range(steps):
        cur = _step(cur, idxs, oks, dampening)
        acc = [acc[k] + cur[k] for k in range(4)]
        dr.eval(cur, acc)
    return acc


@dr.freeze(limit=16, warn_after=64)
def _propagate_blocked(cur: list, idxs: list, oks: list, trans: list, steps: int,
                       dampening: bool, n: int) -> list:
    """:func:`_propagate_frozen` with a geometry volume's face transmittances (not applied
    in the first step, [KD10])."""
    del n
    acc = [mi.Color3f(c) for c in cur]
    for i in range(steps):
        cur = _step(cur, idxs, oks, dampening, None if i == 0 else trans)
        acc = [acc[k] + cur[k] for k in range(4)]
        dr.eval(cur, acc)
    return acc


def face_transmittance(blocking: np.ndarray) -> np.ndarray:
    """Per propagation direction ``AXES[a]`` and destination cell, the transmittance
    ``1 − B_f`` of the face the destination shares with its source neighbour ([KD10] §5.3):
    ``blocking`` ``(n+1, n+1, n+1, 3)`` indexed ``[z, y, x, axis]`` is a geometry volume on
    the dual lattice (its cell ``(i, j, k)`` centred on the LPV cell corner ``origin + s·(i,
    j, k)``, :func:`arlight.realtime.voxels.blocking_potential`) holding the blocking
    potential of light travelling along each axis, in [0, 1]; ``B_f`` is its mean over the 4
    corners of the face (bilinear at the face centre). Returns ``(6, n, n, n)`` float32,
    ``[a, z, y, x]``."""
    b = np.asarray(blocking, np.float64)
    n = b.shape[0] - 1
    out = np.empty((6, n, n, n), np.float32)
    arr_axis = {0: 2, 1: 1, 2: 0}  # world axis → array axis of [z, y, x]
    for a, d in enumerate(AXES):
        ax = int(np.flatnonzero(d)[0])
        face = b[..., ax]
        # the face's coordinate along ax: the destination's lower corner (d > 0) or upper
        lo = 0 if d[ax] > 0 else 1
        sl = [slice(None)] * 3
        sl[arr_axis[ax]] = slice(lo, lo + n)
        f = face[tuple(sl)]
        # mean over the 4 corners in the two other axes
        for other in range(3):
            if other == ax:
                continue
            k = arr_axis[other]
            f = 0.5 * (np.take(f, range(0, n), axis=k) + np.take(f, range(1, n + 1), axis=k))
        out[a] = 1.0 - np.clip(f, 0.0, 1.0)
    return out


def transmittance_dr(trans: np.ndarray) -> list[mi.Float]:
    """:func:`face_transmittance`'s array as the 6 flat Dr.Jit buffers (x fastest) that
    :func:`propagate` takes."""
    return [mi.Float(aligned(np.ascontiguousarray(t.reshape(-1)), np.float32)) for t in trans]


def propagate_numpy(arr: np.ndarray, steps: int, dampening: bool = False,
                    transmittance: np.ndarray | None = None,
                    matrices: np.ndarray | None = None) -> np.ndarray:
    """Plain NumPy peer of :func:`propagate`: ``arr`` is ``(n, n, n, 4, 3)`` indexed
    ``[z, y, x, k, c]``; returns the accumulated volume (float64), with the same dampening
    factor when ``dampening`` and the face transmittances ``(6, n, n, n)`` when given (from
    the second step on). ``matrices`` (default :func:`propagation_matrices`) lets a test
    supply matrices built independently."""
    mats = propagation_matrices() if matrices is None else np.asarray(matrices, np.float64)
    lum = np.array([0.2126, 0.7152, 0.0722])
    cur = np.asarray(arr, np.float64)
    acc = cur.copy()
    for step in range(int(steps)):
        new = np.zeros_like(cur)
        for a, d in enumerate(AXES):
            moved = mats[a] @ cur  # (4, 4) @ (n, n, n, 4, C)
            # destination (x, y, z) receives from source (x, y, z) − d
            sl_dst = [slice(None)] * 3
            sl_src = [slice(None)] * 3
            for ax_xyz, ax_arr in ((0, 2), (1, 1), (2, 0)):
                s = int(d[ax_xyz])
                if s > 0:
                    sl_dst[ax_arr], sl_src[ax_arr] = slice(s, None), slice(None, -s)
                elif s < 0:
                    sl_dst[ax_arr], sl_src[ax_arr] = slice(None, s), slice(-s, None)
            part = moved[tuple(sl_src)]
            if dampening:
                toward = np.abs(np.einsum("k,...kc,c->...", _TOWARD[a], cur, lum))
                i_src, i_dst = toward[tuple(sl_src)], toward[tuple(sl_dst)]
                den = i_src + i_dst
                g = np.where(den > 0, (i_dst - i_src) / np.where(den > 0, den, 1.0), 0.0)
                part = part * (1.0 - np.maximum(g, 0.0))[..., None, None]
            if transmittance is not None and step > 0:
                part = part * np.asarray(transmittance[a], np.float64)[tuple(sl_dst)][
                    ..., None, None]
            new[tuple(sl_dst)] += part
        cur = new
        acc += cur
    return acc


def query_irradiance(vol: SHVolume, p: mi.Point3f, n: mi.Vector3f,
                     active: mi.Bool | bool = True) -> mi.Color3f:
    """Irradiance (W/m², RGB) at points ``p`` with unit normals ``n`` from the light in the
    volume: trilinear interpolation of the cell coefficients (cell centres), then
    ``E = Σ_l Â_l c_lm Y_lm(−n) / s²`` (Franke Alg. 1 evaluates "with the inverse normal";
    [KD10]: radiance ≈ intensity / s²). Zero outside the volume (Franke's cut-off)."""
    g = vol.grid
    n_ = g.n
    inv = g.inv(g.cell)
    o = g.lo()
    fx = (p.x - o[0]) * inv - 0.5
    fy = (p.y - o[1]) * inv - 0.5
    fz = (p.z - o[2]) * inv - 0.5
    inside = (fx > -0.5) & (fy > -0.5) & (fz > -0.5) & (fx < n_ - 0.5) & (fy < n_ - 0.5) & (
        fz < n_ - 0.5) & active
    x0 = dr.clip(mi.Int32(dr.floor(fx)), 0, n_ - 1)
    y0 = dr.clip(mi.Int32(dr.floor(fy)), 0, n_ - 1)
    z0 = dr.clip(mi.Int32(dr.floor(fz)), 0, n_ - 1)
    tx = dr.clip(fx - mi.Float(x0), 0.0, 1.0)
    ty = dr.clip(fy - mi.Float(y0), 0.0, 1.0)
    tz = dr.clip(fz - mi.Float(z0), 0.0, 1.0)
    x1, y1, z1 = dr.minimum(x0 + 1, n_ - 1), dr.minimum(y0 + 1, n_ - 1), dr.minimum(z0 + 1,
                                                                                     n_ - 1)
    w0 = A_HAT[0] * Y00
    w1 = A_HAT[1] * Y1
    sh_w = [mi.Float(w0), -w1 * (-n.x), w1 * (-n.y), w1 * (-n.z)]
    out = mi.Color3f(0.0)
    for cx, wx in ((x0, 1.0 - tx), (x1, tx)):
        for cy, wy in ((y0, 1.0 - ty), (y1, ty)):
            for cz, wz in ((z0, 1.0 - tz), (z1, tz)):
                idx = mi.UInt32(cx + n_ * (cy + n_ * cz))
                w = wx * wy * wz
                e = mi.Color3f(0.0)
                for k in range(4):
                    e = e + dr.gather(mi.Color3f, vol.coeffs[k], idx, inside) * sh_w[k]
                out = out + e * w
    return dr.select(inside, out * (inv * inv), mi.Color3f(0.0))


def query_irradiance_compact(vol: SHVolume, p: mi.Point3f, n: mi.Vector3f,
                             active: mi.Bool) -> mi.Color3f:
    """:func:`query_irradiance` on the ``active`` lanes only (compacted with
    ``dr.compress``, scattered back; zero elsewhere): the trilinear lookup costs 96 gathers per
    lane, so skipping the inactive ones pays off when few are active."""
    g = vol.grid
    lo, hi = g.lo(), g.hi()
    inside = active & (p.x > lo[0]) & (p.y > lo[1]) & (p.z > lo[2]) & (p.x < hi[0]) & (
        p.y < hi[1]) & (p.z < hi[2])
    return on_active(lambda pc, nc: query_irradiance(vol, pc, nc), p, n, inside)


_PLANE_RESPONSE: dict[tuple[int, int, bool], float] = {}


def plane_response(n: int, steps: int, dampening: bool) -> float:
    """How much an LPV over-reads a lit plane: ``E_LPV / E_true`` for a plane at normal
    incidence (our calibration; neither Franke nor [KD10] fix the volume's radiometric
    scale).

    A ``n × n`` layer of cells in the middle of an ``n³`` volume receives the direct lobes of
    a plane lit from straight above (flux ``Φ`` per cell, injected half a cell towards the
    light as in Franke §4.3.2); after ``steps`` propagations (with or without dampening) the
    irradiance read at the centre cell with the plane's normal is compared with the true
    ``Φ / s²``. Lateral exchange inside the injection layer makes the LPV read 1.5–2.1× too
    much (measured at 30°–90° incidence for 32³ and 32 steps). Cached per arguments.
    """
    key = (int(n), int(steps), bool(dampening))
    if key not in _PLANE_RESPONSE:
        g = Grid(np.zeros(3), 1.0, int(n))
        a = np.zeros((n, n, n, 4, 3))
        j = n // 2
        a[:, j, :, :, :] = (cosine_lobe(np.array([0.0, -1.0, 0.0])) / math.pi)[:, None]
        vol = propagate(SHVolume.from_numpy(g, a), int(steps), bool(dampening))
        c = (j + 0.5) * g.cell
        e = np.array(query_irradiance(vol, mi.Point3f(c, c, c), mi.Vector3f(0.0, 1.0, 0.0)))
        _PLANE_RESPONSE[key] = float(np.ravel(e)[0])  # Φ = 1 W per cell, s = 1 m: E_true = 1
    return _PLANE_RESPONSE[key]


_POINT_RESPONSE: dict[tuple[int, int, bool, float], float] = {}

POINT_DISTANCES = (2, 3, 4)
"""Receiver distances (cells from the VPL's cell centre) of :func:`point_response`: the
range over which an LPV carries a VPL's light (beyond about 4 cells the propagated
wavefront has spread: 0.41 of ``Φ/(πr²)`` at 6 cells, 0.19 at 8)."""
POINT_ANGLES_DEG = (0.0, 30.0, 60.0)
"""Receiver directions of :func:`point_response`, degrees from the VPL's normal."""
VPL_OFFSET = 0.5
"""dlpv's ``offset`` (cells) in the sense of :func:`point_response`: it moves a VPL half a
cell along its surface normal before choosing its cell (Franke §4.3.1) and reads a receiver
half a cell along its normal ([KD10]; :func:`arlight.methods.dlpv.shade`)."""
SUBCELL = 8
"""Midpoint samples per axis of a VPL's position in its cell (``SUBCELL³``) in
:func:`point_response`."""


def subcell_texels(normal: np.ndarray, offset: float, k: int = SUBCELL) -> np.ndarray:
    """``(k³, 3)`` positions (cells, relative to a cell's centre) of the surface points whose
    VPLs land in that cell: the VPL ``p + offset · n`` is uniform in the cell (midpoint rule,
    ``k`` per axis), so the emitting texel is ``u − offset · n`` with ``u ∈ [−½, ½]³`` — on
    average ``offset`` cells *behind* the cell centre the LPV propagates from."""
    u = (np.stack(np.meshgrid(*[np.arange(k)] * 3, indexing="ij"), -1).reshape(-1, 3)
         + 0.5) / k - 0.5
    return u - float(offset) * np.asarray(normal, np.float64)


def vpl_irradiance(texels: np.ndarray, normal: np.ndarray, x: np.ndarray,
                   nx: np.ndarray) -> np.ndarray:
    """The mean over ``texels`` ``(m, 3)`` (each a Lambertian emitter of unit flux with unit
    ``normal``) of their irradiance at receivers ``x`` ``(r, 3)`` with unit normals ``nx``:
    ``E = <n, ω>+ <n_x, −ω>+ / (π d²)`` (Franke Eq. 12's lobe ``Φ/π <n, ω>+`` seen at
    distance ``d`` along ``ω``; same length unit as ``d``, NumPy float64)."""
    v = np.asarray(x, np.float64)[:, None, :] - np.asarray(texels, np.float64)[None]
    d2 = np.einsum("rmk,rmk->rm", v, v)
    w = v / np.sqrt(d2)[..., None]
    emit = np.maximum(w @ np.asarray(normal, np.float64), 0.0)
    recv = np.maximum(-np.einsum("rk,rmk->rm", np.asarray(nx, np.float64), w), 0.0)
    return (emit * recv / (math.pi * d2)).mean(axis=1)


def point_response(n: int, steps: int, dampening: bool, offset: float = 0.0) -> float:
    """How an LPV reads one VPL (the shape of every indirect injection): the mean of
    ``E_LPV / E_true`` over receivers at :data:`POINT_DISTANCES` cells from the VPL's cell
    centre and :data:`POINT_ANGLES_DEG` from the VPL's normal, each facing that centre. The
    divisor that makes the volume's indirect light radiometric on average over the
    distances where it carries light. Derived from the propagation operator alone, no
    scene; cached per arguments.

    ``E_LPV``: a lobe ``Φ/π <n, ω>+`` (Franke Eq. 12) at the cell centre, propagated, read
    (:func:`query_irradiance`) at the receiver moved ``offset`` cells along its normal, as
    dlpv reads. ``E_true``: the same flux emitted from the surface point the VPL came from,
    ``Φ cos θ_e cos θ_r / (π d²)`` averaged over the VPL's position in its cell
    (:func:`subcell_texels`, :func:`vpl_irradiance`): the injection moved the VPL ``offset``
    cells along ``n``, so its light really starts that far behind the cell, and the LPV,
    which knows only the cell, sees it closer than it is. ``offset`` 0 (the default): the
    VPL at its cell centre, read in place — 0.88 at 32³ and 32 steps, the divisor dlpv uses
    (:func:`arlight.methods.dlpv.injection_scales`). At dlpv's own :data:`VPL_OFFSET` it is
    1.71 (receivers 1.06–2.80): under the 0.88 one VPL reads 1.7–1.9× the inverse-square
    law at 2.5–4 cells as dlpv injects and reads it (tests/realtime/test_lpv_reference.py).
    dlpv keeps 0.88 (issue #33, docs/methods/dlpv.md "One VPL and the far field"): the
    LPV also loses a VPL's light beyond 4 cells (under 1.71: 0.4 of the law at 6 cells; an
    emitting face lights a floor 4–8 cells away at 0.3–0.5 of it, 8–16 cells at 0.07), where
    much of an object's bounce lands, and the near-field excess of 0.88 makes up for it on
    the training worlds (1.71: −0.09 dB) and against a path tracer (tests/methods/
    test_dlpv_reference.py: the cube's bleed 0.92× → 0.47×).
    """
    key = (int(n), int(steps), bool(dampening), float(offset))
    if key not in _POINT_RESPONSE:
        m = max(int(n), 2 * max(POINT_DISTANCES) + 2)
        g = Grid(np.zeros(3), 1.0, m)
        c = m // 2 - max(POINT_DISTANCES) // 2 - 1
        normal = np.array([1.0, 0.0, 0.0])
        a = np.zeros((m, m, m, 4, 3))
        a[c, c, c] = (cosine_lobe(normal) / math.pi)[:, None]
        vol = propagate(SHVolume.from_numpy(g, a), int(steps), bool(dampening))
        pts, nrm = [], []
        for th in POINT_ANGLES_DEG:
            t = math.radians(th)
            d = np.array([math.cos(t), math.sin(t), 0.0])
            for r in POINT_DISTANCES:
                pts.append(r * d)
                nrm.append(-d)
        x, nx = np.asarray(pts), np.asarray(nrm)
        true = vpl_irradiance(subcell_texels(normal, offset, 1 if offset == 0 else SUBCELL),
                              normal, x, nx)
        p = np.asarray(c + 0.5 + x + float(offset) * nx, np.float32)
        q = np.asarray(nx, np.float32)
        e = np.array(query_irradiance(vol, mi.Point3f(*(aligned(p[:, i], np.float32)
                                                        for i in range(3))),
                                      mi.Vector3f(*(aligned(q[:, i], np.float32)
                                                    for i in range(3)))))
        _POINT_RESPONSE[key] = float(np.mean(np.asarray(e).reshape(3, -1)[0] / true))
    return _POINT_RESPONSE[key]


__all__ = ["AXES", "LATTICE_BLOCKS", "Grid", "SHVolume", "basis", "cell_index", "cosine_lobe",
           "VPL_OFFSET", "face_solid_angles", "inject", "propagate", "propagate_numpy",
           "face_transmittance", "plane_response", "point_response", "propagation_matrices",
           "transmittance_dr", "query_irradiance", "query_irradiance_compact",
           "rect_solid_angle", "subcell_texels", "vpl_irradiance"]
