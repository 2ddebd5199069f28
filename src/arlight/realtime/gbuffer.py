"""A G-buffer by ray casting: per camera sample the first hit's position, normal, diffuse
albedo, role (real / virtual / miss) and depth (Franke §4.5: "a G-Buffer G that contains the
reconstructed albedo of the real scene as well as the albedo of the virtual object, a mask
tagging real geometry and normals").

One sample per pixel by default (the rasteriser's G-buffer); ``spp > 1`` gives stratified
(multi-jittered) samples for anti-aliasing, reduced by :func:`resolve`. Rays come from
:func:`arlight.backend.camera_rays.generate_rays`, so they are deterministic in the seed.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.camera_rays import generate_rays
from arlight.backend.mitsuba_scene import ROLE_MISS, ROLE_VIRTUAL, SceneView
from arlight.layers import Layers
from arlight.scene.camera import Camera


@dataclass
class GBuffer:
    """Dr.Jit arrays of ``width · height · spp`` lanes (sample ``k`` of pixel ``p`` at lane
    ``p · spp + k``).

    Attributes:
        position: world hit points (m).
        normal: unit shading normals turned towards the camera.
        albedo: diffuse reflectance at the hit (Mitsuba's ``eval_diffuse_reflectance``,
            textures included; 0 for purely specular materials).
        role: −1 miss, 0 real, 1 virtual.
        depth: distance along the ray (m), ``inf`` on a miss.
        pixel: pixel index ``row · width + col`` of each lane.
        to_camera: unit direction from the hit towards the camera.
        spp, width, height: layout.
        shape: index of the hit shape in the world's ``shapes`` (−1 miss; None when the
            G-buffer was built without it).
    """

    position: mi.Point3f
    normal: mi.Vector3f
    albedo: mi.Color3f
    role: mi.Int32
    depth: mi.Float
    pixel: mi.UInt32
    to_camera: mi.Vector3f
    spp: int
    width: int
    height: int
    shape: mi.Int32 | None = None

    @property
    def valid(self) -> mi.Bool:
        return self.role != ROLE_MISS

    @property
    def virtual(self) -> mi.Bool:
        return self.role == ROLE_VIRTUAL


def surface_albedo(si: mi.SurfaceInteraction3f, active: mi.Bool) -> mi.Color3f:
    """Diffuse reflectance of the BSDF at ``si``: 0 where inactive and for BSDFs without a
    diffuse lobe (metals, glass, mirrors — Mitsuba's default ``eval_diffuse_reflectance``
    evaluates the whole BRDF at normal incidence, ~2.4 for a rough conductor)."""
    bsdf = si.bsdf()
    diffuse = active & mi.has_flag(bsdf.flags(), mi.BSDFFlags.DiffuseReflection)
    alb = bsdf.eval_diffuse_reflectance(si, diffuse)
    return dr.select(diffuse, mi.Color3f(alb), mi.Color3f(0.0))


def facing(n: mi.Vector3f, towards: mi.Vector3f) -> mi.Vector3f:
    """``n`` flipped, where needed, into the hemisphere of ``towards`` (two-sided shading)."""
    return dr.select(dr.dot(n, towards) < 0.0, -n, n)


def render_gbuffer(view: SceneView, camera: Camera, spp: int = 1, seed: int = 0) -> GBuffer:
    """Cast ``spp`` primary rays per pixel into ``view`` (usually ``views.mixed``)."""
    w, h = camera.width, camera.height
    lanes = dr.arange(mi.UInt32, w * h * spp)
    pixel = lanes // spp
    k = lanes % spp
    rays = generate_rays(camera, pixel, k, spp, dr.opaque(mi.UInt32, seed))  # opaque: one
    # kernel for every frame's seed
    ray = mi.Ray3f(rays)
    si = view.scene.ray_intersect(ray)
    role = view.hit_role(si)
    valid = si.is_valid()
    to_cam = -ray.d
    n = facing(mi.Vector3f(si.sh_frame.n), to_cam)
    albedo = surface_albedo(si, valid)
    depth = dr.select(valid, si.t, dr.inf)
    pos = mi.Point3f(si.p)
    shape = view.hit_shape(si)
    dr.eval(pos, n, albedo, role, depth, pixel, to_cam, shape)
    return GBuffer(pos, n, albedo, role, depth, pixel, to_cam, spp, w, h, shape)


def resolve(gb: GBuffer, values: mi.Color3f) -> np.ndarray:
    """Per-pixel mean ``(H, W, 3)`` float32 of per-lane values."""
    arr = np.stack([np.asarray(ch, dtype=np.float32) for ch in (values.x, values.y,
                                                                values.z)], axis=-1)
    if gb.spp == 1:
        return arr.reshape(gb.height, gb.width, 3)
    return arr.reshape(gb.height, gb.width, gb.spp, 3).mean(axis=2)


def resolve_scalar(gb: GBuffer, values: mi.Float) -> np.ndarray:
    """Per-pixel mean ``(H, W)`` float32 of per-lane scalars."""
    arr = np.array(values, dtype=np.float32)
    if gb.spp == 1:
        return arr.reshape(gb.height, gb.width)
    return arr.reshape(gb.height, gb.width, gb.spp).mean(axis=2)


def assemble(gb: GBuffer, frame: np.ndarray, mixed: mi.Color3f, delta: mi.Color3f,
             stats: dict) -> Layers:
    """Per-pixel layers from per-sample shading: ``mask`` = virtual fraction, ``mixed`` =
    mean over virtual samples (``B + delta`` where none), ``delta`` = mean over the other
    samples, so the composite is the per-sample composite's mean."""
    virt = resolve_scalar(gb, mi.Float(gb.virtual))
    bg = np.asarray(frame, np.float32)
    covered = virt > 0  # boolean row selection: np.where with an (H, W, 1) mask is ~20× slower
    if gb.spp == 1:
        d = resolve(gb, delta)
        m = bg + d
        m[covered] = resolve(gb, mixed)[covered]
        return Layers.assemble(bg, m, d, virt, stats=stats)
    n_v = virt * gb.spp
    n_r = gb.spp - n_v
    d = resolve(gb, delta) * gb.spp
    real = n_r > 0
    d[real] /= n_r[real][:, None]
    d[~real] = 0.0
    m = bg + d
    m[covered] = (resolve(gb, mixed) * gb.spp)[covered] / n_v[covered][:, None]
    return Layers.assemble(bg, m, d, virt, stats=stats)


__all__ = ["GBuffer", "assemble", "facing", "render_gbuffer", "resolve", "resolve_scalar",
           "surface_albedo"]
