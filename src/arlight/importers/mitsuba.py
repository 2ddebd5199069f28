"""Import a Mitsuba 3 XML scene as an arlight world (``arlight import-mitsuba``).

The XML is loaded by Mitsuba's own loader (:func:`mitsuba.load_file`: includes, defaults,
``ref`` s, transforms and file formats are resolved exactly as Mitsuba resolves them) and the
loaded objects are translated:

* **shapes** — ``rectangle``, ``disk``, ``sphere`` become our primitives with the unit size
  of Mitsuba's canonical shape (rectangle ``size = [2, 2]``, disk and sphere ``radius = 1``)
  and Mitsuba's ``to_world`` as ``transform = { matrix = ... }``; every triangle mesh
  (``ply``, ``obj``, ``serialized``, ``cube``, ...) is written as a binary PLY next to the world
  (world-space positions, faces and — when the mesh has them — vertex normals, kept as
  ``normals = "file"``; meshes without vertex normals get ``normals = "flat"``, as Mitsuba
  renders them).
* **BSDFs** — ``diffuse`` (constant RGB) → ``diffuse``; ``conductor`` / ``roughconductor``
  (``material = "none"``; GGX) → ``mirror`` / ``roughconductor``; ``dielectric`` /
  ``roughdielectric`` (GGX) → ``glass`` / ``roughdielectric`` with ``ior`` = Mitsuba's
  ``int_ior / ext_ior`` and ``ext_ior = 1`` (the ratio is all Mitsuba keeps and uses);
  ``twosided`` → ``two_sided = true``, a bare opaque BSDF → ``two_sided = false``.
* **emitters** — ``envmap`` (rotations about +Y only; its pixels are written as an EXR next to
  the world), ``constant``, ``point``, ``directional``, and ``area`` on a ``rectangle``
  (an arlight area light; its shape's BSDF is dropped — arlight's area lights are black).
* **sensor** — ``perspective`` / ``thinlens``: resolution, OpenCV intrinsics (square pixels,
  principal point from Mitsuba's offsets) and ``world_from_camera`` (Mitsuba's ``to_world``
  with x and y flipped); the integrator's ``max_depth`` and the sampler's ``sample_count``
  go to ``[render]``.

Anything else (other plugins, textured reflectances, metals with a measured ``material``,
Beckmann roughness, ...) raises :class:`InputError` naming the XML file and the element
(``shape "id"``, ``bsdf of shape "id"``, ``emitter ...``). Roles come from a list of names or
globs (``virtual``): matching shapes are virtual, the rest real; a pattern that matches no
shape is an error.
"""

from __future__ import annotations

import fnmatch
import math
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from arlight.errors import InputError

# Mitsuba class names -> plugin names, for messages naming the XML element.
_PLUGIN_OF_CLASS = {
    "SmoothDiffuse": "diffuse", "SmoothConductor": "conductor",
    "RoughConductor": "roughconductor", "SmoothDielectric": "dielectric",
    "RoughDielectric": "roughdielectric", "TwoSided": "twosided", "TwoSidedBRDF": "twosided",
    "SmoothPlastic": "plastic",
    "RoughPlastic": "roughplastic", "Principled": "principled", "ThinDielectric":
    "thindielectric", "BlendBSDF": "blendbsdf", "MaskBSDF": "mask", "Null": "null",
    "EnvironmentMapEmitter": "envmap", "ConstantBackgroundEmitter": "constant",
    "PointLight": "point", "DirectionalEmitter": "directional", "SpotLight": "spot",
    "AreaLight": "area", "PerspectiveCamera": "perspective", "ThinLensCamera": "thinlens",
}


class _Importer:
    """Translates one loaded Mitsuba scene; ``fail`` errors name the XML file."""

    def __init__(self, xml: Path, out: Path):
        self.xml, self.out = xml, out
        self.stem = out.stem
        self.files: dict[str, Any] = {}  # file name -> ("ply", arrays) | ("exr", image)

    def fail(self, element: str, message: str) -> InputError:
        return InputError(message, file=str(self.xml), field=element)

    # ------------------------------------------------------------------ helpers
    @staticmethod
    def params(obj) -> dict[str, Any]:
        import mitsuba as mi

        p = mi.traverse(obj)
        return {k: p[k] for k in p.keys()}

    @staticmethod
    def rgb(value) -> list[float]:
        a = np.array(value, dtype=np.float64).ravel()
        return [float(a[0])] * 3 if a.size == 1 else [float(x) for x in a[:3]]

    @staticmethod
    def scalar(value) -> float:
        return float(np.array(value, dtype=np.float64).ravel()[0])

    @staticmethod
    def matrix(t) -> np.ndarray:
        return np.array(t.matrix, dtype=np.float64).reshape(4, 4)

    @staticmethod
    def plugin(obj) -> str:
        name = obj.class_name()
        return _PLUGIN_OF_CLASS.get(name, name)

    # ------------------------------------------------------------------- BSDFs
    def material(self, bsdf, element: str) -> dict[str, Any]:
        """Our material table for a Mitsuba BSDF (see the module docstring)."""
        cls = bsdf.class_name()
        p = self.params(bsdf)
        two_sided = cls in ("TwoSided", "TwoSidedBRDF")
        if two_sided:
            if any(k.startswith("brdf_1.") for k in p):
                raise self.fail(element, "a twosided BSDF with two different sides has no "
                                "arlight equivalent")
            m = re.search(r"brdf\[0\]\s*=\s*(\w+)\[", str(bsdf))
            cls = m.group(1) if m else "?"
            p = {k.removeprefix("brdf_0."): v for k, v in p.items()}
        text = str(bsdf)
        if cls in ("RoughConductor", "RoughDielectric"):
            dist = re.search(r"distribution\s*=\s*(\w+)", text)
            if dist is None or dist.group(1) != "ggx":
                raise self.fail(element, f"<bsdf type=\"{_PLUGIN_OF_CLASS[cls]}\"> with "
                                f"{dist.group(1) if dist else 'an unknown'} distribution: "
                                "arlight's rough materials are GGX (set distribution=\"ggx\")")
            if "alpha_u.value" in p or "alpha_v.value" in p:
                raise self.fail(element, "anisotropic roughness (alpha_u != alpha_v) is not "
                                "supported")
        if cls in ("SmoothConductor", "RoughConductor"):
            eta, k = p.get("eta.value", [0.0]), p.get("k.value", [1.0])
            if any(abs(x) > 0 for x in self.rgb(eta)) or any(abs(x - 1) > 0 for x in
                                                             self.rgb(k)):
                raise self.fail(element, f"<bsdf type=\"{_PLUGIN_OF_CLASS[cls]}\"> with a "
                                "measured metal: arlight's conductors have a constant "
                                "reflectance (use material=\"none\" and "
                                "specular_reflectance)")
            refl = self.rgb(p.get("specular_reflectance.value", [1.0]))
            out: dict[str, Any] = {"type": "mirror", "reflectance": refl}
            if cls == "RoughConductor":
                out = {"type": "roughconductor", "alpha": self.scalar(p["alpha.value"]),
                       "reflectance": refl}
            return {**out, "two_sided": two_sided}
        if cls == "SmoothDiffuse":
            if "reflectance.value" not in p:
                raise self.fail(element, "<bsdf type=\"diffuse\"> with a textured reflectance "
                                "is not supported by the importer (give an <rgb>)")
            return {"type": "diffuse", "albedo": self.rgb(p["reflectance.value"]),
                    "two_sided": two_sided}
        if cls in ("SmoothDielectric", "RoughDielectric"):
            if two_sided:
                raise self.fail(element, "a dielectric inside twosided is not supported")
            for key in ("specular_reflectance.value", "specular_transmittance.value"):
                if key in p and any(abs(x - 1) > 0 for x in self.rgb(p[key])):
                    raise self.fail(element, f"dielectric {key.split('.')[0]} other than 1 is "
                                    "not supported")
            eta = self.scalar(p["eta"])
            if cls == "SmoothDielectric":
                return {"type": "glass", "ior": eta, "ext_ior": 1.0}
            return {"type": "roughdielectric", "alpha": self.scalar(p["alpha.value"]),
                    "ior": eta, "ext_ior": 1.0}
        raise self.fail(element, f"<bsdf type=\"{_PLUGIN_OF_CLASS.get(cls, cls)}\"> has no "
                        "arlight equivalent (supported: diffuse, conductor, roughconductor, "
                        "dielectric, roughdielectric, twosided)")

    # ------------------------------------------------------------------ shapes
    def shape(self, sh, name: str, role: str) -> dict[str, Any]:
        import mitsuba as mi

        element = f"shape \"{name}\""
        kind = sh.shape_type()
        p = self.params(sh)
        material = self.material(sh.bsdf(), f"bsdf of {element}")
        prims = {mi.ShapeType.Rectangle: ("rectangle", {"size": [2.0, 2.0]}),
                 mi.ShapeType.Disk: ("disk", {"radius": 1.0}),
                 mi.ShapeType.Sphere: ("sphere", {"radius": 1.0})}
        base = {"name": name, "role": role}
        if kind in prims:
            if sh.has_flipped_normals() if hasattr(sh, "has_flipped_normals") else False:
                raise self.fail(element, "flip_normals on a primitive is not supported")
            stype, size = prims[kind]
            return {**base, "type": stype, **size, "material": material,
                    "transform": {"matrix": self.matrix(p["to_world"]).tolist()}}
        if not sh.is_mesh():
            raise self.fail(element, f"<shape type=\"{sh.class_name().lower()}\"> has no "
                            "arlight equivalent (supported: rectangle, disk, sphere, cube and "
                            "triangle meshes)")
        v = np.array(p["vertex_positions"], dtype=np.float32).reshape(-1, 3)
        f = np.array(p["faces"], dtype=np.uint32).reshape(-1, 3)
        n = None
        if sh.has_vertex_normals():
            n = np.array(p["vertex_normals"], dtype=np.float32).reshape(-1, 3)
        if sh.has_flipped_normals():
            f = f[:, ::-1].copy()
            n = None if n is None else -n
        file = f"{self.stem}.{_safe(name)}.ply"
        self.files[file] = ("ply", (v, f, n))
        return {**base, "type": "mesh", "file": file,
                "normals": "file" if n is not None else "flat", "material": material}

    def area_light(self, sh, name: str) -> dict[str, Any]:
        import mitsuba as mi

        element = f"emitter of shape \"{name}\""
        if sh.shape_type() != mi.ShapeType.Rectangle:
            raise self.fail(element, "area emitters are supported on rectangles only "
                            "(arlight's area lights are rectangles)")
        p = self.params(sh.emitter())
        if "radiance.value" not in p:
            raise self.fail(element, "a textured area emitter is not supported")
        return {"name": name, "type": "area", "size": [2.0, 2.0],
                "radiance": self.rgb(p["radiance.value"]),
                "transform": {"matrix": self.matrix(self.params(sh)["to_world"]).tolist()}}

    # ----------------------------------------------------------------- emitters
    def emitter(self, em, i: int) -> dict[str, Any] | None:
        cls = em.class_name()
        element = f"emitter {i} (<emitter type=\"{self.plugin(em)}\">)"
        p = self.params(em)
        if cls == "AreaLight":
            return None  # translated with its shape
        if cls == "EnvironmentMapEmitter":
            m = self.matrix(p["to_world"])[:3, :3]
            angle = math.degrees(math.atan2(m[0, 2], m[0, 0]))
            want = np.array([[math.cos(math.radians(angle)), 0, math.sin(math.radians(angle))],
                             [0, 1, 0],
                             [-math.sin(math.radians(angle)), 0,
                              math.cos(math.radians(angle))]])
            if not np.allclose(m, want, atol=1e-5):
                raise self.fail(element, "envmap to_world must be a rotation about +Y "
                                "(arlight's rotation_deg)")
            data = np.array(p["data"], dtype=np.float32)
            img = np.ascontiguousarray(data[:, 1:-1, :3])  # Mitsuba pads one wrap column
            file = f"{self.stem}.envmap{i}.exr"
            self.files[file] = ("exr", img)
            return {"type": "envmap", "file": file, "mapping": "equirect",
                    "scale": self.scalar(p["scale"]), "rotation_deg": angle}
        if cls == "ConstantBackgroundEmitter" and "radiance.value" in p:
            return {"type": "constant", "radiance": self.rgb(p["radiance.value"])}
        if cls == "PointLight" and "intensity.value" in p:
            return {"type": "point", "position": self.rgb(p["position"]),
                    "intensity": self.rgb(p["intensity.value"])}
        if cls == "DirectionalEmitter" and "irradiance.value" in p:
            d = self.matrix(p["to_world"])[:3, :3] @ np.array([0.0, 0.0, 1.0])
            return {"type": "directional", "direction": d.tolist(),
                    "irradiance": self.rgb(p["irradiance.value"])}
        raise self.fail(element, "has no arlight equivalent (supported: envmap, constant, "
                        "point, directional, area on a rectangle; no textured emitters)")

    # ------------------------------------------------------------------- sensor
    def camera(self, sensor) -> dict[str, Any]:
        cls = sensor.class_name()
        element = f"sensor (<sensor type=\"{self.plugin(sensor)}\">)"
        if cls not in ("PerspectiveCamera", "ThinLensCamera"):
            raise self.fail(element, "only perspective and thinlens sensors are supported")
        p = self.params(sensor)
        w, h = (int(x) for x in sensor.film().size())
        fov = self.scalar(p["x_fov"])
        if not (math.isfinite(fov) and 0 < fov < 180):
            raise self.fail(f"{element}.fov", f"expected a horizontal field of view in "
                            f"(0, 180) degrees, got {fov}")
        fx = 0.5 * w / math.tan(math.radians(fov) / 2)
        pose = self.matrix(p["to_world"]) @ np.diag([-1.0, -1.0, 1.0, 1.0])
        r = pose[:3, :3]
        if not np.allclose(r.T @ r, np.eye(3), atol=1e-5) or np.linalg.det(r) < 0:
            raise self.fail(element, "the sensor's to_world must be rigid (rotation and "
                            "translation)")
        cam: dict[str, Any] = {"resolution": [w, h],
                               "intrinsics": {"fx": fx, "fy": fx, "cx": w / 2, "cy": h / 2},
                               "world_from_camera": pose.tolist()}
        if cls == "ThinLensCamera":
            cam["aperture_radius"] = self.scalar(p["aperture_radius"])
            cam["focus_distance"] = self.scalar(p["focus_distance"])
        else:
            cam["intrinsics"]["cx"] = w / 2 - self.scalar(p["principal_point_offset_x"]) * w
            cam["intrinsics"]["cy"] = h / 2 - self.scalar(p["principal_point_offset_y"]) * h
        return cam


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]", "_", name) or "shape"


def _write_ply(path: Path, v: np.ndarray, f: np.ndarray, n: np.ndarray | None) -> None:
    """Binary PLY through trimesh (vertices in file order, unmerged; ``nx ny nz`` when ``n``
    is given, as :func:`arlight.scene.mesh.read_mesh` reads them back)."""
    import trimesh

    from arlight.io.images import atomic_write

    mesh = trimesh.Trimesh(v, f, vertex_normals=n, process=False)
    data = trimesh.exchange.ply.export_ply(mesh, encoding="binary", vertex_normal=n is not None)
    with atomic_write(path, ".ply") as tmp:
        tmp.write_bytes(data)


def xml_references(xml: Path) -> list[Path]:
    """The files a Mitsuba XML scene makes the loader read: ``xml``, its ``<include>`` s
    (recursively) and every ``filename`` string (meshes, textures, environment maps),
    resolved relative to the file naming them (``$name`` parameters from ``<default>``).
    Only the ones that exist are returned; best effort (an unparsable XML: just ``xml``)."""
    import xml.etree.ElementTree as ET

    seen: list[Path] = []
    todo = [Path(xml)]
    while todo:
        f = todo.pop()
        if f in seen or len(seen) > 10000:
            continue
        seen.append(f)
        try:
            root = ET.parse(f).getroot()
        except (OSError, ET.ParseError, ValueError):
            continue
        defaults = {e.get("name", ""): e.get("value", "") for e in root.iter("default")}

        def subst(v: str, defaults=defaults) -> str:
            return re.sub(r"\$(\w+)", lambda m: defaults.get(m.group(1), m.group(0)), v)

        for e in root.iter():
            name = None
            if e.tag == "include" and e.get("filename"):
                name = e.get("filename")
            elif e.tag == "string" and e.get("name") == "filename" and e.get("value"):
                name = e.get("value")
            if not name:
                continue
            q = Path(subst(name))
            q = q if q.is_absolute() else f.parent / q
            if q.is_file():
                (todo if e.tag == "include" else seen).append(q)
    return list(dict.fromkeys(seen))


# Memory of loading and translating a scene, per byte of a referenced mesh file (Mitsuba's
# arrays, our float64 copies, the PLY bytes being written) and per pixel of an image
# (float32 RGBA in Mitsuba, float32 RGB copy, the EXR being written).
BYTES_PER_MESH_FILE_BYTE = 8.0
BYTES_PER_IMAGE_PIXEL = 48.0


def import_estimate(files: Sequence[Path]):
    """The memory/time :class:`~arlight.bounds.Estimate` of importing a scene that reads
    ``files`` (sizes from the file system and the image headers; nothing is decoded)."""
    from arlight.bounds import image_size, work_estimate

    mem = 0.0
    for f in files:
        size = image_size(f) if f.suffix.lower() in _IMAGE_SUFFIXES else None
        try:
            nbytes = float(f.stat().st_size)
        except OSError:
            nbytes = 0.0
        mem += (BYTES_PER_IMAGE_PIXEL * size[0] * size[1] if size
                else BYTES_PER_MESH_FILE_BYTE * nbytes)
    return work_estimate(mem, operations=mem / 8, output_bytes=mem / 4)


_IMAGE_SUFFIXES = {".exr", ".hdr", ".pfm", ".png", ".jpg", ".jpeg", ".tga", ".bmp", ".ppm",
                   ".tif", ".tiff", ".rgbe"}


def _check_finite(node: Any, where: str, xml: Path) -> None:
    """Every number of the translated world is finite (a NaN ``fov`` would otherwise reach
    the world file)."""
    if isinstance(node, dict):
        for k, v in node.items():
            _check_finite(v, f"{where}.{k}" if where else str(k), xml)
    elif isinstance(node, list | tuple):
        for i, v in enumerate(node):
            _check_finite(v, f"{where}[{i}]", xml)
    elif isinstance(node, float) and not math.isfinite(node):
        raise InputError(f"is {node} after translation: every number of the scene must be "
                         "finite", file=str(xml), field=where)


def import_mitsuba(xml: str | Path, out: str | Path, virtual: Sequence[str] = (),
                   overwrite: bool = False, force: bool = False) -> Path:
    """Translate the Mitsuba 3 XML scene ``xml`` into the arlight world file ``out``.

    Args:
        xml: the Mitsuba scene file (loaded with :func:`mitsuba.load_file`).
        out: the ``.toml`` world to write; meshes (``<stem>.<shape>.ply``) and environment
            maps (``<stem>.envmap<i>.exr``) are written next to it, the TOML last.
        virtual: shape ids (or shell globs on them) that become virtual shapes; all others
            are real. A pattern matching no shape raises :class:`InputError`.
        overwrite: replace existing files arlight did not write (never an input: the XML
            or a file it references).
        force: run even when the memory/time estimate is beyond the bounds.

    Every output (the TOML and each side file) is checked before any work
    (:func:`arlight.output_guard.check_outputs`): none may be the XML or a file it
    references, and an existing one must be a file arlight wrote (unless ``overwrite``).
    The files are written into a staging folder next to ``out``, the world loaded back from
    there (validated), and only then moved into place (side files first, the TOML last).

    Returns:
        The path of the world file.
    """
    import os
    import shutil
    import tempfile

    from arlight.bounds import check_estimate
    from arlight.io.images import write_exr
    from arlight.jit import ensure_variant
    from arlight.output_guard import check_outputs, record_written
    from arlight.scene.load import load_scene
    from arlight.scene.save import to_toml

    xml, out = Path(xml), Path(out)
    if xml.is_dir():
        raise InputError("is a folder, expected a Mitsuba XML file", file=str(xml),
                         field="XML")
    if not xml.is_file():
        raise InputError("file not found", file=str(xml))
    inputs = xml_references(xml)
    check_outputs({"-o": out}, inputs, overwrite=overwrite)
    check_estimate(import_estimate(inputs), f"importing {xml.name}", force,
                   lower="the referenced meshes and images", field="XML")
    ensure_variant()
    import mitsuba as mi

    try:
        scene = mi.load_file(str(xml))
    except Exception as exc:  # Mitsuba's own message names the line and element
        lines = [x.strip() for x in str(exc).splitlines() if x.strip()]
        raise InputError(f"Mitsuba cannot load the scene: {' '.join(lines)[:400]}",
                         file=str(xml)) from exc
    imp = _Importer(xml, out)
    names: list[str] = []
    for i, sh in enumerate(scene.shapes()):
        base = _safe(sh.id()) if sh.id() else f"shape{i}"
        name, k = base, 1
        while name in names:
            k += 1
            name = f"{base}_{k}"
        names.append(name)
    unmatched = [pat for pat in virtual if not any(fnmatch.fnmatchcase(n, pat) for n in names)]
    if unmatched:
        raise InputError(f"no shape matches {unmatched[0]!r}; shapes: {', '.join(names)}",
                         field="--virtual")
    shapes, lights = [], []
    for sh, name in zip(scene.shapes(), names, strict=True):
        if sh.is_emitter():
            lights.append(imp.area_light(sh, name))
            continue
        role = "virtual" if any(fnmatch.fnmatchcase(name, p) for p in virtual) else "real"
        shapes.append(imp.shape(sh, name, role))
    for i, em in enumerate(scene.emitters()):
        light = imp.emitter(em, i)
        if light is not None:
            lights.append(light)
    sensors = scene.sensors()
    if not sensors:
        raise InputError("the scene has no sensor", file=str(xml), field="sensor")
    data: dict[str, Any] = {"format": "arlight-scene/1",
                            "description": f"imported from {xml.name} by arlight "
                                           "import-mitsuba",
                            "camera": imp.camera(sensors[0])}
    render: dict[str, Any] = {}
    integrator = scene.integrator()
    if integrator is not None and integrator.class_name() == "PathIntegrator":
        m = re.search(r"max_depth\s*=\s*(-?\d+)", str(integrator))
        if m:
            render["max_depth"] = int(m.group(1))
    spp = sensors[0].sampler().sample_count()
    if spp:
        render["spp"] = int(spp)
    data["shapes"] = shapes
    data["lights"] = lights
    if render:
        data["render"] = render
    _check_finite(data, "", xml)
    for file, (kind, payload) in imp.files.items():
        arrays = payload[:1] if kind == "ply" else (payload,)
        if not all(np.all(np.isfinite(a)) for a in arrays):
            raise InputError("holds non-finite numbers (NaN/Inf)", file=str(xml),
                             field=f"{'mesh' if kind == 'ply' else 'envmap'} {file}")
    folder = out.parent
    side = [folder / file for file in imp.files]
    check_outputs({"-o": out, "side file": side}, inputs, overwrite=overwrite)
    folder.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-{os.getpid()}-", dir=folder))
    try:
        for file, (kind, payload) in imp.files.items():
            if kind == "ply":
                _write_ply(staging / file, *payload)
            else:
                write_exr(staging / file, payload)
        (staging / out.name).write_text(to_toml(data), encoding="utf-8")
        try:
            load_scene(staging / out.name)  # what we wrote must load
        except InputError as exc:  # name the XML, not the staging copy
            raise InputError(f"the translated world is not valid: {exc.message}",
                             file=str(xml), field=exc.field) from exc
        for file in imp.files:
            os.replace(staging / file, folder / file)
        os.replace(staging / out.name, out)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    record_written([*side, out])
    return out
