"""The radiance atlas's geometry: the real proxy as triangles, a chart layout in UV space and
per-texel world position, normal and area (Rohmer §4.1; digest §5.1).

Rohmer rasterises the reconstructed scene in the UV space of its (hand-made) atlas layout.
Here every real shape is triangulated (:func:`proxy_mesh`: mesh files as they are, boxes and
rectangles exactly, disks and spheres tessellated), and a **chart layout** is generated
(:func:`layout_charts`): coplanar faces of one shape form a chart, mapped isometrically
(metres → texels by one global texel size), shelf-packed into the square atlas with a gutter
wider than the dilation. Because the map is isometric, a fully covered texel has area
``texel_size²`` exactly; texels on a chart's border get their covered fraction (``ss × ss``
sub-samples per texel) and the centroid of the covered part as position.

The atlas is also where a ray hit on the proxy is looked up (:meth:`AtlasLayout.texel_of`):
every face keeps its affine world → atlas map.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from arlight.errors import InputError
from arlight.scene.model import Shape, World

GUTTER = 4
"""Empty texels around each chart (≥ dilation range + 2, so dilated charts never touch)."""


@dataclass
class ProxyMesh:
    """All real shapes as one world-space triangle mesh.

    Attributes:
        vertices: (V, 3) float64 world positions, m.
        faces: (F, 3) int64 vertex indices (counter-clockwise around ``face_normals``).
        face_normals: (F, 3) unit geometric normals.
        face_shape: (F,) index of the face's shape in ``World.shapes``.
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_normals: np.ndarray
    face_shape: np.ndarray

    @property
    def face_areas(self) -> np.ndarray:
        """(F,) triangle areas, m²."""
        v = self.vertices[self.faces]
        return 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)


def _transform(m: np.ndarray, v: np.ndarray) -> np.ndarray:
    return v @ m[:3, :3].T + m[:3, 3]


def _canonical(shape: Shape) -> tuple[np.ndarray, np.ndarray]:
    """Object-space vertices and faces of a shape (Mitsuba's canonical primitives)."""
    p = shape.params
    if shape.type == "mesh":
        if shape.mesh is None:
            raise InputError("mesh shape has no mesh data", field=f"shapes.{shape.name}")
        return (np.asarray(shape.mesh.vertices, np.float64),
                np.asarray(shape.mesh.faces, np.int64).reshape(-1, 3))
    if shape.type == "rectangle":
        sx, sy = p["size"][0] / 2, p["size"][1] / 2
        v = np.array([[-sx, -sy, 0], [sx, -sy, 0], [sx, sy, 0], [-sx, sy, 0]], np.float64)
        return v, np.array([[0, 1, 2], [0, 2, 3]])
    if shape.type == "box":
        h = np.asarray(p["size"], np.float64) / 2
        verts, faces = [], []
        for axis in range(3):
            for sign in (-1.0, 1.0):
                u, w = (axis + 1) % 3, (axis + 2) % 3
                quad = []
                for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                    c = np.zeros(3)
                    c[axis], c[u], c[w] = sign, a, b
                    quad.append(c * h)
                base = len(verts)
                verts += quad
                f = [[0, 1, 2], [0, 2, 3]] if sign > 0 else [[0, 2, 1], [0, 3, 2]]
                faces += [[base + i for i in t] for t in f]
        return np.array(verts), np.array(faces)
    if shape.type == "disk":
        r = float(p["radius"])
        a = np.linspace(0, 2 * np.pi, 33)[:-1]
        v = np.vstack([[0, 0, 0], np.stack([r * np.cos(a), r * np.sin(a), 0 * a], 1)])
        f = [[0, 1 + i, 1 + (i + 1) % 32] for i in range(32)]
        return v, np.array(f)
    if shape.type == "sphere":
        r = float(p["radius"])
        th = np.linspace(0, np.pi, 13)
        ph = np.linspace(0, 2 * np.pi, 25)[:-1]
        v = [[0, 0, r]]
        for t in th[1:-1]:
            v += [[r * np.sin(t) * np.cos(q), r * np.sin(t) * np.sin(q), r * np.cos(t)]
                  for q in ph]
        v.append([0, 0, -r])
        n, rings = len(ph), len(th) - 2
        f = [[0, 1 + i, 1 + (i + 1) % n] for i in range(n)]
        for k in range(rings - 1):
            a0, b0 = 1 + k * n, 1 + (k + 1) * n
            for i in range(n):
                j = (i + 1) % n
                f += [[a0 + i, b0 + i, b0 + j], [a0 + i, b0 + j, a0 + j]]
        last = len(v) - 1
        a0 = 1 + (rings - 1) * n
        f += [[a0 + i, last, a0 + (i + 1) % n] for i in range(n)]
        return np.array(v, np.float64), np.array(f)
    raise InputError(f"shape type {shape.type!r} cannot be part of the radiance atlas",
                     field=f"shapes.{shape.name}")


def proxy_mesh(world: World) -> ProxyMesh:
    """The real shapes of ``world`` as one world-space triangle mesh (degenerate faces
    dropped).

    Raises:
        InputError: the world has no real shape (there is nothing to project light onto).
    """
    verts, faces, shape_of = [], [], []
    base = 0
    for i, s in enumerate(world.shapes):
        if s.is_virtual:
            continue
        v, f = _canonical(s)
        m = np.asarray(s.to_world, np.float64)
        if np.linalg.det(m[:3, :3]) < 0:
            f = f[:, ::-1]
        verts.append(_transform(m, v))
        faces.append(f + base)
        shape_of.append(np.full(len(f), i))
        base += len(v)
    if not faces:
        raise InputError("the world has no real shape: the radiance atlas needs the proxy",
                         field="shapes")
    v = np.concatenate(verts)
    f = np.concatenate(faces).astype(np.int64)
    s = np.concatenate(shape_of)
    tri = v[f]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    ln = np.linalg.norm(n, axis=1)
    keep = ln > 1e-12
    return ProxyMesh(v, f[keep], n[keep] / ln[keep, None], s[keep])


@dataclass
class AtlasLayout:
    """Where every proxy face lies in the atlas.

    Attributes:
        resolution: atlas side, texels.
        texel_size: texel edge in metres (the charts are isometric).
        face_chart: (F,) chart index per face.
        face_uv: (F, 3, 2) atlas coordinates (x = column, y = row, in texels, texel
            ``(r, c)`` spans ``[c, c+1] × [r, r+1]``) of each face's corners.
        world_to_atlas: (F, 2, 4) affine map of each face: world point (homogeneous) →
            atlas coordinates.
        charts: number of charts.
    """

    resolution: int
    texel_size: float
    face_chart: np.ndarray
    face_uv: np.ndarray
    world_to_atlas: np.ndarray
    charts: int

    def texel_of(self, face: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Continuous atlas coordinates ``(N, 2)`` of world ``points`` (N, 3) on ``face``."""
        a = self.world_to_atlas[np.asarray(face, np.int64)]
        p = np.concatenate([np.asarray(points, np.float64), np.ones((len(points), 1))], 1)
        return np.einsum("nij,nj->ni", a, p)


def _charts(mesh: ProxyMesh) -> list[np.ndarray]:
    """Faces grouped by shape and plane (normal and offset to 1e-6)."""
    d = np.einsum("fi,fi->f", mesh.face_normals, mesh.vertices[mesh.faces[:, 0]])
    key = np.concatenate([mesh.face_shape[:, None].astype(np.float64),
                          np.round(mesh.face_normals * 1e6), np.round(d[:, None] * 1e6)], 1)
    _, inverse = np.unique(key, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    order = np.argsort(inverse, kind="stable")
    splits = np.flatnonzero(np.diff(inverse[order])) + 1
    return np.split(order, splits)


def _chart_frame(mesh: ProxyMesh, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                               np.ndarray]:
    """Origin and in-plane axes (u, v) of a chart (u along the first face's first edge)."""
    f0 = mesh.faces[faces[0]]
    n = mesh.face_normals[faces[0]]
    e = mesh.vertices[f0[1]] - mesh.vertices[f0[0]]
    u = e / np.linalg.norm(e)
    v = np.cross(n, u)
    return mesh.vertices[f0[0]], u, v


def _shelf_pack(sizes: np.ndarray, res: int) -> np.ndarray | None:
    """Top-left texel offsets ``(C, 2)`` (x, y) packing rectangles ``sizes (C, 2)`` (w, h)
    into ``res × res`` by shelves of decreasing height, or None when they do not fit."""
    order = np.argsort(-sizes[:, 1], kind="stable")
    out = np.zeros((len(sizes), 2), np.int64)
    x = y = shelf = 0
    for c in order:
        w, h = sizes[c]
        if w > res:
            return None
        if x + w > res:
            y += shelf
            x = shelf = 0
        if y + h > res:
            return None
        out[c] = (x, y)
        x += w
        shelf = max(shelf, h)
    return out


def layout_charts(mesh: ProxyMesh, resolution: int) -> AtlasLayout:
    """Generate the chart layout (module docstring): the smallest texel size (largest
    charts) for which all charts fit."""
    groups = _charts(mesh)
    frames = [_chart_frame(mesh, g) for g in groups]
    local = []
    for g, (o, u, v) in zip(groups, frames, strict=True):
        p = mesh.vertices[mesh.faces[g]] - o  # (n, 3, 3)
        local.append(np.stack([p @ u, p @ v], -1))
    lo = np.array([q.reshape(-1, 2).min(0) for q in local])
    ext = np.array([q.reshape(-1, 2).max(0) for q in local]) - lo
    total = float(mesh.face_areas.sum())
    s = np.sqrt(total / (0.6 * resolution**2))
    for _ in range(200):
        sizes = np.ceil(ext / s).astype(np.int64) + 1 + 2 * GUTTER
        offs = _shelf_pack(sizes, resolution)
        if offs is not None:
            break
        s *= 1.05
    else:  # pragma: no cover - 200 steps of 5 % cover any layout
        raise InputError(f"the proxy's {len(groups)} charts do not fit a {resolution}² atlas",
                         field="atlas_resolution")
    F = len(mesh.faces)
    face_chart = np.zeros(F, np.int64)
    face_uv = np.zeros((F, 3, 2))
    w2a = np.zeros((F, 2, 4))
    for c, (g, (o, u, v)) in enumerate(zip(groups, frames, strict=True)):
        start = offs[c] + GUTTER
        # atlas = (local - lo) / s + start; local = (p - o)·(u, v)
        A = np.stack([u, v]) / s  # (2, 3)
        b = -A @ o - lo[c] / s + start
        face_chart[g] = c
        face_uv[g] = (local[c] - lo[c]) / s + start
        w2a[g, :, :3] = A
        w2a[g, :, 3] = b
    return AtlasLayout(resolution, float(s), face_chart, face_uv, w2a, len(groups))


@dataclass
class AtlasGeometry:
    """Per-texel world geometry of the atlas (``(R, R, …)`` arrays, row-major).

    Attributes:
        position: (R, R, 3) centroid of the covered part of each texel, m.
        normal: (R, R, 3) unit surface normal (0 on empty texels).
        area: (R, R) world-space area ΔA covered by the texel, m² (0: empty).
        face: (R, R) int64 proxy face covering the texel's centroid (−1: empty).
    """

    position: np.ndarray
    normal: np.ndarray
    area: np.ndarray
    face: np.ndarray

    @property
    def covered(self) -> np.ndarray:
        return self.area > 0


def rasterize(mesh: ProxyMesh, layout: AtlasLayout, supersample: int = 4) -> AtlasGeometry:
    """Texel positions, normals and areas by ``supersample²`` sub-samples per texel (the
    UV-space rasterisation of Rohmer §4.1)."""
    R, ss = layout.resolution, int(supersample)
    cover = np.zeros((R, R))
    psum = np.zeros((R, R, 3))
    normal = np.zeros((R, R, 3))
    face = np.full((R, R), -1, np.int64)
    sub = (np.arange(ss) + 0.5) / ss
    taken = np.zeros((R * ss, R * ss), bool)  # a sub-sample on a shared edge counts once
    for f in range(len(mesh.faces)):
        uv = layout.face_uv[f]
        x0, y0 = np.floor(uv.min(0)).astype(int)
        x1, y1 = np.ceil(uv.max(0)).astype(int)
        xs = (np.arange(x0, x1)[:, None] + sub[None, :]).reshape(-1)
        ys = (np.arange(y0, y1)[:, None] + sub[None, :]).reshape(-1)
        px, py = np.meshgrid(xs, ys)  # (rows*ss, cols*ss)
        a, b, c = uv
        det = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1])
        l1 = ((px - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (py - a[1])) / det
        l2 = ((b[0] - a[0]) * (py - a[1]) - (px - a[0]) * (b[1] - a[1])) / det
        l0 = 1.0 - l1 - l2
        eps = -1e-12
        inside = (l0 >= eps) & (l1 >= eps) & (l2 >= eps)
        inside &= ~taken[y0 * ss:y1 * ss, x0 * ss:x1 * ss]
        taken[y0 * ss:y1 * ss, x0 * ss:x1 * ss] |= inside
        if not inside.any():
            continue
        tri = mesh.vertices[mesh.faces[f]]
        pos = l0[..., None] * tri[0] + l1[..., None] * tri[1] + l2[..., None] * tri[2]
        h, w = (y1 - y0), (x1 - x0)
        ins = inside.reshape(h, ss, w, ss)
        cnt = ins.sum(axis=(1, 3)).astype(np.float64)
        ps = (pos.reshape(h, ss, w, ss, 3) * ins[..., None]).sum(axis=(1, 3))
        cover[y0:y1, x0:x1] += cnt / ss**2
        psum[y0:y1, x0:x1] += ps
        hit = cnt > 0
        normal[y0:y1, x0:x1][hit] = mesh.face_normals[f]
        face[y0:y1, x0:x1][hit] = f
    area = cover * layout.texel_size**2
    counts = cover * ss**2
    pos = np.where(counts[..., None] > 0, psum / np.maximum(counts, 1)[..., None], 0.0)
    return AtlasGeometry(pos, normal, area, face)


def dilate(values: np.ndarray, valid: np.ndarray, steps: int = 2) -> np.ndarray:
    """Fill texels within ``steps`` texels of valid ones with the mean of their valid
    8-neighbours, one ring per step (Rohmer §4.1: "dilatation … with a range of 2 texels"
    hides seams); valid texels are unchanged. Only the ring texels are computed (a gather
    from a 1-texel padded copy); float32 input stays float32."""
    values = np.asarray(values)
    dt = np.float32 if values.dtype == np.float32 else np.float64
    R0, R1 = values.shape[:2]
    C = values.shape[2] if values.ndim == 3 else 1
    W = R1 + 2
    pad = np.zeros((R0 + 2, W, C), dt)
    pad[1:-1, 1:-1] = values.reshape(R0, R1, C)
    ok = np.zeros((R0 + 2, W), bool)
    ok[1:-1, 1:-1] = np.asarray(valid, bool)
    flat_v, flat_ok = pad.reshape(-1, C), ok.reshape(-1)
    offsets = [dy * W + dx for dy in (-1, 0, 1) for dx in (-1, 0, 1) if dy or dx]
    inner = np.zeros_like(ok)
    inner[1:-1, 1:-1] = True
    for _ in range(int(steps)):
        near = np.zeros_like(ok)
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                if dy or dx:
                    near[1:-1, 1:-1] |= ok[1 + dy:R0 + 1 + dy, 1 + dx:R1 + 1 + dx]
        idx = np.flatnonzero(near & ~ok & inner)
        if len(idx) == 0:
            break
        acc = np.zeros((len(idx), C), dt)
        n = np.zeros(len(idx), dt)
        for o in offsets:
            m = flat_ok[idx + o]
            acc += flat_v[idx + o] * m[:, None]
            n += m
        flat_v[idx] = acc / n[:, None]
        flat_ok[idx] = True
    out = pad[1:-1, 1:-1]
    return out.copy() if values.ndim == 3 else out[..., 0].copy()


__all__ = ["GUTTER", "AtlasGeometry", "AtlasLayout", "ProxyMesh", "dilate", "layout_charts",
           "proxy_mesh", "rasterize"]
