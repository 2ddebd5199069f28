"""An AR scene from one RGB-D frame, its reconstruction and a probeless light estimate.

The reconstruction is the real proxy, the frame is the background ``I_c`` (its depth kept),
the estimate becomes the scene's ``sh`` light (what ``[[lights]] type = "sh"`` reads from
``light.json``'s ``sh.coefficients``), and virtual shapes are placed on a real surface picked
by a pixel (:func:`place_on_surface`).
"""

from __future__ import annotations

import numpy as np

from arlight.backend.mitsuba_scene import build_views
from arlight.errors import InputError
from arlight.light.estimate import LightEstimate
from arlight.probeless.reconstruct import RGBDFrame
from arlight.scene.model import ARScene, Light, Material, Shape, World
from arlight.sphere import sh as SH


def sh_light(est: LightEstimate, resolution: int = 64) -> Light:
    """The estimate's SH as a scene ``sh`` light (negative lobes clamped when rendered)."""
    coeffs = est.sh
    return Light("probeless", "sh", {"coefficients": coeffs.tolist(), "scale": 1.0,
                                     "rotation_deg": 0.0, "resolution": resolution},
                 radiance_map=np.maximum(SH.sh_to_equirect(coeffs, resolution), 0))


def place_on_surface(proxy: Shape, frame: RGBDFrame, pixel: tuple[float, float],
                     up: np.ndarray | None = None, search: int = 40,
                     min_cos: float = 0.9) -> tuple[np.ndarray, np.ndarray]:
    """World point and unit normal (towards the camera side) of the reconstruction seen at
    ``pixel`` (u, v); with ``up``, the nearest pixel within ``search`` px whose surface
    faces ``up`` (normal cosine >= ``min_cos``: a table top, a floor) — reconstructions have
    holes where the sensor saw no depth."""
    from arlight.probeless.pipeline import primary_hits

    views = build_views(World(shapes=[proxy], lights=[]))
    hits = primary_hits(views, frame.camera)
    ok = hits.valid
    if up is not None:
        u = np.asarray(up, np.float64) / np.linalg.norm(up)
        ok = ok & (hits.normal @ u >= min_cos)
    v, c = np.mgrid[0:frame.camera.height, 0:frame.camera.width]
    dist = np.hypot(c + 0.5 - pixel[0], v + 0.5 - pixel[1])
    ok &= dist <= search
    if not np.any(ok):
        raise InputError(f"no reconstructed surface{' facing up' if up is not None else ''} "
                         f"within {search} px of pixel {pixel}", field="pixel")
    i = np.unravel_index(np.argmin(np.where(ok, dist, np.inf)), dist.shape)
    return hits.position[i], hits.normal[i] / np.linalg.norm(hits.normal[i])


def virtual_sphere(centre: np.ndarray, radius: float, albedo=(0.8, 0.8, 0.8),
                   ks: float = 0.15, exponent: float = 40.0) -> Shape:
    """A virtual Phong sphere (its highlight comes from the dominant direction, E7)."""
    m = np.eye(4)
    m[:3, 3] = centre
    kd = [float(a) * (1 - ks) for a in albedo]
    mat = Material("virtual-phong", "phong", {"kd": kd, "ks": [ks] * 3,
                                              "exponent": exponent, "two_sided": True})
    return Shape("virtual-sphere", "virtual", "sphere", {"radius": float(radius)}, m, mat)


def ar_scene(frame: RGBDFrame, proxy: Shape, virtual: list[Shape],
             est: LightEstimate) -> ARScene:
    """Camera, frame, depth, reconstruction, virtual shapes and the estimated SH light."""
    return ARScene(camera=frame.camera, shapes=[proxy, *virtual], lights=[sh_light(est)],
                   frame=np.ascontiguousarray(frame.colour, np.float32),
                   depth=np.where(frame.valid_depth, frame.depth, np.nan).astype(np.float32))


__all__ = ["ar_scene", "place_on_surface", "sh_light", "virtual_sphere"]
