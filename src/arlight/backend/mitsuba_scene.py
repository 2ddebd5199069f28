"""Translating an AR scene for Mitsuba: a plain-data description, then Mitsuba objects.

Translation happens in two steps:

1. **Describe** (:func:`describe_views`, :func:`describe_sensor`): the :class:`ARScene` becomes
   a *description* made of plain data only — nested dicts, lists, floats, ints, strings,
   bools and NumPy arrays. A node is a dict with a ``"type"`` (a Mitsuba plugin name, or
   ``"mesh"`` for an in-memory triangle mesh) and the plugin's properties, as in
   :func:`mitsuba.load_dict`, except that

   * ``to_world`` is a 4×4 NumPy matrix, or Mitsuba's constructor arguments where Mitsuba
     builds the transform itself (``{"rotate": {"axis", "angle"}}``, ``{"look_at": {...}}``)
     so the loaded objects stay bitwise what they were;
   * ``bitmap`` is an ``(H, W, C)`` float32 array (texture files and environment maps enter
     as their decoded pixels, never as file names);
   * a ``"mesh"`` node holds world-space ``vertices (V, 3)`` float32, ``faces (F, 3)``
     uint32, optional ``uv (V, 2)`` and world-space unit vertex ``normals (V, 3)`` float32
     (None: flat faces). Normals come with the scene (file or NumPy-recomputed, see
     :mod:`arlight.scene.mesh`), never from Mitsuba's ``recompute_vertex_normals``, whose
     parallel float atomics made mesh renders differ from run to run.

   A view description is ``{"objects": {name: node}}`` in scene order: the lights
   (``"light<i>"``) then the shapes (``"<i>"``, the index into ``ARScene.shapes``). Materials
   and lights are translated by one function per type (:data:`MATERIALS`, :data:`LIGHTS`).
   Everything that determines a rendered image is in the description and nothing else is
   (no shape names, no scene ``description`` text), so :mod:`arlight.synthetic` can hash it
   as a cache key.

2. **Load** (:func:`load_scene`, :func:`load_view`, :func:`load_sensor`): the description
   becomes Mitsuba objects. Shapes are loaded one by one and given their name as Mitsuba id;
   other emitters go into the scene dictionary.

:func:`build_views` does both for the two views the methods use:

* ``real`` (µ): the real proxy and the lights — what the camera saw.
* ``mixed`` (ρ): the real proxy, the virtual objects and the lights.

Both are built from the same description, so shared shapes, materials and emitters are
identical. :class:`SceneViews` also keeps, per view, a table from Mitsuba's shape registry id
to our shape index, so a hit can be told real or virtual inside a JIT kernel.

Units: lengths in metres (scene units), angles in degrees where Mitsuba takes degrees
(``fov``, ``rotate.angle``, spot ``cutoff_angle``), radiance in W·sr⁻¹·m⁻² (linear RGB).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.errors import InputError
from arlight.interrupts import shielded, test_point
from arlight.io.images import to_bitmap
from arlight.jit import ensure_variant
from arlight.scene.camera import Camera
from arlight.scene.model import ARScene, Light, Material, Shape

ROLE_MISS, ROLE_REAL, ROLE_VIRTUAL = -1, 0, 1
LIGHT_SHAPE_INDEX = -2  # shape index reported for hits on area-light emitter geometry
LIGHT_PREFIX = "light"  # object names of lights: "light<i>"; shapes are named "<i>"
NEAR_CLIP = 1e-4
"""Near clip distance of the Mitsuba sensors, metres: Mitsuba starts camera rays there (its
default, 1 cm, would move ray origins visibly off the camera centre)."""

Node = dict[str, Any]
"""A description node: plain data only (see the module docstring)."""


# --------------------------------------------------------------------------------------------
# Describe: materials
# --------------------------------------------------------------------------------------------

def sampler_count(kind: str, n: int) -> int:
    """Samples per pixel Mitsuba's sampler ``kind`` renders when asked for ``n`` (its own
    rounding, e.g. ``multijitter`` 5 → 6; its warning about rounding is silenced)."""
    ensure_variant()
    level = mi.log_level()
    mi.set_log_level(mi.LogLevel.Error)
    try:
        return int(mi.load_dict({"type": kind, "sample_count": int(n)}).sample_count())
    finally:
        mi.set_log_level(level)


def _rgb(c) -> Node:
    return {"type": "rgb", "value": [float(x) for x in c]}


def _texture(path: str) -> Node:
    """Albedo texture: LDR files are sRGB-decoded, HDR files are used as linear values."""
    from arlight.io.images import read_linear

    data = np.clip(read_linear(path), 0.0, 1.0).astype(np.float32)
    return {"type": "bitmap", "bitmap": data, "raw": True}


def _twosided(inner: Node) -> Node:
    return {"type": "twosided", "bsdf": inner}


def _sided(inner: Node, p: dict[str, Any]) -> Node:
    """An opaque BSDF node, wrapped in ``twosided`` unless ``two_sided = false`` (then the
    back side is black, as a bare Mitsuba BSDF)."""
    return _twosided(inner) if p.get("two_sided", True) else inner


def _diffuse(p: dict[str, Any]) -> Node:
    refl = _texture(p["texture"]) if p.get("texture") else _rgb(p["albedo"])
    return _sided({"type": "diffuse", "reflectance": refl}, p)


def _phong(p: dict[str, Any]) -> Node:
    # kd, ks rounded to float32 as Mitsuba's ScalarColor3f would: the plugin averages them in
    # double precision for its lobe probability, so the rounding is part of the image
    def f32(c) -> list[float]:
        return [float(np.float32(x)) for x in c]

    return _sided({"type": phong_plugin_name(), "kd": f32(p["kd"]), "ks": f32(p["ks"]),
                   "n": float(p["exponent"])}, p)


def _roughconductor(p: dict[str, Any]) -> Node:
    return _sided({"type": "roughconductor", "distribution": "ggx", "alpha": p["alpha"],
                   "material": "none", "specular_reflectance": _rgb(p["reflectance"])}, p)


def _mirror(p: dict[str, Any]) -> Node:
    return _sided({"type": "conductor", "material": "none",
                   "specular_reflectance": _rgb(p["reflectance"])}, p)


def _glass(p: dict[str, Any]) -> Node:
    return {"type": "dielectric", "int_ior": p["ior"], "ext_ior": p["ext_ior"]}


def _roughdielectric(p: dict[str, Any]) -> Node:
    return {"type": "roughdielectric", "distribution": "ggx", "alpha": p["alpha"],
            "int_ior": p["ior"], "ext_ior": p["ext_ior"]}


def _bitmap(pixels: np.ndarray) -> Node:
    """A raw (linear, unconverted) bitmap texture node of ``(H, W, C)`` values."""
    return {"type": "bitmap", "bitmap": np.ascontiguousarray(pixels, dtype=np.float32),
            "raw": True}


def _factor_texture(tex: Any, factor: Any, channels: slice | int) -> Node | float:
    """``factor × tex[..., channels]`` as a bitmap node, or the factor alone without a
    texture (a float for one channel, an ``rgb`` node for three)."""
    f = np.asarray(factor, dtype=np.float64)
    if tex is None:
        return _rgb(f) if f.ndim else float(f)
    px = np.asarray(tex.pixels, dtype=np.float64)[..., channels]
    px = px[..., None] if px.ndim == 2 else px
    return _bitmap(px * f)


def _normal_pixels(tex: Any, scale: float) -> np.ndarray:
    """A glTF normal map scaled as ``normalTexture.scale`` says (x, y times ``scale``,
    renormalised), re-encoded as ``(n + 1) / 2`` for Mitsuba's ``normalmap``."""
    n = 2.0 * np.asarray(tex.pixels[..., :3], dtype=np.float64) - 1.0
    n[..., :2] *= scale
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    return (n + 1.0) / 2.0


def _opacity(p: dict[str, Any]) -> Node | float | None:
    """Coverage of a ``pbr`` material for Mitsuba's ``mask`` (None: opaque)."""
    if p["alpha_mode"] == "opaque":
        return None
    tex = p.get("base_color_texture")
    alpha = (np.asarray(tex.pixels[..., 3], np.float64) * p["alpha"]
             if tex is not None and tex.pixels.shape[2] == 4 else np.float64(p["alpha"]))
    if p["alpha_mode"] == "mask":
        alpha = (alpha >= p["alpha_cutoff"]).astype(np.float64)
    if alpha.ndim == 0:
        return None if alpha >= 1.0 else float(alpha)
    return _bitmap(alpha[..., None])


def _pbr(p: dict[str, Any]) -> Node:
    """Metallic-roughness PBR as Mitsuba's ``principled`` (GGX, α = roughness², dielectric
    F0 from ``ior``), in ``normalmap`` when it has a normal map, ``twosided`` when opaque and
    two-sided, ``mask`` when ``alpha_mode`` is not opaque. Factors are multiplied into the
    texture pixels (glTF: factor × texture). Occlusion and emission are not part of it
    (a path tracer traces occlusion; see docs/scene-format.md for emission)."""
    mr = p.get("metallic_roughness_texture")
    node: Node = {"type": "principled",
                  "base_color": _factor_texture(p.get("base_color_texture"), p["base_color"],
                                                slice(0, 3)),
                  "roughness": _factor_texture(mr, p["roughness"], 1),
                  "metallic": _factor_texture(mr, p["metallic"], 2),
                  "eta": float(p["ior"]), "spec_trans": float(p["transmission"])}
    if p.get("normal_texture") is not None:
        node = {"type": "normalmap",
                "normalmap": _bitmap(_normal_pixels(p["normal_texture"], p["normal_scale"])),
                "bsdf": node}
    if p["transmission"] == 0.0 and p.get("two_sided", True):
        node = _twosided(node)
    opacity = _opacity(p)
    if opacity is not None:
        node = {"type": "mask", "opacity": opacity, "bsdf": node}
    return node


MATERIALS: dict[str, Callable[[dict[str, Any]], Node]] = {
    "diffuse": _diffuse,
    "phong": _phong,
    "roughconductor": _roughconductor,
    "mirror": _mirror,
    "glass": _glass,
    "roughdielectric": _roughdielectric,
    "pbr": _pbr,
}
"""Material type -> BSDF node from the material's ``params`` (opaque materials two-sided
unless ``two_sided = false``; dielectrics have two sides by nature)."""


def phong_plugin_name() -> str:
    """Mitsuba plugin name of the Python Phong BSDF (:mod:`arlight.backend.phong`)."""
    ensure_variant()  # the plugin module subclasses mi.BSDF, which needs a variant
    from arlight.backend.phong import PLUGIN_NAME

    return PLUGIN_NAME


def describe_material(mat: Material) -> Node:
    """BSDF node of one material (see :data:`MATERIALS`)."""
    translate = MATERIALS.get(mat.type)
    if translate is None:  # the schema rejects unknown types first
        raise ValueError(f"unknown material type {mat.type!r}")
    return translate(mat.params)


# --------------------------------------------------------------------------------------------
# Describe: shapes
# --------------------------------------------------------------------------------------------

_PRIMITIVE_CANONICAL: dict[str, Callable[[dict[str, Any]], np.ndarray]] = {
    # Mitsuba's canonical primitives: rectangle and cube span [-1, 1], disk and sphere r = 1.
    "rectangle": lambda p: np.diag([p["size"][0] / 2, p["size"][1] / 2, 1.0, 1.0]),
    "box": lambda p: np.diag([p["size"][0] / 2, p["size"][1] / 2, p["size"][2] / 2, 1.0]),
    "disk": lambda p: np.diag([p["radius"], p["radius"], 1.0, 1.0]),
    "sphere": lambda p: np.diag([p["radius"]] * 3 + [1.0]),
}
_MITSUBA_TYPE = {"rectangle": "rectangle", "box": "cube", "disk": "disk", "sphere": "sphere"}


def _primitive(shape: Shape) -> Node:
    m = np.asarray(shape.to_world, dtype=np.float64) @ _PRIMITIVE_CANONICAL[shape.type](
        shape.params)
    return {"type": _MITSUBA_TYPE[shape.type], "to_world": m}


def _mesh(shape: Shape) -> Node:
    data = shape.mesh
    assert data is not None
    to_world = np.asarray(shape.to_world, dtype=np.float64)
    v = np.asarray(data.vertices, dtype=np.float64)
    v = (v @ to_world[:3, :3].T + to_world[:3, 3]).astype(np.float32)
    faces = np.asarray(data.faces, dtype=np.uint32)
    if np.linalg.det(to_world[:3, :3]) < 0:
        faces = faces[:, ::-1].copy()  # keep outward normals under mirroring transforms
    normals = None
    if data.normals is not None:  # normals transform with the inverse transpose
        n = np.asarray(data.normals, dtype=np.float64) @ np.linalg.inv(to_world[:3, :3])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        normals = n.astype(np.float32)
    return {"type": "mesh", "vertices": v, "faces": faces,
            "uv": None if data.uv is None else np.asarray(data.uv),
            "normals": normals}


SHAPES: dict[str, Callable[[Shape], Node]] = {
    "mesh": _mesh, **{t: _primitive for t in _PRIMITIVE_CANONICAL}}
"""Shape type -> geometry node (world-space geometry, no BSDF)."""


def describe_geometry(shape: Shape) -> Node:
    """Geometry node of one shape (see :data:`SHAPES`): its shape node without the BSDF,
    all that changes when the shape moves."""
    translate = SHAPES.get(shape.type)
    if translate is None:
        raise ValueError(f"unknown shape type {shape.type!r}")
    return translate(shape)


def describe_shape(shape: Shape) -> Node:
    """Shape node of one shape: its geometry (:func:`describe_geometry`) and BSDF."""
    return {**describe_geometry(shape), "bsdf": describe_material(shape.material)}


# --------------------------------------------------------------------------------------------
# Describe: lights
# --------------------------------------------------------------------------------------------

def _envmap(light: Light) -> Node:
    p = light.params
    return {"type": "envmap", "bitmap": light.radiance_map, "scale": p["scale"],
            "to_world": {"rotate": {"axis": [0.0, 1.0, 0.0], "angle": p["rotation_deg"]}}}


def _constant(light: Light) -> Node:
    return {"type": "constant", "radiance": _rgb(light.params["radiance"])}


def _point(light: Light) -> Node:
    p = light.params
    return {"type": "point", "position": p["position"], "intensity": _rgb(p["intensity"])}


def _spot(light: Light) -> Node:
    p = light.params
    up = _any_perpendicular(np.subtract(p["target"], p["position"]))
    return {"type": "spot", "intensity": _rgb(p["intensity"]),
            "cutoff_angle": p["cutoff_deg"], "beam_width": p["beam_width_deg"],
            "to_world": {"look_at": {"origin": p["position"], "target": p["target"],
                                     "up": up}}}


def _directional(light: Light) -> Node:
    p = light.params
    return {"type": "directional", "direction": p["direction"],
            "irradiance": _rgb(p["irradiance"])}


def _area(light: Light) -> Node:
    p = light.params
    m = np.asarray(p["to_world"], dtype=np.float64) @ np.diag(
        [p["size"][0] / 2, p["size"][1] / 2, 1.0, 1.0])
    return {"type": "rectangle", "to_world": m,
            "bsdf": {"type": "diffuse", "reflectance": _rgb([0, 0, 0])},
            "emitter": {"type": "area", "radiance": _rgb(p["radiance"])}}


def _sphere(light: Light) -> Node:
    """A uniformly emitting sphere: radiance I/(πr²) makes its intensity I in every
    direction (its projected area is πr² from anywhere outside)."""
    p = light.params
    r = float(p["radius"])
    return {"type": "sphere", "center": [float(x) for x in p["position"]], "radius": r,
            "bsdf": {"type": "diffuse", "reflectance": _rgb([0, 0, 0])},
            "emitter": {"type": "area",
                        "radiance": _rgb([float(c) / (np.pi * r * r) for c in p["intensity"]])}}


LIGHTS: dict[str, Callable[[Light], Node]] = {
    "envmap": _envmap,
    "sh": _envmap,  # its radiance_map is the SH expansion sampled on the sphere
    "constant": _constant,
    "point": _point,
    "spot": _spot,
    "directional": _directional,
    "area": _area,  # an emitting one-sided rectangle (a shape node)
    "sphere": _sphere,  # an emitting sphere (a shape node)
}
"""Light type -> emitter node, or a shape node with an ``emitter`` for area lights."""


def describe_light(light: Light) -> Node:
    """Emitter (or emitting shape) node of one light (see :data:`LIGHTS`)."""
    translate = LIGHTS.get(light.type)
    if translate is None:
        raise ValueError(f"unknown light type {light.type!r}")
    return translate(light)


def _any_perpendicular(d) -> list[float]:
    d = np.asarray(d, dtype=np.float64)
    a = np.array([0.0, 1.0, 0.0]) if abs(d[1]) < 0.9 * np.linalg.norm(d) else np.array(
        [1.0, 0.0, 0.0])
    return np.cross(d, np.cross(a, d)).tolist()


# --------------------------------------------------------------------------------------------
# Describe: views and sensor
# --------------------------------------------------------------------------------------------

def describe_views(scene: ARScene) -> dict[str, Node]:
    """Descriptions of both views: ``{"real": view, "mixed": view}``, each
    ``{"objects": {name: node}}`` (lights ``"light<i>"`` first, then shapes ``"<i>"``).

    Without virtual shapes the two descriptions are equal.
    """
    lights = {f"{LIGHT_PREFIX}{i}": describe_light(x) for i, x in enumerate(scene.lights)}
    shapes = {str(i): describe_shape(s) for i, s in enumerate(scene.shapes)}
    real = {k: v for k, v in shapes.items() if not scene.shapes[int(k)].is_virtual}
    return {"real": {"objects": {**lights, **real}},
            "mixed": {"objects": {**lights, **shapes}}}


def virtual_names(scene: ARScene) -> set[str]:
    """Object names (in a view description) of the virtual shapes."""
    return {str(i) for i, s in enumerate(scene.shapes) if s.is_virtual}


def is_shape_node(node: Node) -> bool:
    """Whether a top-level object node is a shape (else it is a non-geometric emitter)."""
    return node["type"] in _SHAPE_LOADERS


def describe_coverage_view(mixed: Node, virtual: set[str]) -> Node:
    """The coverage view of a mixed-view description, for the virtual-coverage mask.

    Every shape keeps its geometry; virtual shapes get a two-sided white diffuse BSDF, all
    other shapes (real ones and area-light geometry) a two-sided black one and no emitter;
    emitters without geometry are dropped. Mitsuba's ``aov`` integrator with an ``albedo``
    channel then reads 1 where a camera ray's first hit is virtual and 0 elsewhere (also on
    misses), so its box-filtered pixel mean is the virtual fraction of the pixel's area.
    """
    out = {}
    for name, node in mixed["objects"].items():
        if not is_shape_node(node):
            continue
        albedo = [1.0, 1.0, 1.0] if name in virtual else [0.0, 0.0, 0.0]
        shape = {k: v for k, v in node.items() if k != "emitter"}
        shape["bsdf"] = _twosided({"type": "diffuse", "reflectance": _rgb(albedo)})
        out[name] = shape
    return {"objects": out}


def describe_sensor(camera: Camera, spp: int) -> Node:
    """Mitsuba sensor node for ``camera``: ``perspective``, or ``thinlens`` when the camera
    has a disk aperture (``aperture_radius > 0``); an ``hdrfilm`` with a box filter (each
    sample counts for the one pixel it falls in, with equal weight) and an ``independent``
    sampler of ``spp`` samples per pixel.

    OpenCV camera axes (x right, y down, z forward) become Mitsuba's (x left, y up,
    z forward) by flipping x and y in ``to_world``. Mitsuba's principal-point offsets are
    fractions of the film size measured in its own (flipped) axes, hence ``(W/2 − cx)/W``.
    The thin lens samples the same uniform disk as :mod:`arlight.backend.camera_rays`
    (mirrored through the lens centre, which leaves the distribution unchanged) and focuses
    on the plane ``z = focus_distance``.

    Raises:
        InputError: for what Mitsuba's sensors cannot represent: non-square pixels
            (``fx != fy``), a square aperture, an off-centre principal point with a lens.
    """
    w, h = camera.width, camera.height
    if abs(camera.fx - camera.fy) > 1e-6 * max(abs(camera.fx), abs(camera.fy)):
        raise InputError(f"fx = {camera.fx} != fy = {camera.fy}: Mitsuba's perspective "
                         "sensors have square pixels only", field="camera.intrinsics")
    to_world = np.asarray(camera.world_from_camera, dtype=np.float64) @ np.diag(
        [-1.0, -1.0, 1.0, 1.0])
    node: Node = {"type": "perspective", "fov_axis": "y",
                  "fov": float(np.degrees(2 * np.arctan(0.5 * h / camera.fy))),
                  "near_clip": NEAR_CLIP, "to_world": to_world}
    if camera.aperture_radius > 0:
        if camera.aperture_shape != "disk":
            raise InputError(f"Mitsuba has no {camera.aperture_shape} aperture (its thinlens "
                             "sensor's aperture is a disk)", field="camera.aperture_shape")
        if abs(camera.cx - w / 2) > 1e-9 * w or abs(camera.cy - h / 2) > 1e-9 * h:
            raise InputError(f"principal point ({camera.cx}, {camera.cy}) is not the image "
                             f"centre ({w / 2}, {h / 2}): Mitsuba's thinlens sensor has no "
                             "principal-point offset", field="camera.intrinsics")
        node.update(type="thinlens", aperture_radius=float(camera.aperture_radius),
                    focus_distance=float(camera.focus_distance))
    else:
        node.update(principal_point_offset_x=float((w / 2 - camera.cx) / w),
                    principal_point_offset_y=float((h / 2 - camera.cy) / h))
    node["film"] = {"type": "hdrfilm", "width": w, "height": h, "rfilter": {"type": "box"},
                    "pixel_format": "rgb"}
    node["sampler"] = {"type": "independent", "sample_count": int(spp)}
    return node


# --------------------------------------------------------------------------------------------
# Load
# --------------------------------------------------------------------------------------------

def _load_transform(value: np.ndarray | Node) -> mi.ScalarTransform4f:
    if isinstance(value, dict):
        if "rotate" in value:
            r = value["rotate"]
            return mi.ScalarTransform4f().rotate(r["axis"], r["angle"])
        return mi.ScalarTransform4f().look_at(**value["look_at"])
    return mi.ScalarTransform4f(np.asarray(value, dtype=np.float64).tolist())


_VALUE_LOADERS: dict[str, Callable[[Any], Any]] = {
    "to_world": _load_transform,
    "bitmap": to_bitmap,  # copies read-only arrays (a world unpickled by Ray)
}
"""Property name -> conversion of its plain-data value into a Mitsuba value."""


def plugin_dict(node: Node) -> dict[str, Any]:
    """A description node as a :func:`mitsuba.load_dict` dictionary (nested nodes too)."""
    if node.get("type") == phong_plugin_name():
        from arlight.backend.phong import register

        register()  # a Python plugin: Mitsuba knows it once registered
    out: dict[str, Any] = {}
    for key, value in node.items():
        if isinstance(value, dict) and "type" in value:
            out[key] = plugin_dict(value)
        elif key in _VALUE_LOADERS:
            out[key] = _VALUE_LOADERS[key](value)
        else:
            out[key] = value
    return out


def _load_shape(name: str, node: Node) -> mi.Shape:
    obj = mi.load_dict(plugin_dict(node))
    obj.set_id(name)  # some plugins (cube) do not keep an "id" property
    return obj


def geometry_params(node: Node) -> dict[str, Any]:
    """Mitsuba parameter values (as :func:`mitsuba.traverse` names them) of a geometry node
    (:func:`describe_geometry`): a ``"mesh"`` node's vertex buffers; a sphere's, rectangle's
    or disk's ``to_world`` and a cube's buffers as the plugin computes them (a throw-away
    shape, never part of a scene). Setting them on a loaded shape of the same type makes it
    bitwise the shape :func:`load_object` would load from ``node``."""
    kind = node["type"]
    if kind == "mesh":
        v, faces, uv, normals = node["vertices"], node["faces"], node["uv"], node["normals"]
        out: dict[str, Any] = {
            "vertex_positions": dr.ravel(mi.Point3f(v[:, 0], v[:, 1], v[:, 2])),
            "faces": dr.ravel(mi.Vector3u(faces[:, 0], faces[:, 1], faces[:, 2]))}
        if uv is not None:
            out["vertex_texcoords"] = dr.ravel(mi.Point2f(uv[:, 0], uv[:, 1]))
        if normals is not None:
            out["vertex_normals"] = dr.ravel(
                mi.Normal3f(normals[:, 0], normals[:, 1], normals[:, 2]))
        return out
    # Mitsuba's primitives: what the plugin makes of to_world (a cube's buffers, a sphere's
    # transform with the inverse its constructor computed; assigning a ScalarTransform4f to
    # the parameter would compute the inverse otherwise, last bits apart)
    params = mi.traverse(mi.load_dict(plugin_dict(node)))
    if kind != "cube":
        return {"to_world": transform_parameter(params["to_world"])}
    return {k: type(params[k])(params[k]) for k in
            ("vertex_positions", "faces", "vertex_normals", "vertex_texcoords")}


def transform_parameter(value: mi.Transform4f) -> mi.Transform4f:
    """A ``to_world`` parameter value as every loaded or moved shape gets it: a transform
    built from ``value``'s matrix alone (its inverse computed by ``mi.Transform4f``; the
    plugins' constructors compute it otherwise, last bits apart)."""
    return mi.Transform4f(value.matrix)


def _load_mesh(name: str, node: Node) -> mi.Mesh:
    v, faces, uv, normals = node["vertices"], node["faces"], node["uv"], node["normals"]
    props = mi.Properties()
    props["bsdf"] = mi.load_dict(plugin_dict(node["bsdf"]))
    mesh = mi.Mesh(name, len(v), len(faces), props=props,
                   has_vertex_normals=normals is not None,
                   has_vertex_texcoords=uv is not None)
    params = mi.traverse(mesh)
    for key, value in geometry_params(node).items():
        params[key] = value
    params.update()
    mesh.set_id(name)  # registry lookup uses this id
    return mesh


_SHAPE_LOADERS: dict[str, Callable[[str, Node], mi.Shape]] = {
    "mesh": _load_mesh, **{t: _load_shape for t in _MITSUBA_TYPE.values()}}
"""Node type -> loader of a top-level shape object (others are emitter dictionaries)."""


def load_object(name: str, node: Node) -> mi.Shape | dict[str, Any]:
    """A top-level object: a loaded shape whose Mitsuba id is ``name``, or an emitter's
    :func:`mitsuba.load_dict` dictionary (to be placed in a scene dictionary)."""
    ensure_variant()
    loader = _SHAPE_LOADERS.get(node["type"])
    return plugin_dict(node) if loader is None else loader(name, node)


def load_scene(view: Node) -> mi.Scene:
    """The ``mi.Scene`` of a view description (no sensor)."""
    objects = {name: load_object(name, node) for name, node in view["objects"].items()}
    test_point("scene")
    with shielded():  # native construction; a Ctrl-C is delivered when it returns
        return mi.load_dict({"type": "scene", **objects})


def load_sensor(node: Node) -> mi.Sensor:
    """The ``mi.Sensor`` of a sensor node (:func:`describe_sensor`)."""
    ensure_variant()
    return mi.load_dict(plugin_dict(node))


def mitsuba_sensor(camera: Camera, spp: int) -> mi.Sensor:
    """Mitsuba's own sensor for ``camera`` (see :func:`describe_sensor`); used to run
    Mitsuba's integrators on our scenes (synthetic photographs, benchmark peers)."""
    return load_sensor(describe_sensor(camera, spp))


# --------------------------------------------------------------------------------------------
# The µ and ρ views of the methods
# --------------------------------------------------------------------------------------------

_GENERATIONS = itertools.count(1)
"""Source of :attr:`SceneView.generation` values (never repeated in a process)."""


@dataclass
class SceneView:
    """One Mitsuba scene plus lookup tables from Mitsuba shape ids to our shapes.

    Attributes:
        scene: the loaded ``mi.Scene``.
        shape_index: ``UInt32``-indexable Dr.Jit table: registry id -> our shape index
            (``LIGHT_SHAPE_INDEX`` for area-light geometry).
        role: registry id -> ``ROLE_REAL`` / ``ROLE_VIRTUAL``.
        generation: a number no other view or state of this view has had in the process:
            a new one at construction and at every change of the scene in place
            (:meth:`update`). Keys what is recorded from the scene (the frozen bounce probe,
            :func:`arlight.realtime.ibl_shading.bounce_probe`).
    """

    scene: mi.Scene
    shape_index: mi.Int32
    role: mi.Int32
    generation: int = field(default_factory=lambda: next(_GENERATIONS), compare=False)

    @property
    def base(self) -> SceneView:
        """The loaded view whose parameters a change goes through: this one (a
        :class:`~arlight.backend.object_space.SplitView` names the real view it shares)."""
        return self

    @property
    def params(self) -> mi.SceneParameters:
        """The scene's parameters, traversed once (they are references to the scene's)."""
        params = self.__dict__.get("_params")
        if params is None:
            params = self.__dict__["_params"] = mi.traverse(self.scene)
        return params

    def update(self, values: dict[str, Any]) -> None:
        """Set scene parameters in place (``{key: value}``, keys of :attr:`params`) and
        apply them (``params.update()``: plugins and the acceleration structure follow),
        with a new :attr:`generation` — the one way the views' scenes change in place, so
        nothing recorded from the old state is replayed on the new one."""
        params = self.params
        for key, value in values.items():
            params[key] = value
        params.update()
        for key in values:  # the plugins' copies read from memory: no kernel per lamp value
            dr.make_opaque(params[key])
        self.generation = next(_GENERATIONS)

    def hit_role(self, si: mi.SurfaceInteraction3f) -> mi.Int32:
        """Per-lane role of a surface interaction: miss -1, real 0, virtual 1."""
        reg = dr.reinterpret_array(mi.UInt32, si.shape)
        valid = si.is_valid()
        r = dr.gather(mi.Int32, self.role, reg, valid)
        return dr.select(valid, r, ROLE_MISS)

    def hit_shape(self, si: mi.SurfaceInteraction3f) -> mi.Int32:
        reg = dr.reinterpret_array(mi.UInt32, si.shape)
        valid = si.is_valid()
        return dr.select(valid, dr.gather(mi.Int32, self.shape_index, reg, valid), -1)

    def set_geometry(self, geometry: dict[str, dict[str, Any]]) -> None:
        """Give loaded shapes new geometry in place: ``{object name: geometry_params(...)}``
        (:func:`geometry_params`); the scene's acceleration structure is rebuilt once.

        The scene object, its shapes and their registry ids stay (no kernel that baked them
        is recompiled, no second scene is built). Light samplers cached on the view are kept:
        only non-emitting shapes may be moved this way.
        """
        self.update({f"{name}.{key}": value for name, values in geometry.items()
                     for key, value in values.items()})


@dataclass
class SceneViews:
    """The real-only (µ) and mixed (ρ) views of an AR scene.

    Attributes:
        real: the real-only view (µ).
        mixed: the mixed view (ρ); the same object as ``real`` without virtual shapes; a
            :class:`~arlight.backend.object_space.SplitView` where the virtual shapes are
            traced in object space.
        shapes: the shapes as the views hold them now (index = shape name in the views);
            :meth:`place` moves them.
    """

    real: SceneView
    mixed: SceneView
    shapes: list[Shape] = field(default_factory=list)

    def moved(self, shapes: list[Shape]) -> set[int]:
        """Indices of the shapes whose pose in ``shapes`` differs from the loaded one.

        Raises:
            ValueError: ``shapes`` is not a re-posing of the loaded shapes (another count,
                or a shape with another type, mesh, material or parameters).
        """
        if len(shapes) != len(self.shapes):
            raise ValueError(f"{len(shapes)} shapes, the views hold {len(self.shapes)}")
        moved: set[int] = set()
        for i, (old, new) in enumerate(zip(self.shapes, shapes, strict=True)):
            if old is new or np.array_equal(old.to_world, new.to_world):
                continue
            if (old.name, old.type, old.role) != (new.name, new.type, new.role) or \
                    old.params is not new.params or old.material is not new.material or \
                    old.mesh is not new.mesh:
                raise ValueError(f"shape {i} ({new.name!r}) changed more than its pose")
            moved.add(i)
        return moved

    def place(self, shapes: list[Shape]) -> set[int]:
        """Move the loaded shapes to ``shapes`` in place and return the indices of those that
        moved (:meth:`moved`): ``shapes`` is this world posed (:meth:`World.posed`: the same
        shapes, other ``to_world``). Each view then traces bitwise what
        :func:`build_views` of the posed world would build
        (tests/methods/test_pose_incremental.py); a split mixed view
        (:func:`arlight.backend.object_space.build_split_views`) only swaps its objects'
        frames, no acceleration structure rebuilt."""
        moved = self.moved(shapes)
        if not moved:
            self.shapes = list(shapes)
            return moved
        split = not isinstance(self.mixed, SceneView)  # backend.object_space.SplitView
        views = [self.mixed] if self.mixed is self.real else [self.real, self.mixed]
        held = [(view, {str(i) for i in moved if (view is self.mixed and not split)
                        or not self.shapes[i].is_virtual})
                for view in views if isinstance(view, SceneView)]
        geometry = {name: geometry_params(describe_geometry(shapes[int(name)]))
                    for name in set().union(*[here for _, here in held])}
        for view, here in held:
            if here:
                view.set_geometry({name: geometry[name] for name in here})
        if split:  # objects re-posed by their frames; real shapes moved in the real view
            self.mixed.place(shapes, moved)
        self.shapes = list(shapes)
        return moved


def load_view(view: Node, roles: dict[str, int]) -> SceneView:
    """Load a view description and tabulate its shapes' indices and roles.

    Args:
        view: ``{"objects": {name: node}}`` (see :func:`describe_views`).
        roles: shape name -> ``ROLE_REAL`` / ``ROLE_VIRTUAL`` (light geometry is real).
    """
    scene = load_scene(view)
    out = SceneView(scene, mi.Int32(0), mi.Int32(0))
    # every shape's to_world through the scene's parameters once, as SceneViews.place moves
    # shapes (transform_parameter): a shape moved in place is then bitwise one loaded there
    params = out.params
    objects = view["objects"]
    moved = {name: {"to_world": transform_parameter(params[f"{name}.to_world"])}
             for name, node in objects.items()
             if is_shape_node(node) and f"{name}.to_world" in params}
    if moved:
        out.set_geometry(moved)
    # emitters' to_world likewise (spot, directional, envmap): a light updated in place
    # (methods.base.relight_views) is then bitwise one loaded there
    turned = [f"{name}.to_world" for name, node in objects.items()
              if not is_shape_node(node) and f"{name}.to_world" in params]
    if turned:
        out.update({key: transform_parameter(params[key]) for key in turned})
    ids, idx, role = [], [], []
    for sh in scene.shapes():
        reg = int(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(sh))[0])
        sid = sh.id()
        ids.append(reg)
        if sid.startswith(LIGHT_PREFIX):
            idx.append(LIGHT_SHAPE_INDEX)
            role.append(ROLE_REAL)
        else:
            idx.append(int(sid))
            role.append(roles[sid])
    size = max(ids, default=0) + 1
    idx_table = np.full(size, -1, dtype=np.int32)
    role_table = np.full(size, ROLE_MISS, dtype=np.int32)
    idx_table[ids] = idx
    role_table[ids] = role
    out.shape_index, out.role = mi.Int32(idx_table), mi.Int32(role_table)
    return out


def build_views(scene: ARScene) -> SceneViews:
    """Build both Mitsuba views of ``scene``; each view gets its own shape objects."""
    ensure_variant()
    roles = {str(i): ROLE_VIRTUAL if s.is_virtual else ROLE_REAL
             for i, s in enumerate(scene.shapes)}
    desc = describe_views(scene)
    real = load_view(desc["real"], roles)
    mixed = load_view(desc["mixed"], roles) if scene.has_virtual else real
    return SceneViews(real=real, mixed=mixed, shapes=list(scene.shapes))
