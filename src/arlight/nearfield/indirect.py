"""Indirect light as 9 SH coefficients per virtual object (Rohmer §4.4–4.5, Eqs. 9–12).

From the centre of each virtual object a ``6 × 32 × 32`` cube map is traced: directions that
hit the proxy read the dilated **indirect** atlas (bilinear, at the hit's atlas coordinates),
misses read 0 (nothing was captured there), and the object itself is left out (its
self-occlusion is in its transfer). The cube map is projected with ``C_wtk`` (Eq. 12).

**Several objects** (§4.5): object ``i``'s cube map also contains the other ``n − 1``
objects. Where it sees object ``j`` it reads ``j``'s outgoing radiance, in two cube maps: one
with ``j``'s indirect light (PRT, Eq. 8, with ``j``'s coefficients of the previous update) and
one with ``j``'s direct light from the VALs (Eq. 7, visibility through the proxy and the
virtual objects) — ``2n`` cube maps in all; an object that stays put for ``b`` updates has
``b − 1`` bounces between objects.
"""

from __future__ import annotations

from dataclasses import dataclass

import mitsuba as mi
import numpy as np

from arlight.nearfield import cubemap
from arlight.nearfield.atlas import AtlasLayout
from arlight.nearfield.projection import bilinear
from arlight.nearfield.radiometry import geometry_terms
from arlight.nearfield.raytrace import first_hits, mesh_scene, segment_visible


@dataclass
class VirtualObject:
    """A virtual object as the server sees it (world space).

    Attributes:
        name: the shape's name.
        vertices: (V, 3) m; faces: (F, 3); normals: (V, 3) unit.
        albedo: (3,) diffuse reflectance.
        transfer: (V, 9) Eq.-13 transfer C_vk (world frame), needed only when several
            objects see each other (None until computed).
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    albedo: np.ndarray
    transfer: np.ndarray | None = None

    @property
    def centre(self) -> np.ndarray:
        """Centre of the bounding box, m (the SH probe position)."""
        return (self.vertices.min(0) + self.vertices.max(0)) / 2.0


def object_radiance(obj: VirtualObject, face: np.ndarray, uv: np.ndarray, sh: np.ndarray,
                    direct: np.ndarray | None = None) -> np.ndarray:
    """Outgoing radiance ``(N, 3)`` of hits on ``obj`` (face, barycentrics ``(N, 2)``):
    ``ρ/π Σ_k C_k C_vk`` interpolated (Eq. 8) plus ``direct`` (already × ρ) if given."""
    f = obj.faces[face]
    b1, b2 = uv[:, 0:1], uv[:, 1:2]
    t = ((1 - b1 - b2) * obj.transfer[f[:, 0]] + b1 * obj.transfer[f[:, 1]]
         + b2 * obj.transfer[f[:, 2]])
    out = np.maximum(obj.albedo / np.pi * (t @ sh), 0.0)
    return out if direct is None else out + direct


def hit_points(obj: VirtualObject, face: np.ndarray, uv: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
    """World points and interpolated unit normals of hits on ``obj``."""
    f = obj.faces[face]
    b1, b2 = uv[:, 0:1], uv[:, 1:2]
    w = (1 - b1 - b2, b1, b2)
    p = sum(wi * obj.vertices[f[:, i]] for i, wi in enumerate(w))
    n = sum(wi * obj.normals[f[:, i]] for i, wi in enumerate(w))
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    return p, n


class IndirectProbes:
    """Cube-map SH probes at the virtual objects' centres over one proxy (module docstring).

    Args:
        proxy_vertices, proxy_faces: the proxy mesh (world), traced as mesh 0.
        layout: the atlas layout (hit → atlas coordinates).
        objects: the virtual objects, in the order of ``NearFieldLight.sh``.
        res: cube-map side (32).
        proxy_scene: :func:`~arlight.nearfield.raytrace.mesh_scene` of the proxy mesh alone,
            if the caller has it (the server's): reused, not built again — it is all an
            object's cube map sees when it is the only object, so probes re-made for a
            moved object (``methods.nearfield``'s pose) build no scene (issue #32).
    """

    def __init__(self, proxy_vertices: np.ndarray, proxy_faces: np.ndarray,
                 layout: AtlasLayout, objects: list[VirtualObject], res: int = 32,
                 proxy_scene: mi.Scene | None = None) -> None:
        self.layout = layout
        self.objects = objects
        self.res = int(res)
        proxy = (proxy_vertices, proxy_faces)
        self.proxy_scene = mesh_scene([proxy]) if proxy_scene is None else proxy_scene
        self.others = [[j for j in range(len(objects)) if j != i] for i in range(len(objects))]
        self.scenes = [mesh_scene([proxy] + [(objects[j].vertices, objects[j].faces)
                                             for j in others]) if others else self.proxy_scene
                       for others in self.others]
        # only direct_at (several objects) traces the objects themselves
        self.virtual_scene = (mesh_scene([(o.vertices, o.faces) for o in objects])
                              if len(objects) > 1 else None)
        if len(objects) > 1:
            for o in objects:
                if o.transfer is None:
                    o.transfer = cubemap.vertex_transfer(o.vertices, o.normals, o.faces,
                                                         res=16)

    @property
    def cube_maps(self) -> int:
        """Cube maps traced per update: n for one object, 2n with inter-object light."""
        n = len(self.objects)
        return n if n < 2 else 2 * n

    def coefficients(self, indirect_atlas: np.ndarray, previous: np.ndarray | None = None,
                     vals: tuple[np.ndarray, ...] | None = None) -> np.ndarray:
        """SH ``(n_obj, 9, 3)`` of the indirect light at every object's centre.

        Args:
            indirect_atlas: (R, R, 3) dilated indirect radiance.
            previous: (n_obj, 9, 3) coefficients of the last update (inter-object PRT light;
                zeros when None).
            vals: ``(positions, normals, intensity, area)`` of the VALs (the other objects'
                direct light; none when None).
        """
        n = len(self.objects)
        out = np.zeros((n, 9, 3))
        dirs = cubemap.cube_directions(self.res)
        prev = np.zeros((n, 9, 3)) if previous is None else np.asarray(previous)
        for i, obj in enumerate(self.objects):
            o = np.broadcast_to(obj.centre, dirs.shape)
            t, prim, uv, mesh = first_hits(self.scenes[i], o, dirs)
            L = np.zeros((len(dirs), 3))
            on_proxy = mesh == 0
            if on_proxy.any():
                pts = o[on_proxy] + dirs[on_proxy] * t[on_proxy, None]
                ac = self.layout.texel_of(prim[on_proxy], pts)
                L[on_proxy] = bilinear(indirect_atlas, ac)
            for k, j in enumerate(self.others[i]):
                sel = mesh == k + 1
                if not sel.any():
                    continue
                oj = self.objects[j]
                direct = None
                if vals is not None and len(vals[0]):
                    p, nrm = hit_points(oj, prim[sel], uv[sel])
                    direct = self.direct_at(p, nrm, oj.albedo, vals)
                L[sel] = object_radiance(oj, prim[sel], uv[sel], prev[j], direct)
            out[i] = cubemap.project(L, self.res)
        return out

    def direct_at(self, p: np.ndarray, n: np.ndarray, albedo: np.ndarray,
                  vals: tuple[np.ndarray, ...]) -> np.ndarray:
        """Eq. 7 at points on virtual objects, visibility through proxy and objects."""
        P, N, I, A = vals
        x = p + n * 1e-4
        g = geometry_terms(x, n, P, N, A)
        for j in range(len(P)):
            live = g[:, j] > 0
            if live.any():
                tgt = np.broadcast_to(P[j] + N[j] * 1e-3, (int(live.sum()), 3))
                vis = segment_visible(self.proxy_scene, x[live], tgt)
                vis &= segment_visible(self.virtual_scene, x[live], tgt)
                g[live, j] *= vis
        return albedo / np.pi * (g @ I)


__all__ = ["IndirectProbes", "VirtualObject", "hit_points", "object_radiance"]
