"""RGB-D frames in, a reconstructed real proxy out: Open3D TSDF integration (Gruber §2).

Gruber et al. reconstruct with KinectFusion into a 2 m cube of 268³ voxels; we integrate the
frames with their given poses into Open3D's ``UniformTSDFVolume`` of the same shape (edge
``volume`` metres, ``resolution`` voxels per axis, placed automatically around the observed
points unless an origin is given), extract the zero level set by marching cubes and return it
as a real ``mesh`` :class:`~arlight.scene.model.Shape` with one assumed diffuse albedo, so the
backend traces it like any proxy.

Open3D's Linux wheels link ``libusb-1.0`` at import; :func:`open3d` loads the copy shipped by
the ``libusb-package`` wheel first when the system has none, so no system package is needed.
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass
from types import ModuleType

import numpy as np

from arlight.errors import InputError
from arlight.scene.camera import Camera
from arlight.scene.model import Material, MeshData, Shape

GRUBER_VOLUME = 2.0
"""Edge of Gruber's TSDF volume (m)."""
GRUBER_RESOLUTION = 268
"""Voxels per axis of Gruber's TSDF volume (voxel ≈ 7.46 mm)."""
SMOOTH_ITERATIONS = 100
"""Taubin smoothing passes over the marching-cubes mesh (λ = 0.5, μ = −0.53, Taubin 1995).

The TSDF takes each voxel's distance from the depth of the *pixel* it projects to, so where a
pixel's footprint on a surface is longer than a voxel (grazing views, low-resolution depth)
the zero level set is a staircase: on the synthetic room at 160×120 the vertex normals of the
floor are > 50° off on 10 % of the pixels (risers facing the camera), and E5, which reads the
light through those normals, is off by as much (upper-hemisphere error 0.53 with the exact
proxy's 0.32). Taubin's filter removes those short wavelengths without shrinking the surface;
KinectFusion smooths the same way implicitly (normals from the TSDF gradient over
neighbouring voxels). The number of passes was chosen from {0, 30, 100} on training light
setups (``benchmarks/tune_light_estimation.py --part setups``: training median
upper-hemisphere error 0.616 / 0.568 / 0.568 at Gruber's 10 cm and ridge 1e-3: 30 and
100 are alike, the rule, at 4 decimals, took 100), not on the Gruber setups it is reported
on."""
NORMAL_RADIUS = 0.05
"""Radius (m) of the plane fit that gives the reconstruction's vertex normals
(:func:`plane_fit_normals`; 0: the Taubin-smoothed mesh's own normals). Chosen on the
training light setups' reconstructions by the mean angle to the exact room's normals over
the frames' pixels (``benchmarks/tune_light_estimation.py --part setups``; radius 0 / 2 / 3 /
4 / 5 / 6 cm: 7.1 / 5.5 / 3.7 / 2.7 / 2.4 / 2.6° static camera, 2.8 / 2.2 / 1.8 / 1.5 / 1.4 /
1.8° moving). On Gruber's held-out SH cap light the upper-hemisphere error goes 0.344 →
0.290 (static), 0.285 → 0.251 (moving); the training light error is mixed (static
sequences gain, moving ones flat; docs/methods/probeless.md, *Plane-fit normals*)."""
NORMAL_GATE = 0.8
"""Only neighbours whose mesh normal has at least this cosine with the vertex's own take part
in its plane fit (the fit stays on one face of an edge)."""
NORMAL_NEIGHBOURS = 512
"""Most neighbours of a vertex in its plane fit (the nearest within the radius): bounds the
``(V, k)`` neighbour table: on the synthetic room's 7.5 mm-voxel surface a 5 cm ball holds
209 vertices at the median, 322 at p99."""


def open3d() -> ModuleType:
    """Import Open3D, loading ``libusb-package``'s libusb first if the system lacks it."""
    try:
        import open3d as o3d
    except ImportError as exc:
        if "libusb" not in str(exc):
            raise
        import libusb_package

        ctypes.CDLL(str(libusb_package.get_library_path()), mode=ctypes.RTLD_GLOBAL)
        import open3d as o3d
    return o3d


@dataclass
class RGBDFrame:
    """One RGB-D frame.

    Attributes:
        colour: linear RGB ``(H, W, 3)`` float32 (relative radiance).
        depth: depth along the camera's +z ``(H, W)`` float32 in metres; 0 or NaN unknown.
        camera: intrinsics and pose (``world_from_camera``, OpenCV axes).
        name: where it came from (file name), for error messages.
        timestamp: seconds.
    """

    colour: np.ndarray
    depth: np.ndarray
    camera: Camera
    name: str = ""
    timestamp: float = 0.0

    @property
    def valid_depth(self) -> np.ndarray:
        return np.isfinite(self.depth) & (self.depth > 0)


def _auto_origin(frames: list[RGBDFrame], volume: float, depth_trunc: float) -> np.ndarray:
    """Corner of the cube: centred on the middle of the observed points' 2nd-98th
    percentile box (a subsample), so a camera moving to one side keeps both ends."""
    pts = []
    for f in frames:
        ok = f.valid_depth & (f.depth < depth_trunc)
        v, u = np.nonzero(ok)
        if len(v) == 0:
            continue
        step = max(1, len(v) // 4000)
        v, u = v[::step], u[::step]
        z = f.depth[v, u].astype(np.float64)
        c = f.camera
        pc = np.stack([(u + 0.5 - c.cx) / c.fx * z, (v + 0.5 - c.cy) / c.fy * z, z], axis=1)
        m = c.world_from_camera
        pts.append(pc @ m[:3, :3].T + m[:3, 3])
    if not pts:
        return np.full(3, -volume / 2)
    lo, hi = np.percentile(np.concatenate(pts), [2, 98], axis=0)
    centre = (lo + hi) / 2
    return centre - volume / 2


def plane_fit_normals(vertices: np.ndarray, normals: np.ndarray, radius: float = NORMAL_RADIUS,
                      min_cos: float = NORMAL_GATE, neighbours: int = NORMAL_NEIGHBOURS
                      ) -> np.ndarray:
    """Vertex normals ``(V, 3)`` from a least-squares plane through each vertex's neighbours
    (Hoppe et al. 1992, "Surface reconstruction from unorganized points", §3.2): the
    eigenvector of the smallest eigenvalue of the neighbours' covariance

        C = Σ_j (q_j − q̄)(q_j − q̄)ᵀ,   q_j: the vertices within ``radius`` (m) whose mesh
        normal has cosine ≥ ``min_cos`` with the vertex's own,

    turned to the side of the mesh normal. The marching-cubes surface of a projective TSDF
    is a staircase where a depth pixel is longer than a voxel (grazing views): its
    triangle normals, Taubin-smoothed or not, lean toward the camera that saw it (the
    synthetic room's floor: 1.7° on average, 9° at p90), and E5 reads the light through
    them. A plane over a few centimetres averages the steps out; the normal gate keeps the
    fit on one face of an edge (without it a 3 cm fit at a box's edge takes both faces).
    Vertices with fewer than 6 such neighbours keep their mesh normal.

    Args:
        vertices, normals: ``(V, 3)``, the mesh's vertices (m) and unit normals.
        radius: neighbourhood radius (m); ``<= 0`` returns ``normals`` unchanged.
        min_cos: the normal gate.
        neighbours: at most this many nearest neighbours (bounds memory, ``V × k``).
    """
    from scipy.spatial import cKDTree

    v = np.asarray(vertices, np.float64).reshape(-1, 3)
    n = np.asarray(normals, np.float64).reshape(-1, 3)
    if len(v) != len(n):
        raise ValueError(f"{len(v)} vertices but {len(n)} normals")
    if radius <= 0 or len(v) == 0:
        return n.copy()
    k = int(min(neighbours, len(v)))
    tree = cKDTree(v)
    out = n.copy()
    for a in range(0, len(v), 1 << 12):  # bounded (chunk, k, 3) tables
        dist, idx = tree.query(v[a:a + (1 << 12)], k=k, distance_upper_bound=radius,
                               workers=-1)
        dist, idx = dist.reshape(len(dist), -1), idx.reshape(len(idx), -1)
        ok = np.isfinite(dist)
        idx = np.where(ok, idx, 0)
        # batched matmul, not einsum (6× faster on these (chunk, k, 3) tables)
        ok &= (n[idx] @ n[a:a + len(idx), :, None])[..., 0] >= min_cos
        w = ok.astype(np.float64)
        cnt = w.sum(axis=1)
        q = v[idx]
        mean = (w[:, None, :] @ q)[:, 0] / np.maximum(cnt, 1)[:, None]
        d = (q - mean[:, None, :]) * w[..., None]
        _, vecs = np.linalg.eigh(d.transpose(0, 2, 1) @ d)
        m = vecs[:, :, 0]
        m *= np.where(np.einsum("ic,ic->i", m, n[a:a + len(idx)]) < 0, -1.0, 1.0)[:, None]
        fit = cnt >= 6
        out[a:a + len(idx)][fit] = m[fit]
    return out


def reconstruct(frames: list[RGBDFrame], volume: float = GRUBER_VOLUME,
                resolution: int = GRUBER_RESOLUTION, sdf_trunc: float | None = None,
                depth_trunc: float = 4.0, origin: np.ndarray | None = None,
                albedo: float = 0.5, name: str = "reconstruction",
                smooth_iterations: int = SMOOTH_ITERATIONS,
                normal_radius: float = NORMAL_RADIUS) -> Shape:
    """TSDF-integrate ``frames`` and extract the mesh as a real proxy shape.

    Args:
        volume: cube edge (m). resolution: voxels per axis.
        sdf_trunc: truncation distance (m); default 4 voxels.
        depth_trunc: depths beyond this (m) are ignored.
        origin: cube corner (world, m); default centred on the observed points'
            2nd-98th percentile box.
        albedo: the diffuse albedo assumed for the reconstruction (E5's scale).
        smooth_iterations: Taubin passes over the mesh before its normals are computed
            (:data:`SMOOTH_ITERATIONS`; 0: the raw marching-cubes mesh).
        normal_radius: radius (m) of the plane fit of the vertex normals
            (:func:`plane_fit_normals`, :data:`NORMAL_RADIUS`; 0: the mesh's own normals).

    Raises:
        InputError: no frame has valid depth, or the volume holds no surface.
    """
    o3d = open3d()
    integ = o3d.pipelines.integration
    if not frames or not any(np.any(f.valid_depth) for f in frames):
        raise InputError("no frame has valid depth to reconstruct from", field="depth")
    voxel = volume / resolution
    trunc = float(sdf_trunc) if sdf_trunc is not None else 4 * voxel
    corner = _auto_origin(frames, volume, depth_trunc) if origin is None else np.asarray(
        origin, np.float64)
    tsdf = integ.UniformTSDFVolume(length=float(volume), resolution=int(resolution),
                                   sdf_trunc=trunc, color_type=integ.TSDFVolumeColorType.RGB8,
                                   origin=corner.reshape(3, 1))
    for f in frames:
        c = f.camera
        intr = o3d.camera.PinholeCameraIntrinsic(c.width, c.height, c.fx, c.fy,
                                                 c.cx - 0.5, c.cy - 0.5)
        col = (np.clip(f.colour, 0, 1) ** (1 / 2.2) * 255).astype(np.uint8)
        dep = np.where(f.valid_depth, f.depth, 0).astype(np.float32)
        rgbd = o3d.geometry.RGBDImage.create_from_color_and_depth(
            o3d.geometry.Image(np.ascontiguousarray(col)),
            o3d.geometry.Image(np.ascontiguousarray(dep)), depth_scale=1.0,
            depth_trunc=float(depth_trunc), convert_rgb_to_intensity=False)
        tsdf.integrate(rgbd, intr, np.linalg.inv(c.world_from_camera))
    mesh = tsdf.extract_triangle_mesh()
    mesh.remove_degenerate_triangles()
    mesh.remove_unreferenced_vertices()
    if len(mesh.triangles) == 0:
        raise InputError(f"the TSDF volume ({volume} m, {resolution}³ voxels at "
                         f"{corner.round(3).tolist()}) holds no surface; check the poses "
                         "and the volume", field="poses")
    if smooth_iterations > 0:
        mesh = mesh.filter_smooth_taubin(number_of_iterations=int(smooth_iterations))
    mesh.compute_vertex_normals()
    normals = plane_fit_normals(np.asarray(mesh.vertices), np.asarray(mesh.vertex_normals),
                                normal_radius)
    data = MeshData(vertices=np.asarray(mesh.vertices, np.float32),
                    faces=np.asarray(mesh.triangles, np.uint32),
                    normals=normals.astype(np.float32),
                    normals_from="recompute")
    mat = Material(f"{name}-material", "diffuse",
                   {"albedo": [albedo] * 3, "texture": None, "two_sided": True})
    return Shape(name=name, role="real", type="mesh", params={}, to_world=np.eye(4),
                 material=mat, mesh=data)


__all__ = ["GRUBER_RESOLUTION", "GRUBER_VOLUME", "NORMAL_GATE", "NORMAL_NEIGHBOURS",
           "NORMAL_RADIUS", "SMOOTH_ITERATIONS", "RGBDFrame", "open3d", "plane_fit_normals",
           "reconstruct"]
