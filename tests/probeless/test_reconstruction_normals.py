"""The reconstruction's normals against the exact geometry the frames were rendered from."""

from __future__ import annotations

import numpy as np

from arlight.backend.mitsuba_scene import build_views
from arlight.probeless import synthetic_rgbd as S
from arlight.probeless.pipeline import primary_hits
from arlight.probeless.reconstruct import reconstruct
from arlight.scene.model import World


def _floor_normal_error_deg(mesh, frames) -> np.ndarray:
    exact = build_views(World(shapes=S.room_shapes(), lights=[]))
    rec = build_views(World(shapes=[mesh], lights=[]))
    out = []
    for f in frames:
        ht = primary_hits(exact, f.rgbd.camera, mixed=False)
        hr = primary_hits(rec, f.rgbd.camera, mixed=False)
        ok = np.isfinite(ht.z) & np.isfinite(hr.z) & (ht.shape == 0)  # shape 0: the floor
        cos = np.einsum("hwc,hwc->hw", ht.normal, hr.normal)[ok]
        out.append(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    return np.concatenate(out)


def test_floor_normals_of_the_tsdf_reconstruction():
    """Two 160×120 frames of the room (depth from Mitsuba's ray casts of the exact shapes),
    TSDF-integrated at Gruber's 2 m / 268³: at 90 % of the floor pixels the reconstruction's
    shading normal is within 5° of the exact (0, 1, 0) (measured 2.0° with the 5 cm plane-fit
    normals). Rejects the Taubin-smoothed mesh's own normals (``normal_radius=0``: 14° at
    the 90th percentile, leaning toward the camera) and the raw marching-cubes mesh of the
    projective TSDF (``smooth_iterations=0``: staircase risers on the grazing far floor, 52°),
    whose normals E5 reads the light through."""
    frames = S.render_sequence("sh", n=2, width=160, height=120, spp=4)
    mesh = reconstruct([f.rgbd for f in frames], albedo=S.ALBEDO)
    err = _floor_normal_error_deg(mesh, frames)
    assert len(err) > 5000
    assert np.quantile(err, 0.9) < 5.0, np.quantile(err, 0.9)


def _staircase(tilt_deg: float, step: float = 0.0075) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices of a voxel staircase approximating the plane through the origin with normal
    ``(−sin t, cos t, 0)`` (treads with normal +y, risers with normal −x, the per-face
    normals a marching-cubes mesh of a grazing view has), and the plane's normal."""
    t = np.radians(tilt_deg)
    xs = np.arange(-0.2, 0.2, step / 4)
    zs = np.arange(-0.2, 0.2, step)
    x, z = np.meshgrid(xs, zs, indexing="ij")
    y = np.floor(x * np.tan(t) / step) * step  # the tread's height at x
    v = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    riser = np.abs(np.floor(x * np.tan(t) / step) - np.floor((x + step / 4) * np.tan(t) / step)) > 0
    n = np.where(riser.ravel()[:, None], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    return v, n, np.array([-np.sin(t), np.cos(t), 0.0])


def test_plane_fit_recovers_the_plane_under_a_staircase():
    """Vertices of a 7.5 mm staircase over a plane tilted 10° (treads +y, risers −x, as the
    marching-cubes surface of a projective TSDF): the 4 cm plane fit gives the plane's
    analytic normal within 2° (measured 1.5°) at every vertex 5 cm inside the patch, where
    the staircase's own normals are 10° or 90° off. Rejects the largest eigenvector (a
    tangent), a covariance not centred on the neighbours' mean (the normal points at the
    origin's side), a normal not turned to the mesh normal's side, and the mesh normals
    passed through."""
    from arlight.probeless.reconstruct import plane_fit_normals

    v, n, plane = _staircase(10.0)
    fit = plane_fit_normals(v + [0.0, 0.0, 0.5], n, radius=0.04, min_cos=-1.0)
    inner = np.all(np.abs(v[:, [0, 2]]) < 0.15, axis=1)
    ang = np.degrees(np.arccos(np.clip(fit[inner] @ plane, -1.0, 1.0)))
    assert ang.max() < 2.0, ang.max()
    assert np.degrees(np.arccos(np.clip(n[inner] @ plane, -1, 1))).min() > 9.0


def test_plane_fit_stays_on_its_face_at_an_edge():
    """Two faces of a box meeting at a right-angle edge, exact normals (+y and +x): with the
    normal gate, vertices 0.8–1.2 cm from the edge keep their own face's normal (within 0.5°); a fit
    without the gate (``min_cos = −1``) takes both faces and is off by > 10° there. Rejects a
    gate that compares positions instead of normals, or none."""
    from arlight.probeless.reconstruct import plane_fit_normals

    g = np.arange(0.0, 0.1, 0.004)
    a, b = np.meshgrid(g, np.arange(-0.1, 0.1, 0.004), indexing="ij")
    top = np.stack([-a.ravel(), np.zeros(a.size), b.ravel()], axis=1)   # y = 0, x ≤ 0
    side = np.stack([np.zeros(a.size), -a.ravel() - 0.004, b.ravel()], axis=1)  # x = 0
    v = np.concatenate([top, side])
    n = np.concatenate([np.tile([0.0, 1.0, 0.0], (len(top), 1)),
                        np.tile([1.0, 0.0, 0.0], (len(side), 1))])
    near = np.concatenate([(top[:, 0] > -0.014) & (top[:, 0] < -0.007),
                           np.zeros(len(side), bool)])
    near &= np.abs(v[:, 2]) < 0.05
    gated = plane_fit_normals(v, n, radius=0.03, min_cos=0.8)
    ang = np.degrees(np.arccos(np.clip(gated[near] @ [0.0, 1.0, 0.0], -1, 1)))
    assert near.sum() > 10 and ang.max() < 0.5, ang.max()
    blind = plane_fit_normals(v, n, radius=0.03, min_cos=-1.0)
    ang_b = np.degrees(np.arccos(np.clip(blind[near] @ [0.0, 1.0, 0.0], -1, 1)))
    assert ang_b.min() > 10.0, ang_b.min()
