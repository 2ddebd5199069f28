"""Per-vertex diffuse precomputed radiance transfer (Sloan et al. 2002; Franke thesis §2.4
Eqs. 2.30–2.40 and §4.3, the rigid pipeline).

For a vertex ``x`` with unit normal ``n`` the diffuse transfer vector is

    t_k(x) = (1/π) ∫ V(x, ω) <n, ω>+ y_k(ω) dω                       (Eq. 2.33/2.34)

with ``V`` the binary visibility of the object by itself, traced with ``directions`` rays per
vertex (a Fibonacci sphere, weights ``4π/K``) in one batched ``ray_test``. Outgoing radiance
under distant light of radiance SH ``l`` is then ``L_o = ρ Σ_k t_k l_k`` (Eq. 2.37): an
unoccluded vertex under a uniform sky of radiance ``L`` gives ``ρ L``.

**Inter-reflection** (``bounces > 0``; Sloan 2002 §5): the rays that hit the object record
the hit triangle and barycentrics, and each bounce adds
``t^{b+1}(x) = (1/π) Σ_hits ρ t^b(hit) <n, ω> 4π/K`` (the light reflected once more by the
diffuse object towards ``x``), with ``t^b(hit)`` interpolated from the hit triangle's vertices.

Transfer lives in the object's frame; at run time the light is rotated into it
(:func:`vertex_values`, ``l_obj = rotate(l, Rᵀ)`` with the exact SH rotation of
:mod:`arlight.sphere.sh`), so a rigid object turns without new precomputation.

Precomputations are cached on disk (``<cache>/prt/<key>.npz``, cache directory of
:func:`arlight.cache.default_cache_dir`) and in memory, keyed by the SHA-256 of the
object-space mesh content (vertices, faces, normals) and every setting that changes the result.
"""

from __future__ import annotations

import hashlib
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.io.images import atomic_write
from arlight.realtime.oof import RAY_CHUNK
from arlight.scene.mesh import vertex_normals
from arlight.scene.model import MeshData
from arlight.sphere.points import fibonacci_sphere
from arlight.sphere.sh import n_coeffs, rotate, sh_basis

VERSION = 1
"""Bump when the precomputation changes: part of the cache key."""
EPS = 1e-4
"""Ray origins move this far along the normal (m, object space)."""


@dataclass
class PRTTransfer:
    """Diffuse transfer of one mesh.

    Attributes:
        transfer: ``(V, (order+1)²)`` float32 transfer vectors (object frame, no albedo).
        order: SH order.
        key: cache key (hex).
        seconds: precomputation wall time (s), 0 when read from the cache.
        from_cache: whether it came from the disk or memory cache.
    """

    transfer: np.ndarray
    order: int
    key: str
    seconds: float = 0.0
    from_cache: bool = False

    @property
    def vertices(self) -> int:
        return int(self.transfer.shape[0])


def check_mesh(mesh: MeshData, name: str = "mesh") -> tuple[np.ndarray, list[str]]:
    """Unit vertex normals of ``mesh`` and the warnings its geometry deserves.

    Fallbacks (documented in ``docs/methods/prt.md``): a mesh without vertex normals gets
    angle-weighted smooth normals (:func:`arlight.scene.mesh.vertex_normals`); non-manifold
    edges (shared by more than two faces) and unreferenced vertices are reported but kept —
    visibility rays do not need a manifold, a vertex's transfer is then taken over the
    full sphere of its normal.

    Raises:
        ValueError: no faces, or faces that index missing vertices.
    """
    v = np.asarray(mesh.vertices, np.float64)
    f = np.asarray(mesh.faces, np.int64).reshape(-1, 3)
    if len(f) == 0 or len(v) == 0:
        raise ValueError(f"{name}: PRT needs a triangle mesh with faces")
    if f.max() >= len(v) or f.min() < 0:
        raise ValueError(f"{name}: faces index vertices that do not exist")
    notes = []
    if mesh.normals is None:
        normals = vertex_normals(v, f)
        notes.append(f"{name} has no vertex normals; PRT uses angle-weighted smooth normals")
    else:
        normals = np.asarray(mesh.normals, np.float64)
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    if np.any(counts > 2):
        notes.append(f"{name} is non-manifold ({int(np.sum(counts > 2))} edges shared by more "
                     "than two faces); PRT traces it as it is")
    return normals, notes


def mesh_key(mesh: MeshData, order: int, directions: int, bounces: int,
             albedo: np.ndarray | None, shadowed: bool = True) -> str:
    """SHA-256 of the object-space mesh content and the settings (the cache key)."""
    h = hashlib.sha256()
    h.update(f"prt-v{VERSION}-o{order}-d{directions}-b{bounces}-s{int(shadowed)}".encode())
    for a in (mesh.vertices, mesh.faces, mesh.normals):
        h.update(b"|" if a is None else np.ascontiguousarray(a, np.float64).tobytes())
    if bounces:
        h.update(np.asarray(albedo, np.float64).tobytes())
    return h.hexdigest()


def _mesh_scene(v: np.ndarray, f: np.ndarray) -> mi.Scene:
    m = mi.Mesh("prt", len(v), len(f))
    params = mi.traverse(m)
    params["vertex_positions"] = mi.Float(np.asarray(v, np.float32).reshape(-1))
    params["faces"] = mi.UInt32(np.asarray(f, np.uint32).reshape(-1))
    params.update()
    return mi.load_dict({"type": "scene", "mesh": m})


def precompute(mesh: MeshData, order: int = 2, directions: int = 512, bounces: int = 0,
               albedo: np.ndarray | None = None, name: str = "mesh", progress=None,
               shadowed: bool = True) -> PRTTransfer:
    """Transfer vectors of ``mesh`` in its object frame (module docstring).

    Args:
        order: SH order (2: 9 coefficients, 3: 16).
        directions: rays per vertex.
        bounces: diffuse inter-reflections (needs ``albedo``, RGB; the transfer is then
            ``(V, n)`` per luminance-weighted grey albedo).
        progress: ``progress(done, total)`` callback (e.g. :func:`arlight.progress.reporter`).
        shadowed: trace self-occlusion (False: ``V ≡ 1``, the unshadowed transfer, i.e. SH
            irradiance; no inter-reflection either).
    """
    t0 = time.perf_counter()
    normals, notes = check_mesh(mesh, name)
    for note in notes:
        warnings.warn(note, RuntimeWarning, stacklevel=2)
    v = np.asarray(mesh.vertices, np.float64)
    f = np.asarray(mesh.faces, np.int64).reshape(-1, 3)
    dirs = fibonacci_sphere(directions)
    y = sh_basis(dirs, order).astype(np.float32) * np.float32(4 * np.pi / directions / np.pi)
    scene = _mesh_scene(v, f)
    origins = (v + normals * EPS).astype(np.float32)
    cos = np.clip(normals.astype(np.float32) @ dirs.T.astype(np.float32), 0.0, None)  # (V, K)
    V, K = len(v), len(dirs)
    t = np.empty((V, n_coeffs(order)), np.float32)
    hit_prim = np.full((V, K), -1, np.int64) if bounces else None
    hit_uv = np.zeros((V, K, 2), np.float32) if bounces else None
    per = max(1, RAY_CHUNK // K)
    for p0 in range(0, V, per):
        o = np.repeat(origins[p0:p0 + per], K, axis=0)
        d = np.tile(dirs.astype(np.float32), (len(o) // K, 1))
        ray = mi.Ray3f(mi.Point3f(o[:, 0], o[:, 1], o[:, 2]),
                       mi.Vector3f(d[:, 0], d[:, 1], d[:, 2]))
        rows = slice(p0, p0 + len(o) // K)
        if not shadowed:
            occ = np.zeros((len(o) // K, K), bool)
        elif bounces:
            pi = scene.ray_intersect_preliminary(ray)
            valid = pi.is_valid()
            dr.eval(pi.prim_index, pi.prim_uv, valid)
            occ = np.asarray(valid, bool).reshape(-1, K)
            hit_prim[rows] = np.where(occ, np.asarray(pi.prim_index, np.int64).reshape(-1, K),
                                      -1)
            uv = np.stack([np.asarray(pi.prim_uv.x), np.asarray(pi.prim_uv.y)], -1)
            hit_uv[rows] = np.where(occ[..., None], uv.reshape(-1, K, 2), 0.0)  # misses: NaN
        else:
            occ = np.asarray(scene.ray_test(ray), bool).reshape(-1, K)
        t[rows] = (cos[rows] * ~occ) @ y
        if progress is not None:
            progress(rows.stop if rows.stop < V else V, V)
    if bounces and shadowed:
        rho = float(np.asarray(albedo, np.float64) @ np.array([0.2126, 0.7152, 0.0722]))
        hit = hit_prim >= 0
        b1, b2 = hit_uv[..., 0], hit_uv[..., 1]
        fv = f[np.where(hit, hit_prim, 0)]  # (V, K, 3)
        w = cos * hit  # (V, K)
        tb = t.copy()
        for _ in range(bounces):
            at_hit = ((1 - b1 - b2)[..., None] * tb[fv[..., 0]] + b1[..., None] * tb[fv[..., 1]]
                      + b2[..., None] * tb[fv[..., 2]])  # (V, K, n)
            tb = rho * (4.0 / directions) * np.einsum("vk,vkn->vn", w, at_hit)
            t += tb.astype(np.float32)
    return PRTTransfer(t, order, mesh_key(mesh, order, directions, bounces, albedo, shadowed),
                       time.perf_counter() - t0)


_MEMORY: dict[str, PRTTransfer] = {}


def cached_transfer(mesh: MeshData, cache_dir: Path | None, order: int = 2,
                    directions: int = 512, bounces: int = 0, albedo=None, name: str = "mesh",
                    progress=None, shadowed: bool = True) -> PRTTransfer:
    """:func:`precompute`, read from / written to ``cache_dir/prt/<key>.npz`` (and memory);
    ``cache_dir=None`` keeps the memory cache only."""
    key = mesh_key(mesh, order, directions, bounces, albedo, shadowed)
    if key in _MEMORY:
        hit = _MEMORY[key]
        return PRTTransfer(hit.transfer, hit.order, key, 0.0, True)
    path = None if cache_dir is None else Path(cache_dir) / "prt" / f"{key}.npz"
    if path is not None and path.exists():
        with np.load(path) as z:
            out = PRTTransfer(z["transfer"], int(z["order"]), key, 0.0, True)
    else:
        out = precompute(mesh, order, directions, bounces, albedo, name, progress, shadowed)
        if path is not None:
            # a unique temporary name, renamed into place: concurrent workers (Ray) writing
            # the same key never read or clobber a half-written file
            with atomic_write(path, ".npz") as tmp:
                np.savez(tmp, transfer=out.transfer, order=out.order)
    _MEMORY[key] = out
    return out


def rotation_part(to_world: np.ndarray) -> np.ndarray:
    """The rotation of a 4×4 similarity transform (uniform scale and translation removed,
    by polar decomposition)."""
    m = np.asarray(to_world, np.float64)[:3, :3]
    u, _, vt = np.linalg.svd(m)
    r = u @ vt
    if np.linalg.det(r) < 0:
        raise ValueError("a mirroring transform cannot be handled by SH rotation of PRT")
    return r


def vertex_values(transfer: PRTTransfer, light_sh: np.ndarray, world_from_object: np.ndarray,
                  order: int | None = None) -> np.ndarray:
    """``Σ_k t_k l_k`` per vertex ``(V, 3)`` (multiply by the albedo for radiance,
    W/(sr·m²)) for world radiance SH ``light_sh`` and the object's world rotation.

    Raises:
        ValueError: ``order`` above the precomputed order (the transfer has no such bands).
    """
    order = transfer.order if order is None else int(order)
    if order > transfer.order:
        raise ValueError(f"SH order {order} requested, but the transfer was precomputed to "
                         f"order {transfer.order}; precompute it with order >= {order}")
    k = n_coeffs(order)
    light = np.zeros((k, 3))
    m = min(k, np.asarray(light_sh).shape[0])
    light[:m] = np.asarray(light_sh, np.float64)[:m]
    l_obj = rotate(light, np.asarray(world_from_object, np.float64).T)
    return transfer.transfer[:, :k].astype(np.float64) @ l_obj


__all__ = ["EPS", "PRTTransfer", "VERSION", "cached_transfer", "check_mesh", "mesh_key",
           "precompute", "rotation_part", "vertex_values"]
