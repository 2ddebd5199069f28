"""Building the two Mitsuba views of an AR scene.

* ``real`` (µ): the real proxy and the lights — what the camera saw.
* ``mixed`` (ρ): the real proxy, the virtual objects and the lights.

Both are built from the same dictionaries, so shared shapes, materials and emitters are
identical. :class:`SceneViews` also keeps, per view, a table from Mitsuba's shape registry id
to our shape index, so a hit can be told real or virtual inside a JIT kernel.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.variant import ensure_variant
from arlight.scene.model import ARScene, Light, Material, Shape

ROLE_MISS, ROLE_REAL, ROLE_VIRTUAL = -1, 0, 1
LIGHT_SHAPE_INDEX = -2  # shape index reported for hits on area-light emitter geometry


def _transform(m: np.ndarray) -> mi.ScalarTransform4f:
    return mi.ScalarTransform4f(np.asarray(m, dtype=np.float64).tolist())


def _rgb(c) -> dict[str, Any]:
    return {"type": "rgb", "value": [float(x) for x in c]}


def _texture(path: str) -> dict[str, Any]:
    """Albedo texture: LDR files are sRGB-decoded, HDR files are used as linear values."""
    from arlight.io.images import read_linear

    data = np.clip(read_linear(path), 0.0, 1.0).astype(np.float32)
    return {"type": "bitmap", "bitmap": mi.Bitmap(data), "raw": True}


def material_dict(mat: Material) -> dict[str, Any]:
    """Mitsuba BSDF dictionary for one material (opaque materials are two-sided)."""
    p = mat.params
    t = mat.type
    if t == "diffuse":
        refl = _texture(p["texture"]) if p.get("texture") else _rgb(p["albedo"])
        inner = {"type": "diffuse", "reflectance": refl}
    elif t == "phong":
        from arlight.backend.phong import PLUGIN_NAME, register

        register()
        inner = {"type": PLUGIN_NAME, "kd": mi.ScalarColor3f(p["kd"]),
                 "ks": mi.ScalarColor3f(p["ks"]), "n": float(p["exponent"])}
    elif t == "roughconductor":
        inner = {"type": "roughconductor", "distribution": "ggx", "alpha": p["alpha"],
                 "material": "none", "specular_reflectance": _rgb(p["reflectance"])}
    elif t == "mirror":
        inner = {"type": "conductor", "material": "none",
                 "specular_reflectance": _rgb(p["reflectance"])}
    elif t == "glass":
        return {"type": "dielectric", "int_ior": p["ior"], "ext_ior": p["ext_ior"]}
    elif t == "roughdielectric":
        return {"type": "roughdielectric", "distribution": "ggx", "alpha": p["alpha"],
                "int_ior": p["ior"], "ext_ior": p["ext_ior"]}
    else:  # the schema rejects unknown types first
        raise ValueError(f"unknown material type {t!r}")
    return {"type": "twosided", "bsdf": inner}


_PRIMITIVE_CANONICAL = {
    # Mitsuba's canonical primitives: rectangle and cube span [-1, 1], disk and sphere r = 1.
    "rectangle": lambda p: np.diag([p["size"][0] / 2, p["size"][1] / 2, 1.0, 1.0]),
    "box": lambda p: np.diag([p["size"][0] / 2, p["size"][1] / 2, p["size"][2] / 2, 1.0]),
    "disk": lambda p: np.diag([p["radius"], p["radius"], 1.0, 1.0]),
    "sphere": lambda p: np.diag([p["radius"]] * 3 + [1.0]),
}
_MITSUBA_TYPE = {"rectangle": "rectangle", "box": "cube", "disk": "disk", "sphere": "sphere"}


def shape_object(shape: Shape, index: int) -> mi.Shape:
    """Loaded Mitsuba shape whose id is ``"<index>"`` (our index into ``ARScene.shapes``)."""
    bsdf = material_dict(shape.material)
    if shape.type == "mesh":
        return _mesh(shape, index, bsdf)
    m = shape.to_world @ _PRIMITIVE_CANONICAL[shape.type](shape.params)
    obj = mi.load_dict({"type": _MITSUBA_TYPE[shape.type], "to_world": _transform(m),
                        "bsdf": bsdf})
    obj.set_id(str(index))  # some plugins (cube) do not keep an "id" property
    return obj


def _mesh(shape: Shape, index: int, bsdf: dict[str, Any]) -> mi.Mesh:
    data = shape.mesh
    assert data is not None
    v = np.asarray(data.vertices, dtype=np.float64)
    v = (v @ shape.to_world[:3, :3].T + shape.to_world[:3, 3]).astype(np.float32)
    faces = np.asarray(data.faces, dtype=np.uint32)
    if np.linalg.det(shape.to_world[:3, :3]) < 0:
        faces = faces[:, ::-1].copy()  # keep outward normals under mirroring transforms
    props = mi.Properties()
    props["bsdf"] = mi.load_dict(bsdf)
    mesh = mi.Mesh(str(index), len(v), len(faces), props=props,
                   has_vertex_normals=bool(shape.params.get("smooth", True)),
                   has_vertex_texcoords=data.uv is not None)
    params = mi.traverse(mesh)
    params["vertex_positions"] = dr.ravel(mi.Point3f(v[:, 0], v[:, 1], v[:, 2]))
    params["faces"] = dr.ravel(mi.Vector3u(faces[:, 0], faces[:, 1], faces[:, 2]))
    if data.uv is not None:
        params["vertex_texcoords"] = dr.ravel(mi.Point2f(data.uv[:, 0], data.uv[:, 1]))
    params.update()
    if shape.params.get("smooth", True):
        mesh.recompute_vertex_normals()
    mesh.set_id(str(index))  # registry lookup uses this id
    return mesh


def light_object(light: Light, index: int) -> dict[str, Any] | mi.Shape:
    """Mitsuba emitter dict, or a loaded emitting rectangle for area lights."""
    p = light.params
    if light.type in ("envmap", "sh"):
        rot = mi.ScalarTransform4f().rotate([0, 1, 0], p["rotation_deg"])
        return {"type": "envmap", "bitmap": mi.Bitmap(light.radiance_map),
                "scale": p["scale"], "to_world": rot}
    if light.type == "constant":
        return {"type": "constant", "radiance": _rgb(p["radiance"])}
    if light.type == "point":
        return {"type": "point", "position": p["position"], "intensity": _rgb(p["intensity"])}
    if light.type == "spot":
        return {"type": "spot", "intensity": _rgb(p["intensity"]),
                "cutoff_angle": p["cutoff_deg"], "beam_width": p["beam_width_deg"],
                "to_world": mi.ScalarTransform4f().look_at(
                    origin=p["position"], target=p["target"],
                    up=_any_perpendicular(np.subtract(p["target"], p["position"])))}
    if light.type == "directional":
        return {"type": "directional", "direction": p["direction"],
                "irradiance": _rgb(p["irradiance"])}
    if light.type == "area":
        m = p["to_world"] @ np.diag([p["size"][0] / 2, p["size"][1] / 2, 1.0, 1.0])
        obj = mi.load_dict({"type": "rectangle", "to_world": _transform(m),
                            "bsdf": {"type": "diffuse", "reflectance": _rgb([0, 0, 0])},
                            "emitter": {"type": "area", "radiance": _rgb(p["radiance"])}})
        obj.set_id(f"light{index}")
        return obj
    raise ValueError(f"unknown light type {light.type!r}")


def _any_perpendicular(d) -> list[float]:
    d = np.asarray(d, dtype=np.float64)
    a = np.array([0.0, 1.0, 0.0]) if abs(d[1]) < 0.9 * np.linalg.norm(d) else np.array(
        [1.0, 0.0, 0.0])
    return np.cross(d, np.cross(a, d)).tolist()


@dataclass
class SceneView:
    """One Mitsuba scene plus lookup tables from Mitsuba shape ids to our shapes.

    Attributes:
        scene: the loaded ``mi.Scene``.
        shape_index: ``UInt32``-indexable Dr.Jit table: registry id -> our shape index
            (``LIGHT_SHAPE_INDEX`` for area-light geometry).
        role: registry id -> ``ROLE_REAL`` / ``ROLE_VIRTUAL``.
    """

    scene: mi.Scene
    shape_index: mi.Int32
    role: mi.Int32

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


@dataclass
class SceneViews:
    """The real-only (µ) and mixed (ρ) views of an AR scene."""

    real: SceneView
    mixed: SceneView


def _build_view(objects: dict[str, Any], roles: dict[str, int]) -> SceneView:
    scene = mi.load_dict({"type": "scene", **objects})
    ids, idx, role = [], [], []
    for sh in scene.shapes():
        reg = int(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(sh))[0])
        sid = sh.id()
        ids.append(reg)
        if sid.startswith("light"):
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
    return SceneView(scene, mi.Int32(idx_table), mi.Int32(role_table))


def build_views(scene: ARScene) -> SceneViews:
    """Build both Mitsuba views of ``scene``; each view gets its own shape objects."""
    ensure_variant()
    roles = {str(i): ROLE_VIRTUAL if s.is_virtual else ROLE_REAL
             for i, s in enumerate(scene.shapes)}

    def objects(include_virtual: bool) -> dict[str, Any]:
        lights = {f"light{i}": light_object(x, i) for i, x in enumerate(scene.lights)}
        shapes = {str(i): shape_object(s, i) for i, s in enumerate(scene.shapes)
                  if include_virtual or not s.is_virtual}
        return {**lights, **shapes}

    real = _build_view(objects(False), roles)
    mixed = _build_view(objects(True), roles) if scene.has_virtual else real
    return SceneViews(real=real, mixed=mixed)


def mitsuba_sensor(camera, spp: int) -> mi.Sensor:
    """Mitsuba's own ``perspective`` sensor for ``camera`` (square pixels; thin lens ignored).

    Used to run Mitsuba's integrators on our scenes as a peer in benchmarks. Mitsuba's camera
    space is x left, y up, z forward, i.e. OpenCV's with x and y flipped.
    """
    w, h = camera.width, camera.height
    fov_y = float(np.degrees(2 * np.arctan(0.5 * h / camera.fy)))
    to_world = np.asarray(camera.world_from_camera) @ np.diag([-1.0, -1.0, 1.0, 1.0])
    return mi.load_dict({
        "type": "perspective", "fov_axis": "y", "fov": fov_y, "to_world": _transform(to_world),
        "principal_point_offset_x": (camera.cx - w / 2) / w,
        "principal_point_offset_y": (camera.cy - h / 2) / h,
        "film": {"type": "hdrfilm", "width": w, "height": h, "rfilter": {"type": "box"},
                 "pixel_format": "rgb"},
        "sampler": {"type": "independent", "sample_count": spp}})
