"""Peer benchmark: onepass (and reference) against Blender Cycles' shadow catcher at equal
noise (issue #22), on the suite's ``bunny-box`` and on generated held-out worlds (issue #30).

The same AR scene is rendered by arlight and by Blender 5.0 Cycles (``bpy``, CPU, no
denoiser, no adaptive sampling, box pixel filter, no light threshold, the same bounce limit:
Mitsuba's ``max_depth`` − 2 bounces) with the real shapes (and the real lights) as shadow
catchers. Cycles' composite is the one its manual prescribes: the frame times the *Shadow
Catcher* pass, with the *Combined* pass (virtual objects, premultiplied alpha) over it;
arlight's is Debevec's differential composite (Eq. 2.20). Both composite the same synthetic
camera frame (Mitsuba's render of the world).

Scenes: ``bunny-box`` (``--scene``: real diffuse table and open box, virtual diffuse bunny
and box, one rectangular area light, a constant environment) always; with ``--worlds SPEC``
(``heldout:8``, ``training:4``, seeds) also the generated worlds
(:mod:`arlight.evaluate.worlds`): the proxy is what both renderers get.

**Translation** (:func:`export_scene`): from the Mitsuba description arlight renders
(:func:`arlight.backend.mitsuba_scene.describe_views`), so both renderers read the same
numbers. Lights: ``envmap`` → world Environment Texture through a fixed rotation of the
lookup vector (:func:`envmap_axes`, the map's ``rotation_deg`` and ``scale``); ``constant``
→ world colour; ``directional`` → sun of angle 0, strength = irradiance; ``point`` → point
light, power ``4π I`` (:func:`point_watts`); ``spot`` → spot light of the same power, hard
cone at the cutoff and Mitsuba's linear-in-angle profile as the light's node strength
(:func:`spot_falloff`); emitting ``rectangle`` → one-sided area light, ``P = π A L``
(:func:`area_watts`); emitting ``sphere`` → point light of that radius (a sphere light in
Cycles 4+), ``P = 4π² r² L`` (:func:`sphere_watts`). An emitter shape is also a black
occluder in Mitsuba (it shadows other light): a black copy sits just behind the area light
and just inside the sphere light. Materials: ``diffuse`` (RGB or texture, UVs kept) →
Lambertian Diffuse BSDF; ``roughconductor`` (GGX, ``material = none``) → Glossy BSDF GGX,
roughness ``√α``, colour = reflectance; ``conductor`` (mirror) → Glossy roughness 0;
``dielectric`` → Glass BSDF roughness 0, IOR ``int/ext``. Spheres are tessellated (192×96,
exact normals). Camera: focal length from ``fy``, principal point as shift, thin lens →
depth of field with ``N = f / 2r`` (:func:`aperture_fstop`). What Cycles cannot render as
Mitsuba does raises :class:`Untranslatable` and the world is skipped with the reason (the
Kán Phong BSDF: Cycles has no Phong closure).

**Translation check** (``--check-lights`` renders one-light worlds against Mitsuba; every
generated world is checked too): Cycles renders the *world* (the real world and the virtual
objects, no catcher) and the result is compared with the ground-truth photograph (Mitsuba):
``χ = mean(d²) / mean(s²)`` (``d`` the difference, ``s²`` the two images' variances of the
mean; ≈ 1 when they agree) and the bias beyond noise ``sqrt(max(mean d² − mean s², 0)) /
rms(gt)``. A world with ``χ > 2`` and bias > 1 % is reported as *disagrees* and left out of
the distribution.

Measured, in one process with interleaved repeats (the machine is shared): for each
renderer and ``spp`` in ``--spp``, ``--repeats`` independent renders (different seeds) and
their wall times (arlight: the whole method call, scene preparation included; Cycles: its
synchronisation + render time from the EXR metadata). The *noise* of one render is its
relative RMSE about its own expectation, estimated from the repeats without any converged
image: ``sqrt(mean_pixels s²) / rms(c)``, with ``s²`` the per-pixel unbiased variance over the
repeats and ``c`` the mean of the renderer's highest-spp renders (a converged image of finite
spp would add its own noise to every error and flatten the curves near 1 %). A least-squares
line through log noise against log time gives the time to reach 5 %, 2.5 % and 1 %.
Correctness: the mean of each renderer's highest-spp renders against the ground-truth
photograph (Mitsuba, the world with the virtual objects), next to that mean's own noise.
Every measure leaves out the pixels of directly seen lights (:func:`lights_mask`: brighter
than 64× the ground truth's median luminance; generated worlds see lights of radiance up to
10⁶ whose few pixels would otherwise be the whole RMS); on ``bunny-box`` that is no pixel.

bpy runs in its own virtual environment (bpy 5.0 requires numpy < 2; arlight needs numpy 2):

    python3.11 -m venv /tmp/venv-bpy && /tmp/venv-bpy/bin/pip install "bpy==5.0.*" "numpy<2"
    python benchmarks/bench_vs_cycles.py --bpy-python /tmp/venv-bpy/bin/python --write
    python benchmarks/bench_vs_cycles.py --worlds heldout:8 --width 320 --frame-spp 256 --write
    python benchmarks/bench_vs_cycles.py --check-lights     # the translation, light by light
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from results import cpu_pressure, publish

HEADING = "## Peer benchmark: onepass vs Blender Cycles at equal noise (issue 22)"
WORLDS_HEADING = ("## Held-out worlds: onepass vs Blender Cycles at equal noise, lights chosen "
                  "by importance (issue #35)")
"""The section of ``--worlds`` runs (the issue #30 section, measured before light selection
by importance and the per-render recompilation fix, is kept in RESULTS.md as the before)."""
HERE = Path(__file__).resolve().parent
TARGETS = (0.05, 0.025, 0.01)
ARLIGHT = {  # label -> (method, options)
    "onepass": ("onepass", {"reproject": False}),
    "onepass scrambles": ("onepass", {"reproject": False, "replica_mode": "scrambles"}),
    "onepass power": ("onepass", {"reproject": False, "light_sampling": "solid_angle"}),
    "onepass before #22": ("onepass", {"reproject": False, "sampler": "independent",
                                       "replicas": 1, "light_sampling": "mitsuba"}),
    "reference": ("reference", {}),
}
CHI_MAX, BIAS_MAX = 2.0, 0.01
"""A Cycles render of the world disagrees with Mitsuba's when both are exceeded."""
PHONG_REASON = "Kán Phong BSDF (Cycles has no Phong closure)"

# --------------------------------------------------------------------------------------------
# Translating an AR scene for Cycles (pure functions: tested without bpy)
# --------------------------------------------------------------------------------------------

class Untranslatable(Exception):
    """A scene holds something Cycles cannot render as Mitsuba does (the reason)."""


def point_watts(intensity) -> float:
    """Blender's power (W) of a point or spot light of radiant intensity ``intensity``
    (W/sr, its largest channel): Cycles' point light radiates ``P / 4π`` per steradian (a
    sphere of radius r has radiance ``P / (4π² r²)``, i.e. intensity ``P / 4π``; a spot is a
    masked point light of the same power)."""
    return float(4.0 * np.pi * np.max(intensity))


def sphere_watts(radiance, radius: float) -> float:
    """Blender's power (W) of a point light of ``radius`` (a sphere light in Cycles 4+)
    whose surface has ``radiance``: ``4π² r² L`` (= ``4π I`` with ``I = π r² L``)."""
    return float(4.0 * np.pi**2 * radius**2 * np.max(radiance))


def area_watts(radiance, area: float) -> float:
    """Blender's power (W) of a one-sided area light of ``area`` (m²) and ``radiance``:
    Cycles' area light has radiance ``P / (π A)``."""
    return float(np.pi * area * np.max(radiance))


def light_colour(rgb) -> list[float]:
    """The colour of a Blender light whose power carries the largest channel."""
    rgb = np.asarray(rgb, np.float64)
    m = float(rgb.max())
    return [float(c) / m for c in rgb] if m > 0 else [0.0, 0.0, 0.0]


def glossy_roughness(alpha: float) -> float:
    """Cycles' roughness of a GGX lobe of Mitsuba's ``alpha`` (Cycles squares it)."""
    return float(np.sqrt(alpha))


def lens_mm(fy: float, height: int, sensor_mm: float = 24.0) -> float:
    """Focal length (mm) of a Blender camera with a vertical sensor of ``sensor_mm`` whose
    focal length in pixels is ``fy``."""
    return float(fy) * sensor_mm / height


def aperture_fstop(lens: float, radius: float) -> float:
    """Blender's f-number giving a thin-lens aperture of ``radius`` (m): Cycles' aperture
    radius is ``lens[m] / (2 N)``."""
    return float(lens * 1e-3 / (2.0 * radius))


def spot_falloff(cos_theta, cutoff_deg: float, beam_deg: float):
    """Mitsuba's spot profile: 1 inside the beam width, linear in angle down to 0 at the
    cutoff (what the worker's light node computes; Cycles' own blend is a smoothstep in
    cosine, so the spot's blend is 0 and this profile is the light's strength)."""
    th = np.degrees(np.arccos(np.clip(cos_theta, -1.0, 1.0)))
    return np.clip((cutoff_deg - th) / (cutoff_deg - beam_deg), 0.0, 1.0) * (th < cutoff_deg)


def envmap_axes() -> np.ndarray:
    """Rotation taking a direction in Mitsuba's envmap frame (y up, u = atan2(x, −z)/2π,
    v = acos(y)/π from the top row) to the vector of Blender's equirectangular lookup
    (z up, u = 1/2 − atan2(y, x)/2π, v = 1/2 + asin(z)/π from the bottom row): x' = z,
    y' = x, z' = y, so both look up the same pixel."""
    return np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def blender_equirect_uv(d) -> tuple[float, float]:
    """Blender's equirectangular (u, v) of a direction (its ``direction_to_equirectangular``)."""
    x, y, z = np.asarray(d, np.float64) / np.linalg.norm(d)
    return float(0.5 - np.arctan2(y, x) / (2 * np.pi)), float(0.5 + np.arcsin(z) / np.pi)


def mitsuba_equirect_uv(d) -> tuple[float, float]:
    """Mitsuba's envmap (u, v) of a direction in its frame (v measured from the top row)."""
    x, y, z = np.asarray(d, np.float64) / np.linalg.norm(d)
    return float((np.arctan2(x, -z) / (2 * np.pi)) % 1.0), float(np.arccos(y) / np.pi)


def rotation_y(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])


def uv_sphere(n_lon: int = 192, n_lat: int = 96) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, faces) of the unit sphere, poles on ±y (vertices are their own normals)."""
    th = np.linspace(0.0, np.pi, n_lat + 1)
    ph = np.linspace(0.0, 2 * np.pi, n_lon, endpoint=False)
    t, p = np.meshgrid(th[1:-1], ph, indexing="ij")
    ring = np.stack([np.sin(t) * np.cos(p), np.cos(t), np.sin(t) * np.sin(p)], -1).reshape(-1, 3)
    v = np.concatenate([[[0.0, 1.0, 0.0]], ring, [[0.0, -1.0, 0.0]]])
    faces = []
    idx = lambda i, j: 1 + i * n_lon + j % n_lon  # noqa: E731
    for j in range(n_lon):
        faces.append((0, idx(0, j + 1), idx(0, j)))
        faces.append((len(v) - 1, idx(n_lat - 2, j), idx(n_lat - 2, j + 1)))
    for i in range(n_lat - 2):
        for j in range(n_lon):
            a, b, c, d = idx(i, j), idx(i, j + 1), idx(i + 1, j + 1), idx(i + 1, j)
            faces += [(a, b, c), (a, c, d)]
    return v, np.array(faces, np.int64)


def _rgb(node) -> list[float]:
    if node.get("type") != "rgb":
        raise Untranslatable(f"a {node.get('type')} texture where a colour was expected")
    return [float(x) for x in node["value"]]


def translate_material(bsdf: dict, images: dict[str, np.ndarray]) -> dict:
    """A Mitsuba BSDF node as the worker's material (see the module docstring)."""
    from arlight.backend.mitsuba_scene import phong_plugin_name

    node = bsdf["bsdf"] if bsdf["type"] == "twosided" else bsdf
    t = node["type"]
    if t == "diffuse":
        refl = node["reflectance"]
        if refl["type"] == "bitmap":
            key = f"img{len(images)}"
            images[key] = np.asarray(refl["bitmap"], np.float32)
            return {"type": "diffuse", "texture": key}
        return {"type": "diffuse", "color": _rgb(refl)}
    if t in ("roughconductor", "conductor"):
        if node.get("material", "none") != "none":
            raise Untranslatable(f"conductor of material {node['material']!r}")
        if t == "roughconductor" and node.get("distribution", "beckmann") != "ggx":
            raise Untranslatable(f"{node.get('distribution')} microfacets")
        alpha = float(node["alpha"]) if t == "roughconductor" else 0.0
        return {"type": "glossy", "color": _rgb(node["specular_reflectance"]),
                "roughness": glossy_roughness(alpha)}
    if t == "dielectric":
        return {"type": "glass", "ior": float(node["int_ior"]) / float(node["ext_ior"])}
    if t == phong_plugin_name():
        raise Untranslatable(PHONG_REASON)
    raise Untranslatable(f"{t} BSDF")


BLACK = {"type": "diffuse", "color": [0.0, 0.0, 0.0]}


def _affine(m: np.ndarray, p: np.ndarray) -> np.ndarray:
    return p @ m[:3, :3].T + m[:3, 3]


def _normals(m: np.ndarray, n: np.ndarray) -> np.ndarray:
    n = n @ np.linalg.inv(m[:3, :3])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def _look_at(node: dict) -> tuple[np.ndarray, np.ndarray]:
    la = node["to_world"]["look_at"]
    o, t = np.asarray(la["origin"], float), np.asarray(la["target"], float)
    return o, (t - o) / np.linalg.norm(t - o)


def export_scene(scene, path: Path, max_depth: int, catcher: bool) -> None:
    """The scene as the worker builds it (``.npz``: a JSON ``manifest`` and the arrays it
    names). ``catcher``: real shapes and lights are shadow catchers and the film is
    transparent (the AR render); else everything is an ordinary object (the world check).

    Raises:
        Untranslatable: for what Cycles cannot render as Mitsuba does.
    """
    import mitsuba as mi

    from arlight.backend.mitsuba_scene import describe_views, virtual_names
    from arlight.jit import ensure_variant

    ensure_variant()
    objs = describe_views(scene)["mixed"]["objects"]
    virtual = virtual_names(scene)
    arrays: dict[str, np.ndarray] = {}
    images: dict[str, np.ndarray] = {}
    shapes: list[dict] = []
    lights: list[dict] = []
    world: dict = {"type": "none"}

    def add(v, f, n, uv, material, real, smooth):
        i = len(shapes)
        arrays[f"v{i}"], arrays[f"f{i}"] = np.asarray(v, np.float64), np.asarray(f, np.int64)
        if n is not None:
            arrays[f"n{i}"] = np.asarray(n, np.float64)
        if uv is not None:
            arrays[f"uv{i}"] = np.asarray(uv, np.float64)
        shapes.append({"material": material, "real": bool(real), "smooth": bool(smooth),
                       "normals": n is not None, "uv": uv is not None})

    def sphere(m, material, real):
        v, f = uv_sphere()
        add(_affine(m, v), f, _normals(m, v), None, material, real, True)

    rect = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
    for name, node in objs.items():
        t, emitter = node["type"], node.get("emitter")
        real = name not in virtual
        if t in ("constant", "envmap"):
            if world["type"] != "none":
                raise Untranslatable("two environment emitters")
            if t == "constant":
                world = {"type": "constant", "color": _rgb(node["radiance"])}
            else:
                rot = node.get("to_world", {}).get("rotate", {"axis": [0, 1, 0], "angle": 0.0})
                if list(map(float, rot["axis"])) != [0.0, 1.0, 0.0]:
                    raise Untranslatable("an environment map rotated about another axis than y")
                images["env"] = np.asarray(node["bitmap"], np.float32)
                m = envmap_axes() @ rotation_y(float(rot["angle"])).T
                world = {"type": "envmap", "image": "env", "scale": float(node["scale"]),
                         "matrix": m.tolist()}
        elif t == "point":
            i = _rgb(node["intensity"])
            lights.append({"type": "POINT", "position": list(map(float, node["position"])),
                           "radius": 0.0, "energy": point_watts(i), "color": light_colour(i)})
        elif t == "spot":
            i = _rgb(node["intensity"])
            o, d = _look_at(node)
            lights.append({"type": "SPOT", "position": o.tolist(), "direction": d.tolist(),
                           "energy": point_watts(i), "color": light_colour(i),
                           "cutoff_deg": float(node["cutoff_angle"]),
                           "beam_deg": float(node["beam_width"])})
        elif t == "directional":
            e = _rgb(node["irradiance"])
            d = np.asarray(node["direction"], float)
            lights.append({"type": "SUN", "direction": (d / np.linalg.norm(d)).tolist(),
                           "energy": float(max(e)), "color": light_colour(e)})
        elif emitter is not None:
            if emitter["type"] != "area":
                raise Untranslatable(f"a {emitter['type']} emitter on a shape")
            rad = _rgb(emitter["radiance"])
            if t == "rectangle":
                m = np.asarray(node["to_world"], np.float64)
                ex, ey = 2 * m[:3, 0], 2 * m[:3, 1]
                nrm = np.linalg.inv(m[:3, :3]).T @ [0.0, 0.0, 1.0]
                nrm /= np.linalg.norm(nrm)
                sx, sy = float(np.linalg.norm(ex)), float(np.linalg.norm(ey))
                lights.append({"type": "AREA", "position": m[:3, 3].tolist(),
                               "x": (ex / sx).tolist(), "normal": nrm.tolist(),
                               "size": [sx, sy], "energy": area_watts(rad, sx * sy),
                               "color": light_colour(rad)})
                behind = 1e-4 * max(sx, sy) * nrm  # the black back: just behind the light
                add(_affine(m, rect) - behind, [[0, 1, 2], [0, 2, 3]], None, None, BLACK,
                    True, False)
            elif t == "sphere":
                r, c = float(node["radius"]), np.asarray(node["center"], float)
                lights.append({"type": "POINT", "position": c.tolist(), "radius": r,
                               "energy": sphere_watts(rad, r), "color": light_colour(rad)})
                m = np.eye(4)
                m[:3, :3] *= r * (1 - 1e-3)  # the black body: just inside the light
                m[:3, 3] = c
                sphere(m, BLACK, True)
            else:
                raise Untranslatable(f"an emitting {t}")
        else:
            mat = translate_material(node["bsdf"], images)
            if t == "mesh":
                add(node["vertices"], node["faces"], node.get("normals"), node.get("uv"),
                    mat, real, node.get("normals") is not None)
            elif t == "rectangle":
                m = np.asarray(node["to_world"], np.float64)
                add(_affine(m, rect), [[0, 1, 2], [0, 2, 3]], None, (rect[:, :2] + 1) / 2,
                    mat, real, False)
            elif t == "cube":
                sh = mi.load_dict({"type": "cube", "to_world": mi.ScalarTransform4f(
                    np.asarray(node["to_world"], np.float64))})
                p = mi.traverse(sh)
                add(np.array(p["vertex_positions"]).reshape(-1, 3),
                    np.array(p["faces"]).reshape(-1, 3), None,
                    np.array(p["vertex_texcoords"]).reshape(-1, 2), mat, real, False)
            elif t == "sphere":
                if "texture" in mat:
                    raise Untranslatable("a textured sphere (UVs of the tessellation)")
                sphere(np.asarray(node["to_world"], np.float64), mat, real)
            else:
                raise Untranslatable(f"shape type {t}")
    cam = scene.camera
    camera = {"width": int(cam.width), "height": int(cam.height), "fx": float(cam.fx),
              "fy": float(cam.fy), "cx": float(cam.cx), "cy": float(cam.cy),
              "world_from_camera": np.asarray(cam.world_from_camera, float).tolist(),
              "aperture_radius": float(cam.aperture_radius),
              "focus_distance": float(cam.focus_distance or 0.0)}
    if abs(cam.fx - cam.fy) > 1e-6 * cam.fy:
        raise Untranslatable("non-square pixels")
    if cam.aperture_radius > 0 and cam.aperture_shape != "disk":
        raise Untranslatable(f"a {cam.aperture_shape} aperture")
    manifest = {"catcher": catcher, "bounces": max(max_depth - 2, 0), "camera": camera,
                "world": world, "lights": lights, "shapes": shapes}
    np.savez(path, manifest=np.array(json.dumps(manifest)), **arrays, **images)


# --------------------------------------------------------------------------------------------
# The Blender worker
# --------------------------------------------------------------------------------------------

class Cycles:
    """The Blender worker process (``cycles_worker.py``) and its composites (``frame`` given:
    the AR composite of a catcher scene; None: the plain render of a world scene)."""

    def __init__(self, python: str, scene_npz: Path, frame: np.ndarray | None, tmp: Path,
                 clock: str = "cycles"):
        """``clock``: the seconds :meth:`render` returns — ``"cycles"`` (Cycles' own
        synchronisation + render time) or ``"wall"`` (the whole render call, its denoising
        included)."""
        self.frame = None if frame is None else frame.astype(np.float64)
        self.clock = clock
        self.tmp, self.count, self.syncs = tmp, 0, []
        self.log = tmp / f"{Path(scene_npz).stem}.log"
        with open(self.log, "w") as log:
            self.proc = subprocess.Popen([python, str(HERE / "cycles_worker.py"),
                                          str(scene_npz)], stdin=subprocess.PIPE,
                                         stdout=subprocess.PIPE, stderr=log, text=True)

    def render(self, spp: int, seed: int, denoise: bool = False) -> tuple[np.ndarray, float]:
        """(composite or render, seconds) of one render (``denoise``: Cycles' OIDN)."""

        self.count += 1
        out = self.tmp / f"cycles_{os.getpid()}_{id(self)}_{self.count}"
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(json.dumps({"spp": spp, "seed": seed, "out": str(out),
                                          "denoise": denoise}) + "\n")
        self.proc.stdin.flush()
        while True:  # Blender prints its own lines on stdout too
            line = self.proc.stdout.readline()
            if not line:
                tail = self.log.read_text(errors="replace")[-2000:]
                raise RuntimeError(f"the Blender worker died:\n{tail}")
            if line.startswith("{"):
                break
        reply = json.loads(line)
        if not reply["ok"]:
            raise RuntimeError(reply["error"])
        self.syncs.append(reply.get("sync"))
        with np.load(f"{out}.npz") as z:
            comb = z["combined"].astype(np.float64)
            catcher = z["catcher"].astype(np.float64) if "catcher" in z else None
        os.unlink(f"{out}.npz")
        sec = float(reply["wall" if self.clock == "wall" else "seconds"])
        if self.frame is None:
            return comb[..., :3], sec
        alpha = comb[..., 3:4]
        return comb[..., :3] + (1.0 - alpha) * self.frame * catcher, sec

    def close(self) -> None:
        if self.proc.stdin is not None:
            self.proc.stdin.close()
        try:  # Blender's shutdown is slow on a saturated machine
            self.proc.wait(timeout=600)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


# --------------------------------------------------------------------------------------------
# Measures
# --------------------------------------------------------------------------------------------

BRIGHT = 64.0
"""Pixels whose ground truth is brighter than this many times the image's median luminance
are directly seen lights (or their mirror images): left out of every measure."""


def lights_mask(gt: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels every measure uses (not a directly seen light, see
    :data:`BRIGHT`). A light of radiance 10⁶ in a few pixels would otherwise be the whole
    RMS: the relative noise would be tiny at 1 spp, and the independent noise of frame and
    ground truth on its edges would be the whole error against the ground truth."""
    lum = gt.astype(np.float64) @ np.array([0.2126, 0.7152, 0.0722])
    return lum <= BRIGHT * max(float(np.median(lum)), 1e-12)


def rel_rmse(x: np.ndarray, ref: np.ndarray, keep: np.ndarray | None = None) -> float:
    if keep is not None:
        x, ref = x[keep], ref[keep]
    return float(np.sqrt(np.mean(np.square(x - ref)) / np.mean(np.square(ref))))


def rel_noise(images: list[np.ndarray], norm: float, keep: np.ndarray | None = None) -> float:
    """Relative RMSE of one render about its expectation from independent renders (≥ 2)."""
    var = np.var(np.stack(images), axis=0, ddof=1)
    return float(np.sqrt(np.mean(var if keep is None else var[keep])) / norm)


def time_to(errs: list[tuple[float, float]], target: float) -> float:
    """Time at which the log–log line through (seconds, error) reaches ``target``."""
    t, e = np.log([p[0] for p in errs]), np.log([p[1] for p in errs])
    b, a = np.polyfit(t, e, 1)
    return float(np.exp((np.log(target) - a) / b))


def agreement(images: list[np.ndarray], gt: np.ndarray, gt_stderr: np.ndarray,
              keep: np.ndarray | None = None) -> dict:
    """How the mean of independent renders agrees with a ground truth of known standard
    error: ``chi`` = mean squared difference over mean expected squared difference (≈ 1 when
    they agree), ``bias`` = the relative RMSE beyond the noise, ``rel`` = the plain relative
    RMSE, ``ratio`` = mean of the renders / mean of the ground truth (per channel),
    ``median_ratio`` = median over pixels of their ratio (blind to rare bright outliers)."""
    x = np.stack(images).astype(np.float64)
    if keep is not None:
        x, gt, gt_stderr = x[:, keep], gt[keep], gt_stderr[keep]
    m = x.mean(axis=0)
    var_mean = np.var(x, axis=0, ddof=1) / len(images)
    d2 = np.mean(np.square(m - gt))
    s2 = np.mean(var_mean + np.square(gt_stderr.astype(np.float64)))
    norm = np.mean(np.square(gt))
    return {"chi": float(d2 / s2), "bias": float(np.sqrt(max(d2 - s2, 0.0) / norm)),
            "rel": float(np.sqrt(d2 / norm)),
            "median_ratio": float(np.nanmedian(m / np.where(gt > 0, gt, np.nan))),
            "ratio": (m.reshape(-1, 3).mean(0) / gt.reshape(-1, 3).mean(0)).tolist()}


def disagrees(check: dict) -> bool:
    return check["chi"] > CHI_MAX and check["bias"] > BIAS_MAX


def quantiles(xs: list[float]) -> tuple[float, float, float]:
    """(median, 10th percentile, worst = smallest) of Cycles/onepass time ratios."""
    return float(np.median(xs)), float(np.percentile(xs, 10)), float(min(xs))


# --------------------------------------------------------------------------------------------
# One scene
# --------------------------------------------------------------------------------------------

def export_or_skip(name: str, exports: list[tuple], max_depth: int) -> str | None:
    """Export each ``(scene, path, catcher)`` for Cycles; the reason (also printed) when a
    scene cannot be translated, else None."""
    try:
        for scene, path, catcher in exports:
            export_scene(scene, path, max_depth, catcher=catcher)
    except Untranslatable as exc:
        print(name, "skipped:", exc, flush=True)
        return str(exc)
    return None


def measure(name: str, world, proxy, photo, args, labels: list[str], tmp: Path) -> dict:
    """Translate, check and time one scene; a dict of what was found (``skip`` when the
    scene cannot be translated)."""
    from arlight.methods import RenderSettings, get_method

    scene = proxy.with_frame(photo.frame)
    res: dict = {"name": name}
    skip = export_or_skip(name, [(scene, tmp / f"{name}_ar.npz", True),
                                 (world, tmp / f"{name}_world.npz", False)], args.max_depth)
    if skip:
        return {**res, "skip": skip}
    gt = photo.ground_truth.astype(np.float64)
    wc = Cycles(args.bpy_python, tmp / f"{name}_world.npz", None, tmp)
    try:
        imgs = [wc.render(args.check_spp, 5000 + k)[0] for k in range(2)]
    finally:
        wc.close()
    keep = lights_mask(gt)
    res["lights_px"] = float(1.0 - keep.mean())
    res["check"] = agreement(imgs, gt, photo.ground_truth_stderr, keep)
    print(name, "world check", json.dumps(res["check"]), flush=True)

    def arlight(label: str, spp: int, seed: int) -> tuple[np.ndarray, float]:
        method, opts = ARLIGHT[label]
        lay = get_method(method)(scene, RenderSettings(spp=spp, seed=seed,
                                                       max_depth=args.max_depth,
                                                       options=dict(opts)))
        return lay.composite.astype(np.float64), lay.stats["seconds"]

    cyc = Cycles(args.bpy_python, tmp / f"{name}_ar.npz", photo.frame, tmp)
    try:
        renderers = {label: (lambda s, seed, lb=label: arlight(lb, s, seed)) for label in labels}
        renderers["cycles"] = cyc.render
        for r in renderers.values():  # warm-up: kernels compiled, Blender scene synced
            r(4, 7)
        runs: dict[str, dict[int, list]] = {k: {s: [] for s in args.spp} for k in renderers}
        for rep in range(args.repeats):
            for spp in args.spp:
                for label, r in renderers.items():
                    img, sec = r(spp, 1000 + rep)
                    runs[label][spp].append((img, sec))
                    print(name, label, spp, rep, f"{sec:.2f} s", flush=True)
    finally:
        cyc.close()
    syncs = [x for x in cyc.syncs[1:] if x is not None]  # after the warm-up
    res["cycles_sync"] = float(np.mean(syncs)) if syncs else float("nan")
    top = max(args.spp)
    pts, best, nan = {}, {}, {}
    for k, per_spp in runs.items():
        nan[k] = int(sum(np.count_nonzero(~np.isfinite(img)) for v in per_spp.values()
                         for img, _ in v))
        best[k] = np.mean([img for img, _ in per_spp[top]], axis=0)
        norm = float(np.sqrt(np.mean(np.square(best[k][keep]))))
        pts[k] = [(float(np.mean([sec for _, sec in v])),
                   rel_noise([img for img, _ in v], norm, keep)) for v in per_spp.values()]
    res.update(
        pts=pts, nan=nan,
        t_to={k: {t: time_to(v, t) for t in TARGETS} for k, v in pts.items()},
        slope={k: float(np.polyfit(np.log(args.spp), np.log([e for _, e in v]), 1)[0])
               for k, v in pts.items()},
        vs_gt={k: rel_rmse(best[k], gt, keep) for k in runs},
        own={k: pts[k][-1][1] / np.sqrt(args.repeats) for k in runs})
    return res


# --------------------------------------------------------------------------------------------
# One-light worlds: the translation against Mitsuba, light by light
# --------------------------------------------------------------------------------------------

def one_light_worlds(width: int = 160) -> dict[str, dict]:
    """Small worlds of one light each (and the materials, texture and lens), as scene
    dictionaries: what ``--check-lights`` renders in both renderers."""
    from arlight.evaluate.worlds import HDR_MAPS, data_root, texture_path

    h = round(width * 3 / 4)
    down = {"resolution": [width, h], "fov_y_deg": 50.0,
            "look_at": {"origin": [0.0, 2.0, 3.0], "target": [0.0, 0.0, 0.0],
                        "up": [0.0, 1.0, 0.0]}}
    level = {**down, "look_at": {"origin": [0.0, 0.45, 3.0], "target": [0.0, 0.35, 0.0],
                                 "up": [0.0, 1.0, 0.0]}}
    grey = {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}
    mats = {"ground": grey, "box": {"type": "diffuse", "albedo": [0.7, 0.3, 0.2]},
            "tex": {"type": "diffuse", "texture": str(texture_path("tiles"))},
            "mirror": {"type": "mirror", "reflectance": [0.9, 0.8, 0.7]},
            "rough": {"type": "roughconductor", "alpha": 0.15, "reflectance": [0.9, 0.5, 0.3]},
            "glass": {"type": "glass", "ior": 1.5}}
    ground = {"name": "ground", "role": "real", "type": "rectangle", "size": [6.0, 6.0],
              "normal": [0.0, 1.0, 0.0], "material": "ground"}
    box = {"name": "box", "role": "real", "type": "box", "size": [0.4, 0.3, 0.4],
           "transform": {"rotate": [0.0, 1.0, 0.0, 30.0], "translate": [-0.4, 0.15, -0.2]},
           "material": "box"}

    def sph(name, mat, x, r=0.2):
        return {"name": name, "role": "real", "type": "sphere", "radius": r,
                "transform": {"translate": [x, r, 0.3]}, "material": mat}

    def world(lights, shapes=(ground, box), camera=down):
        return {"format": "arlight-scene/1", "camera": camera, "materials": mats,
                "shapes": list(shapes), "lights": lights}

    env = str(data_root() / HDR_MAPS[2])
    tex_ground = {**ground, "material": "tex", "size": [2.0, 2.0]}
    return {
        "point": world([{"type": "point", "position": [0.3, 1.5, 0.2],
                         "intensity": [3.0, 2.0, 1.0]}]),
        "spot": world([{"type": "spot", "position": [0.2, 1.6, 0.4], "target": [0, 0, 0],
                        "intensity": [5.0, 4.0, 3.0], "cutoff_deg": 40.0,
                        "beam_width_deg": 25.0}]),
        "sun": world([{"type": "directional", "direction": [-0.3, -1.0, -0.2],
                       "irradiance": [2.0, 1.5, 1.0]}]),
        "area": world([{"type": "area", "size": [0.5, 0.3], "normal": [0.2, -1.0, 0.1],
                        "transform": {"translate": [0.2, 1.2, 0.0]},
                        "radiance": [4.0, 3.0, 2.0]}]),
        "sphere": world([{"type": "sphere", "position": [0.5, 0.6, 0.5], "radius": 0.15,
                          "intensity": [2.0, 2.0, 1.5]}]),
        "constant": world([{"type": "constant", "radiance": [0.5, 0.6, 0.7]}]),
        "envmap": world([{"type": "envmap", "file": env, "scale": 1.7,
                          "rotation_deg": 73.0}],
                        [tex_ground, sph("m", "mirror", -0.45), sph("r", "rough", 0.0),
                         sph("g", "glass", 0.45)], level),
        "lens": world([{"type": "point", "position": [0.3, 1.5, 0.9],
                        "intensity": [3.0, 3.0, 3.0]}],
                      [tex_ground, box],
                      {**down, "aperture_radius": 0.06, "focus_distance": 2.5}),
    }


def point_light_analytic(scene, position, intensity, albedo: float) -> np.ndarray:
    """Radiance of the ground plane ``y = 0`` (Lambertian ``albedo``) under a point light,
    through each pixel centre, unshadowed: ``albedo I cos θ / (π d²)`` (0 off the plane)."""
    cam = scene.camera
    h, w = cam.height, cam.width
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    d = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u)], -1)
    m = np.asarray(cam.world_from_camera, float)
    d = d @ m[:3, :3].T
    o = m[:3, 3]
    t = -o[1] / d[..., 1]
    p = o + t[..., None] * d
    to_l = np.asarray(position, float) - p
    dist2 = np.sum(to_l**2, -1)
    cos = np.clip(to_l[..., 1] / np.sqrt(dist2), 0, None)
    e = albedo * cos / (np.pi * dist2)
    out = e[..., None] * np.asarray(intensity, float)
    return np.where((t > 0)[..., None] & (np.abs(p[..., 0]) < 3)[..., None]
                    & (np.abs(p[..., 2]) < 3)[..., None], out, 0.0)


def check_lights(args) -> None:
    from arlight.scene.load import parse_scene
    from arlight.synthetic import synthesize

    rows = ["| world | Cycles / Mitsuba mean (R, G, B) | median pixel ratio | χ | bias beyond "
            "noise | rel. RMSE |", "|---|---|---|---|---|---|"]
    with tempfile.TemporaryDirectory() as tmp_dir:
        tmp = Path(tmp_dir)
        for name, data in one_light_worlds(args.width).items():
            scene = parse_scene(data, ".", file=f"<{name}>")
            photo = synthesize(scene, spp=args.frame_spp, seed=1, max_depth=args.max_depth,
                               use_cache=False)
            export_scene(scene, tmp / f"{name}.npz", args.max_depth, catcher=False)
            cyc = Cycles(args.bpy_python, tmp / f"{name}.npz", None, tmp)
            try:
                imgs = [cyc.render(args.check_spp, 11 + k)[0] for k in range(2)]
            finally:
                cyc.close()
            a = agreement(imgs, photo.frame, photo.frame_stderr)
            ratio = ", ".join(f"{x:.4f}" for x in a["ratio"])
            rows.append(f"| {name} | {ratio} | {a['median_ratio']:.4f} | {a['chi']:.2f} | "
                        f"{100 * a['bias']:.2f} % | "
                        f"{100 * a['rel']:.2f} % |")
            print(rows[-1], flush=True)
            if args.check_dir:
                Path(args.check_dir).mkdir(parents=True, exist_ok=True)
                np.savez_compressed(Path(args.check_dir) / f"{name}.npz", mitsuba=photo.frame,
                                    cycles=np.mean(imgs, 0))
            if name == "point":
                lt = data["lights"][0]
                an = point_light_analytic(scene, lt["position"], lt["intensity"], 0.5)
                # the box shadows part of the plane and reflects onto it: where Mitsuba agrees
                sel = (an > 0) & (np.abs(photo.frame - an) < 0.1 * an + 5 * photo.frame_stderr)
                rows.append(f"| point, analytic (unshadowed plane, {sel.mean():.0%} of the "
                            f"pixels) | Mitsuba / analytic "
                            f"{photo.frame[sel].sum() / an[sel].sum():.4f}, Cycles / "
                            f"analytic {np.mean(imgs, 0)[sel].sum() / an[sel].sum():.4f}"
                            " | | | | |")
                print(rows[-1], flush=True)
    print("\n".join(rows))


# --------------------------------------------------------------------------------------------
# Reports
# --------------------------------------------------------------------------------------------

def _fmt_check(res: dict) -> str:
    c = res["check"]
    flag = " **disagrees**" if disagrees(c) else ""
    noise = c["rel"] / np.sqrt(c["chi"])  # the expected relative difference
    return (f"{c['chi']:.2f} / {100 * c['bias']:.2f} % / {100 * noise:.2g} %{flag} "
            f"({100 * res['lights_px']:.1f} % px lights)")


def scene_table(res: dict, labels: list[str], args) -> list[str]:
    """Today's table for one scene (the issue-22 layout)."""
    t_to, pts = res["t_to"], res["pts"]
    lines = ["| renderer | time to 5 % (s) | to 2.5 % | to 1 % | Cycles time / its time at "
             "2.5 % | at 1 % | noise slope vs spp | mean of top-spp renders vs ground truth "
             "(rel. RMSE / its noise) |",
             "|---|---|---|---|---|---|---|---|"]
    for k in [*labels, "cycles"]:
        tt = t_to[k]
        lines.append(f"| {k} | {tt[0.05]:.3g} | {tt[0.025]:.3g} | {tt[0.01]:.3g} | "
                     f"{t_to['cycles'][0.025] / tt[0.025]:.2f} | "
                     f"{t_to['cycles'][0.01] / tt[0.01]:.2f} | {res['slope'][k]:.3f} | "
                     f"{res['vs_gt'][k]:.4f} / {res['own'][k]:.4f} |")
    lines += ["", "Points (mean seconds, noise) per spp " + str(args.spp) + ":", ""]
    for k, v in pts.items():
        lines.append(f"* {k}: " + ", ".join(f"({s:.2f}, {e:.4f})" for s, e in v))
    return lines


def worlds_report(results: list[dict], descriptions: dict[str, str], labels: list[str],
                  args, size, pressure) -> str:
    ref = "reference" if "reference" in labels else None
    lines = [WORLDS_HEADING, "",
             f"`python benchmarks/bench_vs_cycles.py --worlds {args.worlds} --width {size[0]} "
             f"--spp {' '.join(map(str, args.spp))} --repeats {args.repeats} --frame-spp "
             f"{args.frame_spp} --check-spp {args.check_spp} --only {' '.join(labels)}` — "
             f"`{args.scene}` and the generated worlds `{args.worlds}` (generator "
             f"v{args.generator_version}; seeds ≥ 1 000 000 are held out, nothing was tuned on "
             f"them) at {size[0]}×{size[1]}, max_depth {args.max_depth} (Cycles: "
             f"{args.max_depth - 2} bounces, no denoiser, no adaptive sampling, box filter, "
             "light threshold 0, shadow catcher), "
             f"{args.repeats} interleaved repeats per spp, frame and ground truth "
             f"{args.frame_spp} spp (Mitsuba, the shared cache). CPU pressure (avg60, 2 "
             f"cores shared with other work) before/after: {pressure[0] or 'n/a'} / "
             f"{pressure[1] or 'n/a'} %.", "",
             "Columns: *world check* — Cycles' render of the world (real world and virtual "
             "objects, no catcher) against Mitsuba's ground-truth photograph, "
             f"{args.check_spp} spp ×2: χ (mean squared difference / expected from both "
             "noises, ≈ 1 when they agree) / relative bias beyond the noise / the relative "
             "noise of the difference (the check's resolution) (*disagrees*: "
             f"χ > {CHI_MAX:g} and bias > {100 * BIAS_MAX:g} %); *vs ground truth* — the "
             "mean of each renderer's top-spp AR composites against the ground truth (rel. "
             "RMSE: the proxy's imperfections and the composite, as in issue 22); *t* — "
             "time to the noise level from the log–log fit (s); ratios: Cycles' time / "
             f"onepass's. Every measure leaves out directly seen lights (pixels brighter than "
             f"{BRIGHT:g}× the ground truth's median luminance; share in brackets).", "",
             f"| scene | world check χ / bias / noise | vs ground truth: onepass / "
             f"{'reference / ' if ref else ''}Cycles | onepass t 5 % / 2.5 % | Cycles t 5 % "
             "/ 2.5 % | **Cycles / onepass at 5 %** | **at 2.5 %** | "
             f"{'Cycles / reference at 2.5 % | ' if ref else ''}noise slope onepass / Cycles |",
             "|---|---|---|---|---|---|---|" + ("---|" if ref else "") + "---|"]
    before = "onepass power" if "onepass power" in labels else None
    if before:
        lines[-2] += " before: Cycles / onepass power 5 % / 2.5 % |"
        lines[-1] += "---|"
    lines[-2] += " Cycles without its synchronisation / onepass 5 % / 2.5 % |"
    lines[-1] += "---|"
    ratios: dict[float, list[float]] = {0.05: [], 0.025: []}
    extra: dict[str, dict[float, list[float]]] = {"before": {0.05: [], 0.025: []},
                                                  "nosync": {0.05: [], 0.025: []}}
    skipped, bad = [], []
    for res in results:
        name = res["name"]
        if "skip" in res:
            skipped.append(res)
            lines.append(f"| {name} | skipped: {res['skip']} |" + " |" * (7 if ref else 6))
            continue
        t, vs = res["t_to"], res["vs_gt"]
        r5 = t["cycles"][0.05] / t["onepass"][0.05]
        r25 = t["cycles"][0.025] / t["onepass"][0.025]
        held = name != args.scene
        if disagrees(res["check"]):
            bad.append(name)
        elif held:
            ratios[0.05].append(r5)
            ratios[0.025].append(r25)
        gtcol = " / ".join(f"{vs[k]:.3f}" for k in ["onepass", *([ref] if ref else []),
                                                     "cycles"])
        refcol = f"{t['cycles'][0.025] / t[ref][0.025]:.2f} | " if ref else ""
        mark = "" if held else " (suite)"
        sync = res.get("cycles_sync", float("nan"))
        nosync = [(max(sec - (sync if np.isfinite(sync) else 0.0), 1e-3), e)
                  for sec, e in res["pts"]["cycles"]]
        cols = {"nosync": {x: time_to(nosync, x) / t["onepass"][x] for x in (0.05, 0.025)}}
        if before:
            cols["before"] = {x: t["cycles"][x] / t[before][x] for x in (0.05, 0.025)}
        tail = "".join(f" {cols[k][0.05]:.2f} / {cols[k][0.025]:.2f} |"
                       for k in ("before", "nosync") if k in cols)
        if held and not disagrees(res["check"]):
            for k, v in cols.items():
                for x in (0.05, 0.025):
                    extra[k][x].append(v[x])
        lines.append(f"| {name}{mark} | {_fmt_check(res)} | {gtcol} | "
                     f"{t['onepass'][0.05]:.3g} / {t['onepass'][0.025]:.3g} | "
                     f"{t['cycles'][0.05]:.3g} / {t['cycles'][0.025]:.3g} | {r5:.2f} | "
                     f"{r25:.2f} | {refcol}{res['slope']['onepass']:.2f} / "
                     f"{res['slope']['cycles']:.2f} |{tail}")
    n_worlds = len([r for r in results if r["name"] != args.scene])
    lines += [""]
    if ratios[0.05]:
        q5, q25 = quantiles(ratios[0.05]), quantiles(ratios[0.025])
        lines += [f"**Distribution over the {len(ratios[0.05])} measured held-out worlds** "
                  f"(of {n_worlds}: {len(skipped)} skipped, {len(bad)} disagreeing with the "
                  "ground truth, left out), Cycles' time / onepass's to equal noise:", "",
                  "| noise | median | 10th percentile | worst |", "|---|---|---|---|",
                  f"| 5 % | {q5[0]:.2f} | {q5[1]:.2f} | {q5[2]:.2f} |",
                  f"| 2.5 % | {q25[0]:.2f} | {q25[1]:.2f} | {q25[2]:.2f} |", ""]
        share = {x: sum(r >= 1.0 for r in ratios[x]) / len(ratios[x]) for x in ratios}
        lines += [f"onepass at least as fast as Cycles on {100 * share[0.05]:.0f} % of these "
                  f"worlds at 5 % and {100 * share[0.025]:.0f} % at 2.5 %.", ""]
        for k, what in (("before", "before (lights chosen by one global power estimate, "
                                   "same run)"),
                        ("nosync", "Cycles' time without its synchronisation (an estimate: "
                                   "its mean synchronisation per render subtracted)")):
            if extra[k][0.05]:
                a, b = quantiles(extra[k][0.05]), quantiles(extra[k][0.025])
                lines += [f"The same, {what}: 5 % median {a[0]:.2f} / 10th percentile "
                          f"{a[1]:.2f} / worst {a[2]:.2f}; 2.5 % median {b[0]:.2f} / "
                          f"{b[1]:.2f} / {b[2]:.2f}.", ""]
    if skipped:
        lines += ["Skipped (not translatable to Cycles as Mitsuba renders them): "
                  + "; ".join(f"{r['name']} — {r['skip']}" for r in skipped) + ".", ""]
    lines += ["Worlds:", ""]
    for res in results:
        lines.append(f"* {res['name']}: {descriptions.get(res['name'], '')}")
    lines += ["", f"Points (mean seconds, noise) per spp {args.spp}; Cycles' seconds include its "
              "synchronisation (its mean per render on its own line: with an environment "
              "map mostly the bake of the map's importance table):", ""]
    for res in results:
        if "pts" in res:
            lines.append(f"* {res['name']} Cycles synchronisation: {res['cycles_sync']:.2f} s")
            for k, v in res["pts"].items():
                lines.append(f"* {res['name']} {k}: "
                             + ", ".join(f"({s:.2f}, {e:.4f})" for s, e in v))
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------
# Main
# --------------------------------------------------------------------------------------------

def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bpy-python", default=os.environ.get("ARLIGHT_BPY_PYTHON",
                                                           "/tmp/venv-bpy/bin/python"))
    ap.add_argument("--scene", default="bunny-box")
    ap.add_argument("--worlds", default=None,
                    help="generated worlds too, e.g. heldout:8 (arlight.evaluate.worlds)")
    ap.add_argument("--width", type=int, default=160)
    ap.add_argument("--spp", nargs="+", type=int, default=[4, 16, 64, 256])
    ap.add_argument("--repeats", type=int, default=3,
                    help="independent renders per spp and renderer (>= 2: the noise estimate)")
    ap.add_argument("--frame-spp", type=int, default=1024)
    ap.add_argument("--check-spp", type=int, default=128,
                    help="spp of each of the two Cycles renders of a world checked against "
                         "the ground truth")
    ap.add_argument("--max-depth", type=int, default=8)
    ap.add_argument("--only", nargs="+", default=None, choices=list(ARLIGHT),
                    help="arlight renderers to run (Cycles always runs; default: all, with "
                         "--worlds onepass and reference)")
    ap.add_argument("--check-lights", action="store_true",
                    help="only render the one-light worlds in both renderers and compare")
    ap.add_argument("--check-dir", default=None,
                    help="with --check-lights: keep both renders of each world here (.npz)")
    ap.add_argument("--denoise", action="store_true",
                    help="instead: equal-time PSNR against the ground truth with the denoiser "
                         "on both sides (onepass + OIDN, Cycles + its OIDN; issue #31) at "
                         "--denoise-spp")
    ap.add_argument("--denoise-spp", nargs="+", type=int, default=[1, 4, 16])
    ap.add_argument("--write", action="store_true")
    args = ap.parse_args()
    if args.repeats < 2:
        sys.exit("--repeats must be >= 2 (the noise comes from the spread of the repeats)")
    if not Path(args.bpy_python).exists():
        sys.exit(f"no Python with bpy at {args.bpy_python} (see the module docstring)")
    if args.check_lights:
        check_lights(args)
        return
    labels = list(args.only or (["onepass", "reference"] if args.worlds else ARLIGHT))
    if "onepass" not in labels:
        sys.exit("--only must include onepass (the ratios are Cycles' time over onepass's)")

    from vs_cycles_denoised import denoised_report, measure_denoised

    from arlight.evaluate.suite import get_scene
    from arlight.evaluate.worlds import GENERATOR_VERSION, generate, parse_worlds
    from arlight.synthetic import synthesize

    args.generator_version = GENERATOR_VERSION
    suite = get_scene(args.scene, quick=False)
    w, h = suite.resolution
    size = (args.width, round(args.width * h / w))
    jobs = [(args.scene, suite.world.resized(*size), suite.proxy.resized(*size), None)]
    descriptions = {args.scene: suite.description}
    for seed in parse_worlds(args.worlds) if args.worlds else []:
        gw = generate(seed)
        jobs.append((gw.name, None, None, gw))
        descriptions[gw.name] = gw.describe()
    pressure = [cpu_pressure()]
    results = []
    with tempfile.TemporaryDirectory() as tmp_dir:
        for name, world, proxy, gw in jobs:
            if gw is not None:
                sc = gw.suite_scene(args.width)
                world, proxy = sc.world, sc.proxy
                photo = sc.photo(spp=args.frame_spp, seed=1, max_depth=args.max_depth)
            else:
                photo = synthesize(world, spp=args.frame_spp, seed=1, max_depth=args.max_depth)
            if args.denoise:
                results.append(measure_denoised(name, proxy, photo, args, Path(tmp_dir)))
            else:
                results.append(measure(name, world, proxy, photo, args, labels,
                                       Path(tmp_dir)))
    pressure.append(cpu_pressure())
    if args.denoise:
        publish(denoised_report(results, descriptions, args, size, pressure), args.write)
        return
    if not args.worlds:
        res = results[0]
        lines = [HEADING, "",
                 f"`python benchmarks/bench_vs_cycles.py --width {size[0]} --spp "
                 f"{' '.join(map(str, args.spp))} --repeats {args.repeats}` — `{args.scene}` "
                 f"proxy at {size[0]}×{size[1]}, max_depth {args.max_depth} (Cycles: "
                 f"{args.max_depth - 2} bounces), {args.repeats} interleaved repeats per spp, "
                 f"frame and ground truth {args.frame_spp} spp (Mitsuba). Noise: relative RMSE "
                 "of one render about its own expectation, from the repeats' per-pixel "
                 f"variance. CPU pressure (avg60) before/after: {pressure[0] or 'n/a'} / "
                 f"{pressure[1] or 'n/a'} %.", ""]
        if "skip" in res:
            sys.exit(f"{args.scene}: {res['skip']}")
        lines += [f"World check (Cycles' render of the world vs the ground truth, χ / bias): "
                  f"{_fmt_check(res)}.", ""]
        publish("\n".join(lines + scene_table(res, labels, args)), args.write)
        return
    publish(worlds_report(results, descriptions, labels, args, size, pressure), args.write)


if __name__ == "__main__":
    main()
