"""Reading triangle meshes and their vertex normals (NumPy only, deterministic).

:func:`read_mesh` reads a mesh file through trimesh (without merging or reordering vertices)
and, for PLY and OBJ files, the per-vertex normals stored in the file (trimesh reads them
but does not keep them on the mesh). :func:`vertex_normals` recomputes smooth normals.

Normals are computed here, in float64 on the CPU, rather than by Mitsuba's
``Mesh.recompute_vertex_normals``: that one accumulates face normals into vertices with
parallel float atomics, whose order — hence the rounding of the sums — changes from run to
run, so a render of a mesh was not reproducible bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

FILE_NORMAL_FORMATS = (".ply", ".obj")
"""Formats whose stored vertex normals are read (others always get recomputed normals)."""


@dataclass(frozen=True)
class RawMesh:
    """A mesh as read from a file: positions ``(V, 3)`` float64, faces ``(F, 3)`` int64,
    optional ``uv (V, 2)`` and the file's unit vertex normals ``(V, 3)`` (None if absent)."""

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray | None
    normals: np.ndarray | None


def read_mesh(path: str | Path) -> RawMesh:
    """Read a mesh file (PLY, OBJ, glTF/GLB, STL, OFF) without processing its vertices.

    Raises whatever trimesh raises for unreadable files; the caller names the field.
    """
    import trimesh

    path = Path(path)
    ext = path.suffix.lower()
    normals: np.ndarray | None = None
    if ext == ".obj":
        mesh, normals = _read_obj(path)
    else:
        mesh = trimesh.load(path, force="mesh", process=False)
        if ext == ".ply":
            normals = _ply_normals(mesh)
    verts = np.asarray(getattr(mesh, "vertices", np.zeros((0, 3))), dtype=np.float64)
    faces = np.asarray(getattr(mesh, "faces", np.zeros((0, 3))), dtype=np.int64)
    uv = getattr(getattr(mesh, "visual", None), "uv", None)
    uv = None if uv is None or len(uv) != len(verts) else np.asarray(uv, np.float64)
    if normals is not None and normals.shape != verts.shape:
        normals = None
    return RawMesh(verts, faces.reshape(-1, 3), uv, normals)


def _ply_normals(mesh) -> np.ndarray | None:
    """The ``nx, ny, nz`` vertex properties of a PLY file, in file order (None if absent)."""
    raw = getattr(mesh, "metadata", {}).get("_ply_raw", {})
    data = raw.get("vertex", {}).get("data") if isinstance(raw, dict) else None
    names = getattr(getattr(data, "dtype", None), "names", None) or ()
    if not {"nx", "ny", "nz"} <= set(names):
        return None
    return np.stack([np.asarray(data[k], np.float64).ravel() for k in ("nx", "ny", "nz")],
                    axis=1)


def _read_obj(path: Path):
    """An OBJ file as one trimesh mesh plus its ``vn`` normals per (split) vertex.

    trimesh's OBJ reader splits vertices where position/uv/normal combinations differ and
    returns the matching normals; the geometries of a multi-object file are concatenated in
    file order (as ``trimesh.load(..., force="mesh")`` does).
    """
    import trimesh

    with open(path, "rb") as f:
        kw = trimesh.exchange.obj.load_obj(f)
    geoms = list(kw["geometry"].values()) if "geometry" in kw else [kw]
    meshes, normals = [], []
    for g in geoms:
        g = dict(g)
        n = g.pop("vertex_normals", None)
        m = trimesh.Trimesh(process=False, **g)
        meshes.append(m)
        ok = n is not None and np.shape(n) == np.shape(m.vertices)
        normals.append(np.asarray(n, np.float64) if ok else None)
    mesh = meshes[0] if len(meshes) == 1 else trimesh.util.concatenate(meshes)
    if any(n is None for n in normals):
        return mesh, None
    return mesh, np.concatenate(normals, axis=0)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Smooth unit vertex normals ``(V, 3)`` float64 of a triangle mesh.

    Each face's unit normal is added to its three corners weighted by the corner angle
    (radians; the weighting of Mitsuba's ``recompute_vertex_normals``), summed over all
    vertices at the same position — so seams where a file splits vertices (texture or
    material borders) stay smooth — and normalised. Sums run in float64 in a fixed order:
    the result is the same on every run. Vertices used by no (non-degenerate) face get the
    normal ``(0, 0, 1)``.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    _, weld = np.unique(v, axis=0, return_inverse=True)
    weld = weld.ravel()
    p = v[f]  # (F, 3 corners, 3)
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
    acc = np.zeros((weld.max() + 1 if len(weld) else 0, 3))
    for c in range(3):
        d0 = p[:, (c + 1) % 3] - p[:, c]
        d1 = p[:, (c + 2) % 3] - p[:, c]
        l0 = np.linalg.norm(d0, axis=1)
        l1 = np.linalg.norm(d1, axis=1)
        cos = np.einsum("ij,ij->i", d0, d1) / np.maximum(l0 * l1, 1e-300)
        angle = np.arccos(np.clip(cos, -1.0, 1.0))
        np.add.at(acc, weld[f[:, c]], n * angle[:, None])
    out = acc[weld]
    length = np.linalg.norm(out, axis=1, keepdims=True)
    fallback = np.broadcast_to([0.0, 0.0, 1.0], out.shape)
    return np.where(length > 0, out / np.where(length > 0, length, 1.0), fallback)


def unit_normals(normals: np.ndarray) -> np.ndarray | None:
    """``normals`` normalised to unit length, or None if any is zero or not finite."""
    n = np.asarray(normals, dtype=np.float64)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    if not np.all(np.isfinite(n)) or np.any(length == 0):
        return None
    return n / length
