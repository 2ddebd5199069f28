"""Loading, validating and saving AR scene files (TOML or JSON).

The format is documented in ``docs/scene-format.md``; field tables live in
:mod:`arlight.scene.schema`. A scene file has the tables ``[camera]``, optional ``[frame]``,
optional ``[materials.<name>]``, and the arrays ``[[shapes]]`` and ``[[lights]]``. Relative
paths are relative to the scene file.
"""

from __future__ import annotations

import copy
import json
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from arlight.camera_response import Transfer
from arlight.errors import InputError
from arlight.scene import schema
from arlight.scene.camera import Camera, look_at
from arlight.scene.model import ARScene, FrameView, Light, Material, MeshData, Shape, World
from arlight.scene.pbr import TEXTURE_FIELDS
from arlight.scene.schema import Validator

FORMAT = "arlight-scene/1"
TOP_LEVEL = {"format", "camera", "frame", "materials", "shapes", "lights", "description",
             "render"}
PATH_KEYS = ("file", "image", "texture", "depth", *TEXTURE_FIELDS)
"""Fields holding paths (made absolute in ``raw``)."""


def _read_file(path: str | Path) -> tuple[dict[str, Any], Path]:
    path = Path(path)
    if not path.is_file():
        raise InputError("scene file not found", file=str(path))
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(f"not UTF-8 text (byte {exc.start}); scene files are UTF-8 TOML or "
                         "JSON", file=str(path)) from exc
    except OSError as exc:
        raise InputError(f"cannot read the file ({exc.strerror})", file=str(path)) from exc
    try:
        data = json.loads(text) if path.suffix.lower() == ".json" else tomllib.loads(text)
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"syntax error: {exc}", file=str(path)) from exc
    return data, path


def load_scene(path: str | Path, frame: str | Path | None = None) -> ARScene:
    """Load and validate a scene file; raise :class:`InputError` naming file and field.

    ``frame``: an image that replaces the file's ``[frame] image`` (see
    :func:`with_frame_file`)."""
    data, path = _read_file(path)
    scene = parse_scene(data, base_dir=path.parent, file=str(path))
    return scene if frame is None else with_frame_file(scene, frame)


def load_world(path: str | Path) -> World:
    """Load the static world of a scene file (a file without ``[camera]`` is allowed)."""
    data, path = _read_file(path)
    return parse_world(data, base_dir=path.parent, file=str(path))


def load_view(path: str | Path) -> FrameView:
    """Load one frame's view (``[camera]`` and optional ``[frame]``) from a scene file."""
    data, path = _read_file(path)
    return parse_view(data, base_dir=path.parent, file=str(path))


def _validator(data: Any, base_dir: str | Path, file: str) -> Validator:
    v = Validator(file, Path(base_dir).resolve())
    v.table(data, "")
    v.check_keys(data, TOP_LEVEL, "")
    if data.get("format", FORMAT) != FORMAT:
        raise v.fail("format", f"unsupported format {data['format']!r}; expected {FORMAT!r}")
    return v


def parse_scene(data: dict[str, Any], base_dir: str | Path = ".",
                file: str = "<scene>") -> ARScene:
    """Validate a scene dictionary (as read from TOML/JSON) and build an :class:`ARScene`:
    the world (:func:`parse_world`) seen in the view (:func:`parse_view`)."""
    world = parse_world(data, base_dir, file)
    view = parse_view(data, base_dir, file)
    try:
        return ARScene.compose(world, view)
    except ValueError as exc:
        raise InputError(str(exc), file=file, field="frame.object_transforms") from exc


def parse_world(data: dict[str, Any], base_dir: str | Path = ".",
                file: str = "<scene>") -> World:
    """The static world of a scene dictionary: ``[materials]``, ``[[shapes]]``,
    ``[[lights]]`` (``[camera]`` and ``[frame]`` are not read here)."""
    v = _validator(data, base_dir, file)
    materials = _materials(v, data.get("materials", {}))
    shapes = [shape for i, s in enumerate(_array(v, data, "shapes"))
              for shape in _shapes(v, s, i, materials)]
    names = [s.name for s in shapes]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise v.fail("shapes", f"duplicate shape name {sorted(dup)[0]!r}")
    lights = [_light(v, x, i) for i, x in enumerate(_array(v, data, "lights"))]
    if "render" in data:
        render_table(v, data["render"])
    return World(shapes=shapes, lights=lights,
                 source=Path(file) if file != "<scene>" else None,
                 raw=_canonical_raw(data, v.base_dir))


def parse_view(data: dict[str, Any], base_dir: str | Path = ".",
               file: str = "<scene>") -> FrameView:
    """One frame's view of a scene dictionary: ``[camera]`` and the optional ``[frame]``
    (background image, depth, timestamp, object transforms)."""
    v = _validator(data, base_dir, file)
    if "camera" not in data:
        raise v.fail("camera", "missing required table")
    view = FrameView(camera=_camera(v, v.table(data["camera"], "camera")))
    if "frame" not in data:
        return view
    tab = v.fields(v.table(data["frame"], "frame"), schema.FRAME_FIELDS, "frame")
    if tab["image"] is not None:
        view.frame, view.frame_codes = _read_frame(v, view.camera, tab["image"])
    if tab["depth"] is not None:
        view.depth = _read_depth(v, view.camera, tab["depth"])
    view.timestamp = tab["timestamp"]
    objects = v.table(tab["object_transforms"], "frame.object_transforms")
    view.object_transforms = {
        name: transform_matrix(v, t, f"frame.object_transforms.{name}")
        for name, t in objects.items()}
    return view


def render_table(v: Validator, tab: Any) -> dict[str, Any]:
    """The validated ``[render]`` table: only the keys it gives (see
    :data:`arlight.scene.schema.RENDER_FIELDS`); ``options`` is a table of scalars."""
    tab = v.table(tab, "render")
    out = v.fields(tab, schema.RENDER_FIELDS, "render")
    if out["max_depth"] == 0:
        raise v.fail("render.max_depth", "must be -1 or >= 1, got 0")
    opts = v.table(out["options"], "render.options")
    for key, x in opts.items():
        if not isinstance(x, str | bool | int | float):
            raise v.fail(f"render.options.{key}", f"expected a string, number or boolean, "
                         f"got {x!r}")
    return {k: x for k, x in out.items() if k in tab}


RENDER_DEFAULTS: dict[str, Any] = {"method": "reference", "spp": 64, "max_depth": 8, "seed": 0}
"""Render settings used when neither the command line nor the scene's ``[render]`` gives
them (documented in :data:`arlight.scene.schema.RENDER_FIELDS`)."""


def read_render_table(path: str | Path) -> dict[str, Any]:
    """The validated ``[render]`` table of a scene file (only the keys it gives), read
    without loading the rest of the scene (so a bad option can fail before any work)."""
    data, path = _read_file(path)
    v = _validator(data, path.parent, str(path))
    return render_table(v, data["render"]) if "render" in data else {}


def render_settings_for(path: str | Path, method: str | None = None, spp: int | None = None,
                        max_depth: int | None = None, seed: int | None = None,
                        options: dict[str, Any] | None = None) -> dict[str, Any]:
    """Render settings for a scene file: what the caller gives (not None) wins over the
    file's ``[render]`` table, which wins over :data:`RENDER_DEFAULTS`. ``options`` merge
    key by key (the caller's win). Returns ``method, spp, max_depth, seed, options``."""
    tab = read_render_table(path)
    given = {"method": method, "spp": spp, "max_depth": max_depth, "seed": seed}
    out = {k: given[k] if given[k] is not None else tab.get(k, RENDER_DEFAULTS[k])
           for k in RENDER_DEFAULTS}
    out["options"] = {**tab.get("options", {}), **(options or {})}
    return out


def with_frame_file(scene: ARScene, path: str | Path) -> ARScene:
    """``scene`` with its background frame replaced by the image at ``path`` (as the
    ``--frame`` option does); read like ``[frame] image``, errors name ``--frame``."""
    p = Path(path)
    if not p.is_file():
        raise InputError("file not found", file=str(p), field="--frame")
    v = Validator(str(p), p.parent.resolve())
    try:
        frame, codes = _read_frame(v, scene.camera, str(p.resolve()))
    except InputError as exc:
        raise InputError(exc.message, file=str(p), field="--frame") from exc
    out = scene.with_frame(frame, codes)
    raw = copy.deepcopy(scene.raw)
    raw.setdefault("frame", {})["image"] = str(p.resolve())
    out.raw = raw
    return out


def _array(v: Validator, data: dict, key: str) -> list[dict]:
    items = data.get(key, [])
    if not isinstance(items, list):
        raise v.fail(key, "expected an array of tables")
    return [v.table(x, f"{key}[{i}]") for i, x in enumerate(items)]


def _camera(v: Validator, tab: dict) -> Camera:
    c = v.fields(tab, schema.CAMERA_FIELDS, "camera")
    w, h = c["resolution"]
    if w != int(w) or h != int(h) or w < 1 or h < 1:
        raise v.fail("camera.resolution", f"expected two positive integers, got {[w, h]}")
    w, h = int(w), int(h)
    if (c["fov_y_deg"] is None) == (c["intrinsics"] is None):
        raise v.fail("camera", "give exactly one of `fov_y_deg` and `intrinsics`")
    if (c["look_at"] is None) == (c["world_from_camera"] is None):
        raise v.fail("camera", "give exactly one of `look_at` and `world_from_camera`")
    if c["look_at"] is not None:
        la = v.table(c["look_at"], "camera.look_at")
        v.check_keys(la, {"origin", "target", "up"}, "camera.look_at")
        for key in ("origin", "target"):
            if key not in la:
                raise v.fail(f"camera.look_at.{key}", "missing required field")
        point = schema.Field("vec3", schema.REQUIRED, min=-schema.MAX_LENGTH,
                             max=schema.MAX_LENGTH)
        origin = v.value(la["origin"], point, "camera.look_at.origin")
        target = v.value(la["target"], point, "camera.look_at.target")
        up = v.vector(la.get("up", [0, 1, 0]), 3, "camera.look_at.up")
        try:
            pose = look_at(origin, target, up)
        except ValueError as exc:
            raise v.fail("camera.look_at", str(exc)) from exc
    else:
        pose = np.array(c["world_from_camera"], dtype=np.float64)
        _check_rigid(v, pose, "camera.world_from_camera")
    kw = dict(world_from_camera=pose, aperture_radius=c["aperture_radius"],
              focus_distance=c["focus_distance"], aperture_shape=c["aperture_shape"],
              transfer=Transfer(c["transfer"], c["gamma"], c["exposure"]))
    if c["intrinsics"] is not None:
        k = v.table(c["intrinsics"], "camera.intrinsics")
        spec = schema.Field("float", schema.REQUIRED, min=0.0, exclusive_min=True, max=1e9)
        centre = schema.Field("float", schema.REQUIRED, min=-1e9, max=1e9)
        f = v.fields(k, {"fx": spec, "fy": spec, "cx": centre, "cy": centre},
                     "camera.intrinsics")
        return Camera(w, h, f["fx"], f["fy"], f["cx"], f["cy"], **kw)
    return Camera.from_fov(w, h, c["fov_y_deg"], **kw)


def _check_rigid(v: Validator, m: np.ndarray, field: str) -> None:
    r = m[:3, :3]
    if not np.allclose(r.T @ r, np.eye(3), atol=1e-5) or np.linalg.det(r) < 0 or \
            not np.allclose(m[3], [0, 0, 0, 1]):
        raise v.fail(field, "must be a rigid transform (rotation + translation)")


def _material(v: Validator, tab: dict, name: str, field: str) -> Material:
    tab = v.table(tab, field)
    mtype = tab.get("type")
    if mtype not in schema.MATERIAL_TYPES:
        raise v.fail(f"{field}.type", f"unknown material type {mtype!r}; expected one of "
                     f"{', '.join(schema.MATERIAL_TYPES)}")
    params = v.fields(tab, schema.MATERIAL_TYPES[mtype], field, extra={"type"})
    check = _MATERIAL_CHECKS.get(mtype)
    if check is not None:
        params = check(v, params, field) or params
    return Material(name=name, type=mtype, params=params)


def _check_texture(v: Validator, p: dict, field: str) -> None:
    """Decode the albedo texture now, so a bad file fails validation, not the render."""
    if not p.get("texture"):
        return
    from arlight.io.images import read_linear

    try:
        img = read_linear(p["texture"])
    except InputError as exc:
        raise v.fail(f"{field}.texture", f"{exc.message} ({p['texture']})") from exc
    if img.ndim != 3 or img.shape[2] != 3 or min(img.shape[:2]) < 1:
        raise v.fail(f"{field}.texture", f"expected an RGB image, got shape {img.shape} "
                     f"({p['texture']})")
    if np.any(img < 0):
        raise v.fail(f"{field}.texture", f"negative values in {p['texture']}")


def _check_phong(v: Validator, p: dict, field: str) -> None:
    if any(a + b > 1.0 + 1e-9 for a, b in zip(p["kd"], p["ks"], strict=True)):
        raise v.fail(f"{field}.ks", "k_d + k_s must not exceed 1 (energy conservation)")


def _finish_pbr(v: Validator, p: dict, field: str) -> dict:
    """Decode the PBR textures now (sizes checked on the headers first)."""
    from arlight.scene.pbr import finish_pbr

    return finish_pbr(v.fail, p, field)


# Checks across fields that a field table cannot express, one entry per material type; a
# check may return the parameters with derived values (decoded textures).
_MATERIAL_CHECKS: dict[str, Callable[[Validator, dict, str], dict | None]] = {
    "phong": _check_phong, "diffuse": _check_texture, "pbr": _finish_pbr}


def _materials(v: Validator, tab: Any) -> dict[str, Material]:
    tab = v.table(tab, "materials")
    out = {"default": Material("default", "diffuse", {"albedo": [0.5] * 3, "texture": None,
                                                      "two_sided": True})}
    for name, m in tab.items():
        out[name] = _material(v, m, name, f"materials.{name}")
    return out


def transform_matrix(v: Validator, tab: Any, field: str) -> np.ndarray:
    """Object-to-world 4×4 from a transform table: translate · rotate_n…rotate_1 · scale."""
    if tab is None:
        return np.eye(4)
    tab = v.table(tab, field)
    v.check_keys(tab, set(schema.TRANSFORM_FIELDS), field)
    if "matrix" in tab:
        if len(tab) > 1:
            raise v.fail(f"{field}.matrix", "`matrix` excludes scale/rotate/translate")
        m = np.array(v.value(tab["matrix"], schema.TRANSFORM_FIELDS["matrix"],
                             f"{field}.matrix"))
        if abs(np.linalg.det(m[:3, :3])) < 1e-12 or not np.allclose(m[3], [0, 0, 0, 1]):
            raise v.fail(f"{field}.matrix", "must be an invertible affine matrix")
        return m
    spec = schema.TRANSFORM_FIELDS
    scale = tab.get("scale", 1.0)
    s = v.value([scale] * 3 if isinstance(scale, int | float) and not isinstance(scale, bool)
                else scale, spec["scale"], f"{field}.scale")
    if any(abs(x) < 1e-6 for x in s):
        raise v.fail(f"{field}.scale", f"scale factors must be at least 1e-6 in magnitude "
                     f"(zero flattens the shape), got {s}")
    m = np.diag([*s, 1.0])
    for path, axis, deg in _rotations(v, tab.get("rotate", []), f"{field}.rotate"):
        m = _rotation(axis, np.radians(deg), v, path) @ m
    t = np.eye(4)
    t[:3, 3] = v.value(tab.get("translate", [0.0, 0.0, 0.0]), spec["translate"],
                       f"{field}.translate")
    return t @ m


def _rotations(v: Validator, rots: Any, field: str) -> list[tuple[str, list[float], float]]:
    """``(field, axis, angle_deg)`` of every rotation in a ``rotate`` value: one
    ``[ax, ay, az, deg]`` or ``{axis, angle}``, or a list of them (applied in order)."""
    if isinstance(rots, dict) or (isinstance(rots, list) and rots
                                  and not isinstance(rots[0], list | dict)):
        items, paths = [rots], [field]
    elif isinstance(rots, list):
        items, paths = rots, [f"{field}[{i}]" for i in range(len(rots))]
    else:
        raise v.fail(field, f"expected [ax, ay, az, angle_deg], {{axis = [...], angle = ...}} "
                     f"or a list of them, got {rots!r}")
    out = []
    for r, path in zip(items, paths, strict=True):
        if isinstance(r, dict):
            v.check_keys(r, {"axis", "angle"}, path)
            for key in ("axis", "angle"):
                if key not in r:
                    raise v.fail(f"{path}.{key}", "missing required field")
            axis = v.vector(r["axis"], 3, f"{path}.axis")
            deg = v.number(r["angle"], f"{path}.angle")
        else:
            *axis, deg = v.vector(r, 4, path)
        out.append((path, axis, deg))
    return out


def _rotation(axis, angle: float, v: Validator | None = None, field: str = "") -> np.ndarray:
    a = np.asarray(axis, dtype=np.float64)
    n = np.linalg.norm(a)
    if n == 0:
        if v is None:
            raise ValueError("zero rotation axis")
        raise v.fail(field, "rotation axis must not be zero")
    a /= n
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    r = np.eye(4)
    r[:3, :3] = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)
    return r


def z_to(normal, v: Validator | None = None, field: str = "") -> np.ndarray:
    """Rotation (4×4) that turns +z onto ``normal`` along the shortest arc."""
    nrm = np.asarray(normal, dtype=np.float64)
    length = np.linalg.norm(nrm)
    if length == 0:
        raise (v.fail(field, "normal must not be zero") if v else ValueError("zero normal"))
    nrm /= length
    c = float(np.clip(nrm[2], -1, 1))
    if c > 1 - 1e-12:
        return np.eye(4)
    if c < -1 + 1e-12:
        return _rotation([1, 0, 0], np.pi)
    return _rotation(np.cross([0, 0, 1], nrm), np.arccos(c))


def _shapes(v: Validator, tab: dict, i: int, materials: dict[str, Material]) -> list[Shape]:
    """The shapes of one ``[[shapes]]`` entry: one, or a model's parts."""
    shape = _shape(v, tab, i, materials)
    if shape.type != "model":
        return [shape]
    from arlight.scene.model_shapes import expand_model

    return expand_model(v, shape, f"shapes[{i}]", own_material="material" in tab)


def _shape(v: Validator, tab: dict, i: int, materials: dict[str, Material]) -> Shape:
    field = f"shapes[{i}]"
    stype = tab.get("type")
    if stype not in schema.SHAPE_TYPES:
        raise v.fail(f"{field}.type", f"unknown shape type {stype!r}; expected one of "
                     f"{', '.join(schema.SHAPE_TYPES)}")
    common = v.fields({k: tab[k] for k in tab if k in schema.SHAPE_COMMON},
                      schema.SHAPE_COMMON, field)
    params = v.fields({k: tab[k] for k in tab if k not in schema.SHAPE_COMMON},
                      schema.SHAPE_TYPES[stype], field)
    name = common["name"] or f"shape{i}"
    mat = common["material"]
    if isinstance(mat, str):
        if mat not in materials:
            raise v.fail(f"{field}.material", f"unknown material {mat!r}; defined: "
                         f"{', '.join(sorted(materials))}")
        material = materials[mat]
    else:
        material = _material(v, mat, f"{name}.material", f"{field}.material")
    to_world = transform_matrix(v, common["transform"], f"{field}.transform")
    if "normal" in params:
        to_world = to_world @ z_to(params["normal"], v, f"{field}.normal")
    mesh = _load_mesh(v, params, field) if stype == "mesh" else None
    if stype == "mesh" and mesh is not None and mesh.uv is None and \
            (tex := _uv_field(material)) is not None:
        raise v.fail(f"{field}.material.{tex}", "the mesh has no texture coordinates")
    return Shape(name=name, role=common["role"], type=stype, params=params,
                 to_world=to_world, material=material, mesh=mesh)


def _uv_field(material: Material) -> str | None:
    """The first texture field of ``material`` (which needs texture coordinates), or None."""
    from arlight.scene.pbr import TEXTURE_FIELDS

    keys = ("texture", *TEXTURE_FIELDS) if material.type != "pbr" else tuple(TEXTURE_FIELDS)
    return next((k for k in keys if material.params.get(k)), None)


def _load_mesh(v: Validator, params: dict, field: str) -> MeshData:
    """Read the mesh file and settle its shading normals (see the ``normals`` field)."""
    from arlight.scene.mesh import read_mesh, unit_normals, vertex_normals

    path = params["file"]
    try:
        raw = read_mesh(path)
    except Exception as exc:
        raise v.fail(f"{field}.file", f"cannot read mesh {path}: {exc}") from exc
    if raw.faces.size == 0:
        raise v.fail(f"{field}.file", f"mesh {path} has no faces")
    if not np.all(np.isfinite(raw.vertices)):
        raise v.fail(f"{field}.file", f"mesh {path} has non-finite vertex positions")
    if raw.faces.min() < 0 or raw.faces.max() >= len(raw.vertices):
        raise v.fail(f"{field}.file", f"mesh {path} has faces indexing missing vertices")
    mode = params["normals"]
    if not params["smooth"]:
        if mode not in ("auto", "flat"):
            raise v.fail(f"{field}.smooth", f"`smooth = false` contradicts `normals = "
                         f"\"{mode}\"`")
        mode = "flat"
    file_normals = None if raw.normals is None else unit_normals(raw.normals)
    if mode == "file" and file_normals is None:
        why = "has no vertex normals" if raw.normals is None else "has zero or non-finite " \
            "vertex normals"
        raise v.fail(f"{field}.normals", f"mesh {path} {why} (use `normals = \"recompute\"`)")
    if mode == "auto":
        mode = "file" if file_normals is not None else "recompute"
    normals = {"file": file_normals, "flat": None}.get(mode) if mode != "recompute" \
        else vertex_normals(raw.vertices, raw.faces)
    return MeshData(raw.vertices.astype(np.float32), raw.faces.astype(np.uint32),
                    None if raw.uv is None else raw.uv.astype(np.float32),
                    None if normals is None else normals.astype(np.float32), mode)


def _light(v: Validator, tab: dict, i: int) -> Light:
    field = f"lights[{i}]"
    ltype = tab.get("type")
    if ltype not in schema.LIGHT_TYPES:
        raise v.fail(f"{field}.type", f"unknown light type {ltype!r}; expected one of "
                     f"{', '.join(schema.LIGHT_TYPES)}")
    params = v.fields(tab, schema.LIGHT_TYPES[ltype], field, extra={"type", "name"})
    finish = _LIGHT_FINISH.get(ltype)
    params, radiance_map = finish(v, params, field) if finish else (params, None)
    return Light(name=tab.get("name", f"light{i}"), type=ltype, params=params,
                 radiance_map=radiance_map)


LightParts = tuple[dict[str, Any], np.ndarray | None]


def _envmap_light(v: Validator, p: dict, field: str) -> LightParts:
    """Reads the map and resamples angular probes to equirect (Mitsuba's layout)."""
    from arlight.io.images import is_hdr_path, read_hdr

    if not is_hdr_path(p["file"]):
        raise v.fail(f"{field}.file", f"an environment map must be an HDR image (EXR or .hdr) "
                     f"of linear radiance, got {p['file']}")
    try:
        img = read_hdr(p["file"])
    except InputError as exc:
        raise v.fail(f"{field}.file", exc.message + f" ({p['file']})") from exc
    if img.ndim != 3 or img.shape[2] != 3:
        raise v.fail(f"{field}.file", f"expected an RGB image, got shape {img.shape} "
                     f"({p['file']})")
    h, w = img.shape[:2]
    if p["mapping"] == "equirect" and w != 2 * h:
        raise v.fail(f"{field}.file", f"an equirect map is twice as wide as high, got {w}×{h} "
                     f"({p['file']}); a square probe needs `mapping = \"angular\"`")
    if p["mapping"] == "angular" and w != h:
        raise v.fail(f"{field}.file", f"an angular map is square, got {w}×{h} ({p['file']})")
    if np.any(img < 0):
        raise v.fail(f"{field}.file", f"negative radiance in {p['file']}")
    if p["mapping"] != "equirect":
        from arlight.sphere.envmap import to_equirect

        img = to_equirect(img, p["mapping"])
    return p, np.ascontiguousarray(img, dtype=np.float32)


def _sh_light(v: Validator, p: dict, field: str) -> LightParts:
    """Renders the SH radiance into an equirect map (negative lobes clamped to 0)."""
    n = len(p["coefficients"])
    if int(round(np.sqrt(n))) ** 2 != n:
        raise v.fail(f"{field}.coefficients", f"expected (L+1)² rows, got {n}")
    from arlight.sphere.sh import sh_to_equirect

    env = sh_to_equirect(np.array(p["coefficients"]), p["resolution"])
    return p, np.maximum(env, 0).astype(np.float32)


def _directional_light(v: Validator, p: dict, field: str) -> LightParts:
    if np.linalg.norm(p["direction"]) == 0:
        raise v.fail(f"{field}.direction", "direction must not be zero")
    return p, None


def _spot_light(v: Validator, p: dict, field: str) -> LightParts:
    if p["beam_width_deg"] > p["cutoff_deg"]:
        raise v.fail(f"{field}.beam_width_deg", "must not exceed cutoff_deg")
    return p, None


def _area_light(v: Validator, p: dict, field: str) -> LightParts:
    """Adds ``to_world``: the transform times the rotation of +z onto ``normal``."""
    m = transform_matrix(v, p["transform"], f"{field}.transform")
    return {**p, "to_world": m @ z_to(p["normal"], v, f"{field}.normal")}, None


# What a light type needs beyond its field table (files, cross-field checks, derived
# values), one entry per light type; types without an entry need nothing more.
_LIGHT_FINISH: dict[str, Callable[[Validator, dict, str], LightParts]] = {
    "envmap": _envmap_light, "sh": _sh_light, "directional": _directional_light,
    "spot": _spot_light, "area": _area_light,
}


def _read_frame(v: Validator, cam: Camera, path: str) -> tuple[np.ndarray,
                                                              np.ndarray | None]:
    """The frame as linear radiance and, for LDR files, its raw code values."""
    from arlight.io.images import is_hdr_path, read_hdr, read_ldr

    try:
        if is_hdr_path(path):
            codes, frame = None, read_hdr(path)
        else:
            codes = read_ldr(path)
            frame = cam.transfer.to_radiance(codes).astype(np.float32)
    except InputError as exc:
        raise v.fail("frame.image", f"{exc.message} ({path})") from exc
    if frame.shape[:2] != (cam.height, cam.width):
        raise v.fail("frame.image", f"image is {frame.shape[1]}×{frame.shape[0]} but the camera "
                     f"resolution is {cam.width}×{cam.height} ({path})")
    if np.any(frame < 0):
        raise v.fail("frame.image", f"negative radiance in {path}")
    return frame.astype(np.float32), codes


def _read_depth(v: Validator, cam: Camera, path: str) -> np.ndarray:
    from arlight.io.images import read_depth

    try:
        depth = read_depth(path)
    except InputError as exc:
        raise v.fail("frame.depth", f"{exc.message} ({path})") from exc
    if depth.shape != (cam.height, cam.width):
        raise v.fail("frame.depth", f"depth is {depth.shape[1]}×{depth.shape[0]} but the camera "
                     f"resolution is {cam.width}×{cam.height} ({path})")
    return depth


def _canonical_raw(data: dict, base_dir: Path) -> dict:
    """A copy of the scene dict with relative paths made absolute (for saving elsewhere)."""

    def fix(node: Any, key: str = "") -> Any:
        if isinstance(node, dict):
            return {k: fix(x, k) for k, x in node.items()}
        if isinstance(node, list):
            return [fix(x) for x in node]
        if key in PATH_KEYS and isinstance(node, str):
            p = Path(node)
            return str(p if p.is_absolute() else (base_dir / p).resolve())
        return node

    return fix(data)
