"""glTF 2.0 (``.gltf`` + ``.bin``/images, or binary ``.glb``) to :class:`ModelPart` s.

Conventions (glTF 2.0 §3.4): metres, right-handed, +Y up, the front of an asset faces +Z —
the same as arlight's world, so positions are used as they are after the node hierarchy's
transforms (each node: ``matrix``, or ``translation · rotation · scale``) are flattened.
A node whose world matrix has a negative determinant has its triangles' winding reversed
(glTF §3.7.4). Texture coordinates keep glTF's origin (top-left, the first image row at
v = 0), which is Mitsuba's.

The JSON is parsed by ``pygltflib``; accessors are decoded here with NumPy. Before any
buffer is decoded the triangle count (from the accessors' ``count``) and the texture sizes
(from the images' headers) are checked against the limits of :mod:`.part` and
:mod:`arlight.scene.pbr`.

Supported extensions: ``KHR_materials_ior``, ``KHR_materials_transmission``,
``KHR_materials_emissive_strength``. Refused (an error naming the extension):
``KHR_draco_mesh_compression``, ``EXT_meshopt_compression``, ``KHR_texture_basisu`` (KTX2),
``KHR_mesh_quantization`` and any other *required* extension. Skins, morph targets and
animations are not applied: the static (bind, base) pose is loaded with a
:class:`~.part.ModelWarning`.
"""

from __future__ import annotations

import base64
from pathlib import Path
from typing import Any

import numpy as np

from arlight.scene import pbr
from arlight.scene.models.part import MAX_TRIANGLES, Model, ModelError, ModelPart, warn

SUPPORTED_EXTENSIONS = frozenset({"KHR_materials_ior", "KHR_materials_transmission",
                                  "KHR_materials_emissive_strength"})
REFUSED_EXTENSIONS = {
    "KHR_draco_mesh_compression": "Draco-compressed geometry",
    "EXT_meshopt_compression": "meshopt-compressed buffers",
    "KHR_texture_basisu": "KTX2 / Basis Universal textures",
    "KHR_mesh_quantization": "quantized vertex attributes",
}
"""Extensions arlight cannot decode -> what they hold (the error message names both)."""

_COMPONENTS = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16,
               5125: np.uint32, 5126: np.float32}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}


class _Reader:
    """One glTF document: buffers, accessors, textures and materials, decoded on demand."""

    def __init__(self, path: Path, model: Model):
        import pygltflib

        self.path = path
        self.file = str(path)
        self.model = model
        try:
            self.doc = pygltflib.GLTF2().load(str(path))
        except Exception as exc:  # pygltflib raises many kinds for garbage
            raise ModelError(f"not a readable glTF 2.0 file ({exc})", "asset") from exc
        if self.doc is None:
            raise ModelError("not a readable glTF 2.0 file", "asset")
        version = getattr(self.doc.asset, "version", None) or ""
        if not str(version).startswith("2."):
            raise ModelError(f"glTF version {version!r}; only 2.x is read", "asset.version")
        self._buffers: dict[int, bytes] = {}
        self._textures: dict[tuple[int, str], pbr.Texture] = {}

    # ---- extensions -----------------------------------------------------------------
    def check_extensions(self) -> None:
        d = self.doc
        for i, mesh in enumerate(d.meshes or []):
            for j, prim in enumerate(mesh.primitives or []):
                for ext in (prim.extensions or {}):
                    if ext in REFUSED_EXTENSIONS:
                        raise ModelError(f"{ext} ({REFUSED_EXTENSIONS[ext]}) is not "
                                         "supported; decompress the file first (e.g. "
                                         "`gltf-transform copy`)",
                                         f"meshes[{i}].primitives[{j}].extensions.{ext}")
        for j, tex in enumerate(d.textures or []):
            for ext in (tex.extensions or {}):
                if ext in REFUSED_EXTENSIONS:
                    raise ModelError(f"{ext} ({REFUSED_EXTENSIONS[ext]}) is not supported; "
                                     "convert the textures to PNG or JPEG",
                                     f"textures[{j}].extensions.{ext}")
        for ext in d.extensionsRequired or []:
            if ext in REFUSED_EXTENSIONS:
                raise ModelError(f"{ext} ({REFUSED_EXTENSIONS[ext]}) is not supported",
                                 "extensionsRequired")
            if ext not in SUPPORTED_EXTENSIONS:
                raise ModelError(f"required extension {ext} is not supported (supported: "
                                 f"{', '.join(sorted(SUPPORTED_EXTENSIONS))})",
                                 "extensionsRequired")
        ignored = sorted(set(d.extensionsUsed or []) - SUPPORTED_EXTENSIONS)
        if ignored:
            warn(self.model, self.file, "extensionsUsed",
                 f"ignored optional extension(s) {', '.join(ignored)}")
        if d.animations:
            warn(self.model, self.file, "animations",
                 f"{len(d.animations)} animation(s) not applied; the static pose is loaded")

    # ---- buffers and accessors --------------------------------------------------------
    def buffer(self, i: int) -> bytes:
        if i in self._buffers:
            return self._buffers[i]
        buf = self.doc.buffers[i]
        uri = buf.uri
        if uri is None:
            data = self.doc.binary_blob()
            if data is None:
                raise ModelError("no GLB binary chunk for a buffer without uri",
                                 f"buffers[{i}]")
        else:
            data = self._uri_bytes(uri, f"buffers[{i}].uri")
        if len(data) < (buf.byteLength or 0):
            raise ModelError(f"{len(data)} bytes, fewer than byteLength {buf.byteLength}",
                             f"buffers[{i}]")
        self._buffers[i] = data
        return data

    def _uri_bytes(self, uri: str, field: str) -> bytes:
        if uri.startswith("data:"):
            try:
                return base64.b64decode(uri.split(",", 1)[1])
            except Exception as exc:
                raise ModelError(f"bad data URI ({exc})", field) from exc
        from urllib.parse import unquote

        p = (self.path.parent / unquote(uri)).resolve()
        if not p.is_file():
            raise ModelError(f"file not found: {p}", field)
        return p.read_bytes()

    def view_bytes(self, i: int, field: str) -> tuple[bytes, int, int | None]:
        """(buffer bytes, offset of the view, byteStride) of bufferView ``i``."""
        views = self.doc.bufferViews or []
        if not 0 <= i < len(views):
            raise ModelError(f"bufferView {i} does not exist", field)
        v = views[i]
        data = self.buffer(v.buffer)
        if (v.byteOffset or 0) + v.byteLength > len(data):
            raise ModelError("bufferView runs past its buffer", f"bufferViews[{i}]")
        return data, v.byteOffset or 0, v.byteStride

    def accessor(self, i: int) -> np.ndarray:
        """Accessor ``i`` as ``(count, width)`` float64 (normalized integers scaled to
        [0, 1] / [-1, 1]) or ``(count,)`` for scalars."""
        field = f"accessors[{i}]"
        acc = (self.doc.accessors or [])[i] if 0 <= i < len(self.doc.accessors or []) else None
        if acc is None:
            raise ModelError(f"accessor {i} does not exist", field)
        if acc.sparse is not None:
            raise ModelError("sparse accessors are not supported", f"{field}.sparse")
        dtype = _COMPONENTS.get(acc.componentType)
        width = _WIDTH.get(acc.type)
        if dtype is None or width is None:
            raise ModelError(f"unknown componentType {acc.componentType} / type {acc.type}",
                             field)
        item = np.dtype(dtype).itemsize * width
        if acc.bufferView is None:
            out = np.zeros((acc.count, width))
        else:
            data, base, stride = self.view_bytes(acc.bufferView, f"{field}.bufferView")
            start = base + (acc.byteOffset or 0)
            stride = stride or item
            end = start + stride * (acc.count - 1) + item if acc.count else start
            if end > len(data):
                raise ModelError("accessor runs past its buffer", field)
            raw = np.frombuffer(data, np.uint8, count=end - start, offset=start)
            if stride == item:
                arr = raw[: acc.count * item].view(dtype).reshape(acc.count, width)
            else:
                rows = np.lib.stride_tricks.as_strided(raw, (acc.count, item), (stride, 1))
                arr = np.ascontiguousarray(rows).view(dtype).reshape(acc.count, width)
            out = arr.astype(np.float64)
            if acc.normalized and dtype != np.float32:
                info = np.iinfo(dtype)
                out = np.maximum(out / info.max, -1.0)
        return out[:, 0] if width == 1 else out

    # ---- textures and materials ----------------------------------------------------------
    def image_bytes(self, j: int) -> bytes:
        img = self.doc.images[j]
        if img.bufferView is not None:
            data, base, _ = self.view_bytes(img.bufferView, f"images[{j}].bufferView")
            length = self.doc.bufferViews[img.bufferView].byteLength
            return data[base: base + length]
        if img.uri is None:
            raise ModelError("image has neither uri nor bufferView", f"images[{j}]")
        return self._uri_bytes(img.uri, f"images[{j}].uri")

    def texture(self, info: Any, encoding: str, field: str) -> pbr.Texture | None:
        if info is None:
            return None
        if (getattr(info, "texCoord", 0) or 0) != 0:
            raise ModelError("only TEXCOORD_0 is supported", f"{field}.texCoord")
        if getattr(info, "extensions", None) and "KHR_texture_transform" in info.extensions:
            warn(self.model, self.file, f"{field}.extensions.KHR_texture_transform",
                 "texture transform not applied")
        t = info.index
        key = (t, encoding)
        if key not in self._textures:
            textures = self.doc.textures or []
            if not 0 <= t < len(textures) or textures[t].source is None:
                raise ModelError(f"texture {t} has no image source", f"{field}.index")
            j = textures[t].source
            try:
                self._textures[key] = pbr.decode_texture(self.image_bytes(j), encoding,
                                                         f"{self.file}#images[{j}]")
            except ValueError as exc:
                if isinstance(exc, ModelError):
                    raise
                raise ModelError(str(exc), f"images[{j}]") from exc
        return self._textures[key]

    def material(self, i: int | None) -> tuple[dict[str, Any], str]:
        p = pbr.default_params()
        if i is None:
            return p, "default"
        m = self.doc.materials[i]
        f = f"materials[{i}]"
        mr = m.pbrMetallicRoughness
        if mr is not None:
            c = mr.baseColorFactor or [1.0, 1.0, 1.0, 1.0]
            p["base_color"], p["alpha"] = [float(x) for x in c[:3]], float(c[3])
            p["metallic"] = float(1.0 if mr.metallicFactor is None else mr.metallicFactor)
            p["roughness"] = float(1.0 if mr.roughnessFactor is None else mr.roughnessFactor)
            p["base_color_texture"] = self.texture(mr.baseColorTexture, "srgb",
                                                   f"{f}.pbrMetallicRoughness.baseColorTexture")
            p["metallic_roughness_texture"] = self.texture(
                mr.metallicRoughnessTexture, "linear",
                f"{f}.pbrMetallicRoughness.metallicRoughnessTexture")
        if m.normalTexture is not None:
            p["normal_texture"] = self.texture(m.normalTexture, "linear", f"{f}.normalTexture")
            p["normal_scale"] = float(getattr(m.normalTexture, "scale", 1.0) or 1.0)
        if m.occlusionTexture is not None:
            p["occlusion_texture"] = self.texture(m.occlusionTexture, "linear",
                                                  f"{f}.occlusionTexture")
            strength = getattr(m.occlusionTexture, "strength", 1.0)
            p["occlusion_strength"] = float(1.0 if strength is None else strength)
        ext = m.extensions or {}
        strength = float(ext.get("KHR_materials_emissive_strength", {}).get(
            "emissiveStrength", 1.0))
        p["emissive"] = [float(x) * strength for x in (m.emissiveFactor or [0.0, 0.0, 0.0])]
        p["emissive_texture"] = self.texture(m.emissiveTexture, "srgb", f"{f}.emissiveTexture")
        p["alpha_mode"] = (m.alphaMode or "OPAQUE").lower()
        p["alpha_cutoff"] = float(0.5 if m.alphaCutoff is None else m.alphaCutoff)
        p["two_sided"] = bool(m.doubleSided)
        if "KHR_materials_ior" in ext:
            p["ior"] = float(ext["KHR_materials_ior"].get("ior", 1.5))
        if "KHR_materials_transmission" in ext:
            t = ext["KHR_materials_transmission"]
            p["transmission"] = float(t.get("transmissionFactor", 0.0))
            if "transmissionTexture" in t:
                warn(self.model, self.file, f"{f}.extensions.KHR_materials_transmission",
                     "transmissionTexture not applied (the factor is used)")
        return pbr.check_factors(p, self.file, f), m.name or f"material{i}"

    # ---- budget -----------------------------------------------------------------------------
    def check_budget(self, prims: list[tuple[str, Any]]) -> None:
        """Triangle count and texture memory, estimated from headers before decoding."""
        tris = 0
        for _, prim in prims:
            acc = prim.indices if prim.indices is not None else prim.attributes.POSITION
            if acc is not None and 0 <= acc < len(self.doc.accessors or []):
                tris += self.doc.accessors[acc].count // 3
        if tris > MAX_TRIANGLES:
            raise ModelError(f"{tris} triangles, more than the {MAX_TRIANGLES} allowed",
                             "meshes")
        total = 0
        for j in range(len(self.doc.images or [])):
            try:
                w, h = pbr.image_size(self.image_bytes(j))
            except ModelError:
                raise
            except ValueError as exc:
                raise ModelError(str(exc), f"images[{j}]") from exc
            except Exception as exc:
                raise ModelError(f"not a readable PNG/JPEG image ({exc})",
                                 f"images[{j}]") from exc
            if w * h > pbr.MAX_TEXTURE_PIXELS:
                raise ModelError(f"texture is {w}×{h} = {w * h / 1e6:.1f} Mpx, more than the "
                                 f"{pbr.MAX_TEXTURE_PIXELS / 1e6:.1f} Mpx allowed",
                                 f"images[{j}]")
            total += w * h * 16
        if total > pbr.MAX_TEXTURE_BYTES_TOTAL:
            raise ModelError(f"textures would take {total / 2**20:.0f} MiB decoded, more than "
                             f"{pbr.MAX_TEXTURE_BYTES_TOTAL / 2**20:.0f} MiB", "images")


def _local_matrix(node: Any) -> np.ndarray:
    if node.matrix is not None and len(node.matrix) == 16:
        return np.asarray(node.matrix, np.float64).reshape(4, 4).T  # column-major
    t = np.eye(4)
    t[:3, 3] = node.translation or [0.0, 0.0, 0.0]
    x, y, z, w = node.rotation or [0.0, 0.0, 0.0, 1.0]
    r = np.eye(4)
    r[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    s = np.diag([*(node.scale or [1.0, 1.0, 1.0]), 1.0])
    return t @ r @ s


def _instances(doc: Any, select: str | None) -> list[tuple[int, np.ndarray]]:
    """(node index, world matrix) of every node under the default scene (or under the
    nodes named ``select``), depth first."""
    nodes = doc.nodes or []
    if doc.scenes:
        scene = doc.scenes[doc.scene or 0]
        roots = list(scene.nodes or [])
    else:
        children = {c for n in nodes for c in (n.children or [])}
        roots = [i for i in range(len(nodes)) if i not in children]
    out: list[tuple[int, np.ndarray]] = []
    stack = [(i, np.eye(4), select is None) for i in reversed(roots)]
    seen = 0
    while stack:
        i, parent, inside = stack.pop()
        seen += 1
        if seen > 10 * max(len(nodes), 1) + 100:
            raise ModelError("the node hierarchy has a cycle", "nodes")
        world = parent @ _local_matrix(nodes[i])
        inside = inside or nodes[i].name == select
        if inside:
            out.append((i, world))
        stack += [(c, world, inside) for c in reversed(nodes[i].children or [])]
    if select is not None and not out:
        names = sorted({n.name for n in nodes if n.name})
        raise ModelError(f"no node named {select!r} in the default scene (nodes: "
                         f"{', '.join(names[:20]) or 'none named'})", "nodes")
    return out


def _triangles(mode: int | None, n: int, idx: np.ndarray) -> np.ndarray | None:
    """``(F, 3)`` triangles of a primitive's index list (strips and fans converted)."""
    mode = 4 if mode is None else mode
    if mode == 4:
        return idx[: n - n % 3].reshape(-1, 3)
    if mode == 5:  # strip: alternate winding
        k = np.arange(max(n - 2, 0))
        tri = np.stack([idx[k], idx[k + 1], idx[k + 2]], axis=1)
        tri[1::2] = tri[1::2][:, [1, 0, 2]]
        return tri
    if mode == 6:  # fan
        k = np.arange(1, max(n - 1, 1))
        return np.stack([np.full(len(k), idx[0]), idx[k], idx[k + 1]], axis=1)
    return None  # points and lines: nothing to render


def read_gltf(path: str | Path, select: str | None = None) -> Model:
    """Read a ``.gltf`` / ``.glb`` file into parts in world space (metres, +Y up).

    Raises:
        ModelError: naming the field inside the file (an unsupported extension, a missing
            buffer or image, a broken accessor, too many triangles, too large textures).
    """
    model = Model(parts=[])
    r = _Reader(Path(path), model)
    r.check_extensions()
    doc = r.doc
    inst = _instances(doc, select)
    prims = [(f"meshes[{n.mesh}].primitives[{j}]", p)
             for i, _ in inst if (n := doc.nodes[i]).mesh is not None
             for j, p in enumerate(doc.meshes[n.mesh].primitives or [])]
    r.check_budget(prims)
    for i, world in inst:
        node = doc.nodes[i]
        if node.mesh is None:
            continue
        if node.skin is not None:
            warn(model, r.file, f"nodes[{i}].skin", "skinning not applied; the bind pose is "
                 "loaded")
        mesh = doc.meshes[node.mesh]
        for j, prim in enumerate(mesh.primitives or []):
            where = f"meshes[{node.mesh}].primitives[{j}]"
            part = _part(r, prim, where, world, f"{node.name or f'node{i}'}.{j}")
            if part is not None:
                model.parts.append(part)
    return model


def _part(r: _Reader, prim: Any, where: str, world: np.ndarray, name: str) -> ModelPart | None:
    a = prim.attributes
    if a.POSITION is None:
        raise ModelError("primitive without POSITION", f"{where}.attributes.POSITION")
    if prim.targets:
        warn(r.model, r.file, f"{where}.targets", f"{len(prim.targets)} morph target(s) not "
             "applied; the base shape is loaded")
    pos = r.accessor(a.POSITION)
    n_v = len(pos)
    idx = (r.accessor(prim.indices).astype(np.int64) if prim.indices is not None
           else np.arange(n_v, dtype=np.int64))
    faces = _triangles(prim.mode, len(idx), idx)
    if faces is None:
        warn(r.model, r.file, f"{where}.mode", f"mode {prim.mode} (points/lines) skipped")
        return None

    def attr(acc: int | None, width: int, label: str) -> np.ndarray | None:
        if acc is None:
            return None
        x = r.accessor(acc)
        if x.shape != (n_v, width):
            raise ModelError(f"expected {n_v}×{width} values, got {x.shape}",
                             f"{where}.attributes.{label}")
        return x

    normals = attr(a.NORMAL, 3, "NORMAL")
    tangents = attr(a.TANGENT, 4, "TANGENT")
    uv = attr(a.TEXCOORD_0, 2, "TEXCOORD_0")
    m3 = world[:3, :3]
    vertices = pos @ m3.T + world[:3, 3]
    det = np.linalg.det(m3)
    if det < 0:
        faces = faces[:, ::-1]
    if normals is not None:
        normals = normals @ np.linalg.inv(m3)
        length = np.linalg.norm(normals, axis=1, keepdims=True)
        normals = np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)
    if tangents is not None:
        t = tangents[:, :3] @ m3.T
        length = np.linalg.norm(t, axis=1, keepdims=True)
        t = np.divide(t, length, out=np.zeros_like(t), where=length > 0)
        tangents = np.concatenate([t, tangents[:, 3:] * np.sign(det)], axis=1)
    material, mat_name = r.material(prim.material)
    if uv is None and pbr.has_textures(material):
        raise ModelError(f"material {mat_name!r} has textures but the primitive has no "
                         "TEXCOORD_0", f"{where}.attributes.TEXCOORD_0")
    return ModelPart(name, vertices, np.ascontiguousarray(faces), uv, normals, tangents,
                     material, mat_name, where)
