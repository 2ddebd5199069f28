"""Cube maps and their SH projection (Rohmer Eqs. 9–13).

A cube map of ``6 × res × res`` texels (res = 32 in Rohmer) is a set of directions
``ω_t`` with exact solid angles

    Δω_t = A(x0, y0) − A(x0, y1) − A(x1, y0) + A(x1, y1),  A(x, y) = atan2(xy, √(x²+y²+1))

(face coordinates in [−1, 1]), which sum to 4π. The projection weights are
``C_wtk = Y_k(ω_t) Δω_t`` (Eq. 11), so ``C_k ≈ Σ_t L(ω_t) C_wtk`` (Eq. 12) and the
per-vertex transfer ``C_vk ≈ Σ_t V(ω_t) cos θ_t C_wtk`` (Eq. 13, V = 0 where the object
hides direction ``ω_t`` from the vertex). SH basis and order of :mod:`arlight.sphere.sh`.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from arlight.sphere.sh import sh_basis


def _face_axes() -> list[tuple[int, float]]:
    return [(a, s) for a in range(3) for s in (1.0, -1.0)]


@lru_cache(maxsize=8)
def cube_directions(res: int) -> np.ndarray:
    """Unit texel-centre directions ``(6·res·res, 3)`` (face-major, then rows, columns)."""
    c = (np.arange(res) + 0.5) / res * 2.0 - 1.0
    v, u = np.meshgrid(c, c, indexing="ij")
    out = []
    for a, s in _face_axes():
        b, d = (a + 1) % 3, (a + 2) % 3
        w = np.zeros((res, res, 3))
        w[..., a] = s
        w[..., b] = u
        w[..., d] = v * s
        out.append(w.reshape(-1, 3))
    d = np.concatenate(out)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d.setflags(write=False)
    return d


def _area_element(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.arctan2(x * y, np.sqrt(x * x + y * y + 1.0))


@lru_cache(maxsize=8)
def texel_solid_angles(res: int) -> np.ndarray:
    """Exact solid angles ``(6·res·res,)`` of the texels (module docstring), sr."""
    e = np.arange(res + 1) / res * 2.0 - 1.0
    x0, x1 = e[None, :-1], e[None, 1:]
    y0, y1 = e[:-1, None], e[1:, None]
    face = (_area_element(x0, y0) - _area_element(x0, y1) - _area_element(x1, y0)
            + _area_element(x1, y1))
    out = np.tile(face.reshape(-1), 6)
    out.setflags(write=False)
    return out


@lru_cache(maxsize=8)
def projection_weights(res: int, order: int = 2) -> np.ndarray:
    """``C_wtk = Y_k(ω_t) Δω_t`` ``(6·res², (order+1)²)`` (Eq. 11)."""
    w = sh_basis(cube_directions(res), order) * texel_solid_angles(res)[:, None]
    w.setflags(write=False)
    return w


def project(radiance: np.ndarray, res: int, order: int = 2) -> np.ndarray:
    """``C_k = Σ_t L(ω_t) C_wtk`` (Eq. 12): ``radiance (6·res², 3)`` → ``((order+1)², 3)``."""
    return projection_weights(res, order).T @ np.asarray(radiance, np.float64)


def transfer(visible: np.ndarray, normals: np.ndarray, res: int, order: int = 2) -> np.ndarray:
    """``C_vk = Σ_t V(ω_t) cos θ_t C_wtk`` (Eq. 13): ``visible (V, 6·res²)`` (1: the
    direction is free), unit ``normals (V, 3)`` → ``(V, (order+1)²)``. Multiply by ρ/π and
    dot with ``C_k`` for the indirect radiance (Eq. 8)."""
    cos = np.clip(np.asarray(normals, np.float64) @ cube_directions(res).T, 0.0, None)
    return (np.asarray(visible, np.float64) * cos) @ projection_weights(res, order)


def vertex_transfer(vertices: np.ndarray, normals: np.ndarray, faces: np.ndarray,
                    res: int = 32, order: int = 2, eps: float = 1e-4) -> np.ndarray:
    """Eq. 13 for a mesh: per vertex a ``6·res²`` cube map of the object's self-occlusion
    (rays from ``vertex + eps·normal`` against the mesh alone, Rohmer's black-on-white
    per-vertex cube map), then :func:`transfer`. World frame, ``(V, (order+1)²)``."""
    from arlight.nearfield.raytrace import mesh_scene
    from arlight.realtime.oof import occlusion_rays

    scene = mesh_scene([(vertices, faces)])
    n = np.asarray(normals, np.float64)
    occ = occlusion_rays(scene, np.asarray(vertices, np.float64) + eps * n,
                         cube_directions(res))
    return transfer(1.0 - occ, n, res, order)


__all__ = ["cube_directions", "project", "projection_weights", "texel_solid_angles",
           "transfer", "vertex_transfer"]
