"""Synthetic RGB-D sequences with known light, for measuring the probeless estimate.

A modelled "room corner" of real shapes — a floor, boxes of several sizes and orientations,
a sphere — with one uniform diffuse albedo, lit by an environment given either as 16 SH
coefficients (a smooth cap around an animated direction over an ambient term: Gruber's
"animated circular area light falling off from centre to border", projected to SH) or as a
real HDR map (bundled, rotated per frame), or by a *near* lamp (a 25 cm emitting square
0.9 m from the objects, as bunny-box's, over a dim constant ambient: light the distant-light
model of E5 does not describe, used to check that a constant does not break it). Frames are
rendered by Mitsuba's own path tracer through :func:`arlight.synthetic.synthesize` (direct
light only by default, ``max_depth = 2``, as the Lambertian transfer model of E1 assumes);
depth is the camera-space ``z`` of the first hit; poses are the cameras'. The *true* light of
a frame is known: its SH (the cap), the SH projection of the rotated map, or the light
arriving at the objects (the lamp), and the true dominant direction.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from arlight.backend.mitsuba_scene import build_views
from arlight.probeless.directions import N_COEFFS, SH_ORDER, fibonacci_sphere
from arlight.probeless.pipeline import primary_hits
from arlight.probeless.reconstruct import RGBDFrame
from arlight.scene.camera import Camera, look_at
from arlight.scene.model import ARScene, Light, Material, Shape, World
from arlight.sphere import sh as SH
from arlight.synthetic import sensor_depth

ALBEDO = 0.6
LAMP_TARGET = np.array([0.02, 0.065, 0.10])
"""Where the near lamp of ``kind = "lamp"`` is aimed and its true light measured (m): the
centre of :func:`virtual_objects`."""
LAMP_DISTANCE = 0.9
"""Distance of the near lamp from :data:`LAMP_TARGET` (m); bunny-box's is 0.88 m."""


def _box(name: str, size, centre, yaw_deg: float = 0.0, mat: Material | None = None,
         role: str = "real") -> Shape:
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    m = np.eye(4)
    m[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    m[:3, 3] = centre
    return Shape(name, role, "box", {"size": list(map(float, size))}, m,
                 mat or _material(ALBEDO))


def _material(a: float) -> Material:
    return Material(f"grey{a}", "diffuse", {"albedo": [a] * 3, "texture": None,
                                             "two_sided": True})


def room_shapes(albedo: float = ALBEDO) -> list[Shape]:
    """Floor (top at y = 0), five boxes and a sphere: many normals and contact shadows."""
    mat = _material(albedo)
    shapes = [_box("floor", (1.6, 0.02, 1.6), (0, -0.01, 0), mat=mat)]
    for i, (size, centre, yaw) in enumerate([
            ((0.20, 0.12, 0.16), (-0.25, 0.06, -0.10), 20.0),
            ((0.10, 0.22, 0.10), (0.18, 0.11, -0.22), -35.0),
            ((0.30, 0.05, 0.12), (0.05, 0.025, 0.20), 60.0),
            ((0.12, 0.12, 0.12), (0.32, 0.06, 0.12), 10.0),
            ((0.16, 0.08, 0.24), (-0.30, 0.04, 0.28), -15.0)]):
        shapes.append(_box(f"box{i}", size, centre, yaw, mat=mat))
    m = np.eye(4)
    m[:3, 3] = (0.0, 0.09, -0.02)
    shapes.append(Shape("sphere", "real", "sphere", {"radius": 0.09}, m, mat))
    return shapes


def virtual_objects() -> list[Shape]:
    """A virtual Phong sphere and a diffuse box on the floor of the room, in view of the
    camera paths: what the image-quality comparison of the variants inserts."""
    from arlight.probeless.compose import virtual_sphere

    box = _box("vbox", (0.14, 0.14, 0.14), (0.12, 0.07, 0.05), 30.0,
               mat=Material("vbox", "diffuse", {"albedo": [0.7, 0.5, 0.3], "texture": None,
                                                "two_sided": True}), role="virtual")
    return [virtual_sphere(np.array([-0.08, 0.06, 0.15]), 0.06), box]


def cap_light(direction: np.ndarray, power: float = 4.0, ambient: float = 0.25,
              width_deg: float = 40.0) -> np.ndarray:
    """16×3 SH of ``ambient + power · smooth cap around direction`` (cos² fall-off to the
    border at ``width_deg``), warm-tinted, shifted so it is nonnegative everywhere."""
    d0 = np.asarray(direction, np.float64)
    d0 = d0 / np.linalg.norm(d0)
    cw = np.cos(np.radians(width_deg))

    def f(d: np.ndarray) -> np.ndarray:
        c = d @ d0
        x = np.clip((c - cw) / (1 - cw), 0, 1)
        val = ambient + power * x * x
        return np.stack([val * 1.0, val * 0.9, val * 0.8], axis=1)

    sh = SH.project_function(f, SH_ORDER)
    low = float(SH.sh_to_equirect(sh, 64).min())
    if low < 0:
        sh[0] += (-low + 1e-3) / SH.Y00
    return sh


@dataclass
class SyntheticFrame:
    """A rendered frame and its truth: RGB-D + pose and the light's SH / direction."""

    rgbd: RGBDFrame
    true_sh: np.ndarray
    true_direction: np.ndarray


def camera_path(n: int, moving: bool, width: int, height: int, radius: float = 1.05,
                height_m: float = 0.75, fov_deg: float = 50.0) -> list[Camera]:
    """``n`` cameras looking at the scene centre: fixed, or moving along a 60° arc."""
    out = []
    for i in range(n):
        a = np.radians(-30 + 60 * i / max(n - 1, 1)) if moving else 0.0
        eye = np.array([radius * np.sin(a), height_m, radius * np.cos(a)])
        out.append(Camera.from_fov(width, height, fov_deg,
                                   world_from_camera=look_at(eye, (0, 0.05, 0))))
    return out


def light_directions(n: int) -> np.ndarray:
    """The animated light: elevation 50°, azimuth sweeping 120° over the sequence."""
    az = np.radians(20 + 120 * np.arange(n) / max(n - 1, 1))
    el = np.radians(50.0)
    return np.stack([np.cos(el) * np.sin(az), np.full(n, np.sin(el)),
                     np.cos(el) * np.cos(az)], axis=1)


def near_lamp(direction: np.ndarray, distance: float = LAMP_DISTANCE,
              size: float = 0.25, radiance: float = 14.0) -> list[Light]:
    """A square area lamp (``size`` m, ``radiance`` W/(sr·m²), warm) ``distance`` m from
    :data:`LAMP_TARGET` along ``direction``, facing it, and a dim constant ambient (0.04):
    bunny-box's lamp moved around the room."""
    from arlight.scene.load import z_to

    d = np.asarray(direction, np.float64) / np.linalg.norm(direction)
    m = z_to(-d)
    m[:3, 3] = LAMP_TARGET + distance * d
    lamp = Light("lamp", "area", {"size": [size, size], "to_world": m,
                                  "radiance": [radiance, radiance * 0.96, radiance * 0.9]})
    amb = Light("ambient", "constant", {"radiance": [0.04, 0.04, 0.045]})
    return [lamp, amb]


def bundled_hdr() -> Path:
    """The bundled lat-long HDR map used for the "real map" sequences."""
    return Path(str(resources.files("arlight") / "data" / "demo" / "lebombo_512x256.hdr"))


def incident_sh(world: World, point: np.ndarray, emitter_samples: int = 1 << 16,
                directions: int = 8192, spp: int = 16, max_depth: int = 8,
                seed: int = 0) -> np.ndarray:
    """The true 16-coefficient radiance SH ``(16, 3)`` of the light arriving at ``point`` in
    ``world``'s real part (virtual shapes left out: the light of the frame), computed
    independently of any estimate, by Mitsuba:

    * **emitted light seen directly** (environment, sun, area, sphere, point and spot
      lights): ``emitter_samples`` draws of ``Scene.sample_emitter_direction`` from the point
      with visibility tested; each draw's radiance / pdf (for delta lights: the irradiance)
      projected onto ``Y_k`` of its direction, averaged (an unbiased projection);
    * **reflected light**: the ``path`` integrator with ``hide_emitters`` (emitters seen
      directly count 0, every bounce after the first surface counts) from the point along
      ``directions`` spherical-Fibonacci directions, ``spp`` paths each, projected with the
      quadrature weight ``4π/directions``.
    """
    import drjit as dr
    import mitsuba as mi

    from arlight.backend.rays import np3
    from arlight.nearfield.capture import real_scene

    scene = real_scene(world)
    p = np.asarray(point, np.float64).reshape(3)
    out = np.zeros((N_COEFFS, 3))
    # direct: emitter sampling
    if scene.emitters():
        rng = np.random.default_rng(seed)
        n = int(emitter_samples)
        it = dr.zeros(mi.Interaction3f, n)
        it.p = mi.Point3f(*[np.full(n, c, np.float32) for c in p])
        it.t = mi.Float(np.zeros(n, np.float32))
        u = rng.random((n, 2)).astype(np.float32)
        ds, spec = scene.sample_emitter_direction(it, mi.Point2f(u[:, 0], u[:, 1]), True)
        col = np3(spec)
        d = np3(ds.d)
        col[~np.isfinite(col).all(axis=1)] = 0.0
        out += SH.sh_basis(d, SH_ORDER).T @ col / n
    # reflected: path tracing with the directly seen emitters hidden
    d = fibonacci_sphere(int(directions))
    dd = np.repeat(d, int(spp), axis=0)
    m = len(dd)
    integrator = mi.load_dict({"type": "path", "max_depth": int(max_depth),
                               "hide_emitters": True})
    o = np.broadcast_to(p.astype(np.float32), (m, 3))
    ray = mi.Ray3f(mi.Point3f(*[np.ascontiguousarray(o[:, i]) for i in range(3)]),
                   mi.Vector3f(*[np.ascontiguousarray(dd[:, i], np.float32)
                                 for i in range(3)]))
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(int(seed) + 1, m)
    spec, _, _ = integrator.sample(scene, sampler, ray)
    col = np3(spec)
    col[~np.isfinite(col).all(axis=1)] = 0.0
    rad = col.reshape(len(d), int(spp), 3).mean(axis=1)
    out += SH.sh_basis(d, SH_ORDER).T @ rad * (4 * np.pi / len(d))
    return out


def render_sequence(kind: str = "sh", n: int = 8, moving: bool = False, width: int = 160,
                    height: int = 120, spp: int = 32, seed: int = 1,
                    hdr: Path | None = None, max_depth: int = 2,
                    cache_dir: Path | str | None = None) -> list[SyntheticFrame]:
    """Render ``n`` frames of the room under an animated light.

    Args:
        kind: ``"sh"`` (cap light as 16 SH coefficients, an ``sh`` light) or ``"hdr"`` (a real
            HDR map rotated by 45° per frame about +Y, an ``envmap`` light) or ``"lamp"``
            (:func:`near_lamp` along the animated direction; its true SH is the light
            arriving at :data:`LAMP_TARGET`, by
            :func:`incident_sh`, and its true direction the
            lamp's from there).
        moving: camera on an arc (else static).
        max_depth: Mitsuba path depth (2: direct light only, the model of E1).
    """
    from arlight.io.images import read_hdr
    from arlight.synthetic import synthesize

    shapes = room_shapes()
    cams = camera_path(n, moving, width, height)
    frames = []
    env = read_hdr(hdr or bundled_hdr()) if kind == "hdr" else None
    env_sh = SH.project_equirect(env, SH_ORDER) if env is not None else None
    dirs = light_directions(n)
    for i, cam in enumerate(cams):
        if kind == "sh":
            sh = cap_light(dirs[i])
            light = Light("sky", "sh", {"coefficients": sh.tolist(), "scale": 1.0,
                                        "rotation_deg": 0.0, "resolution": 64},
                          radiance_map=np.maximum(SH.sh_to_equirect(sh, 64), 0))
        elif kind == "hdr":
            ang = 45.0 * i
            a = np.radians(ang)
            R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
            sh = SH.rotate(env_sh, R)
            light = Light("sky", "envmap", {"file": str(hdr or bundled_hdr()),
                                            "mapping": "equirect", "scale": 1.0,
                                            "rotation_deg": ang}, radiance_map=env)
        elif kind != "lamp":
            raise ValueError(f"kind must be 'sh', 'hdr' or 'lamp', got {kind!r}")
        lights = near_lamp(dirs[i]) if kind == "lamp" else [light]
        scene = ARScene(camera=cam, shapes=shapes, lights=lights)
        true_dir = dirs[i] if kind == "lamp" else SH.dominant_direction(sh)
        if kind == "lamp":
            sh = incident_sh(scene.world, LAMP_TARGET, emitter_samples=1 << 14,
                             directions=1024, spp=4, max_depth=max_depth, seed=seed + i)
        photo = synthesize(scene, spp=spp, seed=seed + i, max_depth=max_depth,
                           cache_dir=cache_dir, batches=min(8, spp))
        hits = primary_hits(build_views(scene), cam, mixed=False)
        depth = np.where(np.isfinite(hits.z), hits.z, 0).astype(np.float32)
        frames.append(SyntheticFrame(RGBDFrame(photo.frame, depth, cam, f"frame{i}", float(i)),
                                     sh, true_dir))
    return frames


def write_suite_depth(folder: str | Path) -> Path:
    """Write ``depth.exr`` of the suite scene in ``folder`` (full resolution, from its
    world.toml), which its proxy.toml names as ``[frame] depth`` (the RGB-D input of
    ``probeless``), e.g. ``src/arlight/data/scenes/bunny-box``."""
    from arlight.io.images import write_exr
    from arlight.scene.load import load_scene

    folder = Path(folder)
    return write_exr(folder / "depth.exr", sensor_depth(load_scene(folder / "world.toml")))


if __name__ == "__main__":  # python -m arlight.probeless.synthetic_rgbd SCENE_FOLDER
    import sys

    print(write_suite_depth(sys.argv[1]))


__all__ = ["ALBEDO", "LAMP_DISTANCE", "LAMP_TARGET", "SyntheticFrame", "bundled_hdr",
           "camera_path", "cap_light", "incident_sh",
           "light_directions", "near_lamp", "render_sequence", "room_shapes", "virtual_objects",
           "write_suite_depth"]
