"""Camera rays in Dr.Jit: multi-jittered pixel and lens samples, pinhole or thin lens.

Sample ``k`` of ``spp`` in a pixel is placed by *correlated multi-jittered* stratification
(Kensler 2013, with per-pixel cyclic shifts as the permutation) when ``spp = N²``: the pixel
is cut into N×N cells holding one sample each, and each of the N² thin columns and rows also
holds exactly one sample. An axis-aligned edge therefore gets a coverage error of at most
1/N² (the mask test of the foundation issue relies on this). The lens is stratified the same
way with the sample indices permuted, so pixel and lens strata are decorrelated (Kán §3.4:
"stratified jittered sampling of the pixel area and the aperture"). Other ``spp`` use
independent uniform samples.

All random numbers are hashes (TEA) of (seed, pixel, sample index), so any subset of samples
can be drawn in any order and two renders with the same seed are bitwise identical.
:func:`rays_from_samples` builds the rays from given pixel and lens samples (the Sobol
sampler's, :mod:`arlight.sampling.stream`).
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi

from arlight.jit import opaque
from arlight.sampling.stream import pixel_key
from arlight.scene.camera import Camera

_SALT_JITTER_X, _SALT_JITTER_Y, _SALT_SHIFT_X, _SALT_SHIFT_Y = 1, 2, 3, 4
_LENS_SALT = 1 << 16


def _uniform(key: mi.UInt32, salt: mi.UInt32) -> mi.Float:
    return mi.sample_tea_float32(key, salt, 6)


def _lens_permutation(spp: int) -> int:
    """A multiplier coprime to ``spp`` that scatters consecutive sample indices."""
    a = max(1, int(spp * 0.6180339887))
    while math.gcd(a, spp) != 1:
        a += 1
    return a


def stratified_2d(key: mi.UInt32, k: mi.UInt32, spp: int, salt: int) -> mi.Point2f:
    """Point in [0,1)² for sample ``k`` of ``spp`` (multi-jittered when spp is a square).

    Args:
        key: per-pixel hash (includes the seed).
        k: sample index in ``[0, spp)``.
        spp: samples per pixel of the full render (not of one pass).
        salt: separates independent 2D dimensions (pixel vs lens).
    """
    n = math.isqrt(spp)
    s = mi.UInt32(salt)
    jx = _uniform(key ^ (k * 0x9E3779B9), s + _SALT_JITTER_X)
    jy = _uniform(key ^ (k * 0x9E3779B9), s + _SALT_JITTER_Y)
    if n * n != spp or n == 1:
        return mi.Point2f(jx, jy)
    # n opaque: one kernel serves every square spp
    n, nf = dr.opaque(mi.UInt32, n), opaque(n)
    i = k % n
    j = k // n
    shift_i = mi.UInt32(dr.floor(_uniform(key ^ (i * 0x85EBCA6B), s + _SALT_SHIFT_X) * nf))
    shift_j = mi.UInt32(dr.floor(_uniform(key ^ (j * 0xC2B2AE35), s + _SALT_SHIFT_Y) * nf))
    sub_x = (j + dr.minimum(shift_i, n - 1)) % n
    sub_y = (i + dr.minimum(shift_j, n - 1)) % n
    x = (mi.Float(i) + (mi.Float(sub_x) + jx) / nf) / nf
    y = (mi.Float(j) + (mi.Float(sub_y) + jy) / nf) / nf
    return mi.Point2f(dr.minimum(x, dr.one_minus_epsilon(mi.Float)),
                      dr.minimum(y, dr.one_minus_epsilon(mi.Float)))


def generate_rays(camera: Camera, pixel: mi.UInt32, k: mi.UInt32, spp: int,
                  seed: mi.UInt32) -> mi.RayDifferential3f:
    """World-space camera rays for (pixel index, sample index) lanes.

    Pixel index ``p = row * width + col``; the sample position inside the pixel comes from
    :func:`stratified_2d`. With ``camera.aperture_radius > 0`` the thin-lens model of Kán
    Eq. 3.1–3.3 applies (disk via the concentric map, or Kán's square aperture).
    """
    key = pixel_key(pixel, seed)
    off = stratified_2d(key, k, spp, 0)
    lens_u = None
    if camera.aperture_radius > 0:
        k_lens = (k * dr.opaque(mi.UInt32, _lens_permutation(spp))) % dr.opaque(mi.UInt32, spp)
        lens_u = stratified_2d(key, k_lens, spp, _LENS_SALT)
    return rays_from_samples(camera, pixel, off, lens_u)


class Projection:
    """The pinhole projection of world points into a camera's image, in Dr.Jit, with the
    camera's pose, intrinsics and size as opaque values (:func:`opaque`: a moved camera
    reuses the compiled kernels). Pixel ``(u, v)``: column, row in pixels, OpenCV
    convention; ``z``: camera-space depth, metres (≤ 0 behind the camera)."""

    def __init__(self, camera: Camera):
        m = camera.camera_from_world()
        self.rows = [[opaque(m[r][c]) for c in range(4)] for r in range(3)]
        self.fx, self.fy = opaque(camera.fx), opaque(camera.fy)
        self.cx, self.cy = opaque(camera.cx), opaque(camera.cy)
        self.center = mi.Point3f(*(opaque(x) for x in camera.position))
        self.width = dr.opaque(mi.UInt32, camera.width)
        self.height = dr.opaque(mi.UInt32, camera.height)

    def camera_space(self, p: mi.Point3f) -> list[mi.Float]:
        """``p`` in camera coordinates (x right, y down, z forward), metres."""
        r = self.rows
        return [r[i][0] * p.x + r[i][1] * p.y + r[i][2] * p.z + r[i][3] for i in range(3)]

    def project(self, p: mi.Point3f, min_z: float = 0.0) -> tuple[mi.Float, mi.Float, mi.Float]:
        """``(u, v, z)`` of ``p``; ``|z|`` below ``min_z`` is raised to it first (keeps
        ``u, v`` finite behind or at the camera)."""
        x, y, z = self.camera_space(p)
        if min_z > 0:
            z = dr.select(dr.abs(z) > min_z, z, min_z)
        return self.fx * x / z + self.cx, self.fy * y / z + self.cy, z


def rays_from_samples(camera: Camera, pixel: mi.UInt32, off: mi.Point2f,
                      lens_u: mi.Point2f | None) -> mi.RayDifferential3f:
    """World-space camera rays through ``pixel`` at offsets ``off`` ∈ [0,1)² inside the
    pixel, with lens samples ``lens_u`` ∈ [0,1)² (ignored for a pinhole; needed otherwise).
    The camera's pose, intrinsics and width enter the kernel as opaque values
    (:func:`opaque`): a moving camera reuses the compiled tracer.
    """
    width = dr.opaque(mi.UInt32, camera.width)
    col = mi.Float(pixel % width)
    row = mi.Float(pixel // width)
    dx = (col + off.x - opaque(camera.cx)) / opaque(camera.fx)
    dy = (row + off.y - opaque(camera.cy)) / opaque(camera.fy)
    d = mi.Vector3f(dx, dy, 1.0)
    o = mi.Vector3f(0.0)
    if camera.aperture_radius > 0:
        u = lens_u
        if camera.aperture_shape == "disk":
            lens = mi.warp.square_to_uniform_disk_concentric(u)
        else:
            lens = mi.Point2f(2.0 * u.x - 1.0, 2.0 * u.y - 1.0)
        radius = opaque(camera.aperture_radius)
        o = mi.Vector3f(lens.x * radius, lens.y * radius, 0.0)
        d = d * opaque(camera.focus_distance) - o
    d = dr.normalize(d)
    m = camera.world_from_camera
    rot = [[opaque(m[r][c]) for c in range(3)] for r in range(3)]
    world_d = mi.Vector3f(*(rot[r][0] * d.x + rot[r][1] * d.y + rot[r][2] * d.z
                            for r in range(3)))
    world_o = mi.Point3f(*(rot[r][0] * o.x + rot[r][1] * o.y + rot[r][2] * o.z
                           + opaque(m[r][3]) for r in range(3)))
    return mi.RayDifferential3f(world_o, world_d)
