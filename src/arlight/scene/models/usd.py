"""USD (``.usd``, ``.usda``, ``.usdc``, ``.usdz``) to :class:`ModelPart` s, through Pixar's
``usd-core`` (``pxr``).

Conventions: a stage's length unit is ``metersPerUnit`` metres (``UsdGeom`` default 0.01, as
the USD spec says when the stage does not author it) and its up axis is ``upAxis`` (``Y`` or
``Z``). Positions are scaled by ``metersPerUnit`` and, for a ``Z``-up stage, turned by −90°
about +X (USD +Z becomes arlight +Y, USD +Y becomes arlight −Z), so the result is arlight's
right-handed, +Y-up, metre world. Each ``Mesh`` prim (instance proxies included, guides and
invisible prims excluded) becomes one part, its polygons triangulated as fans, its
attributes expanded to one vertex per triangle corner (USD's ``faceVarying`` primvars need
it). ``orientation = "leftHanded"`` reverses the winding. The ``st`` texture coordinates
(origin bottom-left) are flipped to v = 1 − t (glTF's and Mitsuba's origin, top-left).

Materials: the bound ``UsdPreviewSurface`` maps to ``pbr`` (see ``docs/scene-format.md``);
an input connected to a ``UsdUVTexture`` reads the texture's channel (``rgb``, ``r``, ``g``,
``b``, ``a``) with the texture's ``scale`` as the factor. Roughness and metallic may come
from two channels of one texture or from two textures of the same size. Skeletal bindings,
blend shapes and time samples are not applied: the default (or earliest) time's pose is
loaded with a :class:`~.part.ModelWarning`.
"""

from __future__ import annotations

import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from arlight.scene import pbr
from arlight.scene.models.part import MAX_TRIANGLES, Model, ModelError, ModelPart, warn

_Z_UP = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]])
"""Rotation of −90° about +X: USD Z-up to arlight Y-up (z → y, y → −z)."""
_CHANNEL = {"r": 0, "g": 1, "b": 2, "a": 3}


def _asset_bytes(resolved: str, field: str) -> bytes:
    """Bytes of a resolved asset path: a file, or ``package.usdz[member]``."""
    if resolved.endswith("]") and "[" in resolved:
        package, member = resolved[:-1].split("[", 1)
        try:
            with zipfile.ZipFile(package) as z:
                return z.read(member)
        except (OSError, KeyError, zipfile.BadZipFile) as exc:
            raise ModelError(f"cannot read {member} from {package} ({exc})", field) from exc
    p = Path(resolved)
    if not p.is_file():
        raise ModelError(f"file not found: {resolved}", field)
    return p.read_bytes()


class _Materials:
    """``UsdPreviewSurface`` materials of one stage as ``pbr`` tables (cached per prim)."""

    def __init__(self, file: str, model: Model):
        self.file = file
        self.model = model
        self._cache: dict[str, tuple[dict[str, Any], str]] = {}
        self._tex: dict[tuple[str, str], pbr.Texture] = {}

    def texture_pixels(self, shader: Any, encoding: str, field: str) -> pbr.Texture:
        from pxr import Sdf

        asset = shader.GetInput("file").Get() if shader.GetInput("file") else None
        if not isinstance(asset, Sdf.AssetPath) or not asset.path:
            raise ModelError("UsdUVTexture without inputs:file", f"{field}.inputs:file")
        resolved = asset.resolvedPath
        if not resolved:
            raise ModelError(f"texture file not found: {asset.path}", f"{field}.inputs:file")
        space = shader.GetInput("sourceColorSpace")
        space = space.Get() if space else "auto"
        enc = "linear" if space == "raw" else ("srgb" if space == "sRGB" else encoding)
        key = (resolved, enc)
        if key not in self._tex:
            data = _asset_bytes(resolved, f"{field}.inputs:file")
            try:
                self._tex[key] = pbr.decode_texture(data, enc, f"{self.file}#{asset.path}")
            except ValueError as exc:
                raise ModelError(f"{exc} ({asset.path})", f"{field}.inputs:file") from exc
        return self._tex[key]

    def source(self, surface: Any, name: str) -> tuple[Any, Any, str] | None:
        """(value or None, UsdUVTexture shader or None, channel) of a surface input."""
        from pxr import UsdShade

        inp = surface.GetInput(name)
        if not inp:
            return None
        if inp.HasConnectedSource():
            src, out_name, _ = inp.GetConnectedSource()
            shader = UsdShade.Shader(src.GetPrim())
            sid = shader.GetIdAttr().Get() if shader else None
            if sid != "UsdUVTexture":
                raise ModelError(f"connected to {sid!r}; only UsdUVTexture is read",
                                 f"{surface.GetPath()}.inputs:{name}")
            return None, shader, out_name
        return inp.Get(), None, ""

    @staticmethod
    def _scale(shader: Any) -> np.ndarray:
        s = shader.GetInput("scale")
        return np.asarray(s.Get() if s and s.Get() is not None else (1, 1, 1, 1), np.float64)

    def material(self, prim: Any) -> tuple[dict[str, Any], str]:
        from pxr import UsdShade

        mat, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
        if not mat:
            return pbr.default_params(), "default"
        key = str(mat.GetPath())
        if key not in self._cache:
            self._cache[key] = (self._read(mat, key), mat.GetPrim().GetName())
        return self._cache[key]

    def _read(self, mat: Any, key: str) -> dict[str, Any]:
        from pxr import UsdShade

        p = pbr.default_params()
        surface = mat.ComputeSurfaceSource()[0]
        sid = UsdShade.Shader(surface.GetPrim()).GetIdAttr().Get() if surface else None
        if sid != "UsdPreviewSurface":
            warn(self.model, self.file, f"{key}.outputs:surface", f"surface shader {sid!r} "
                 "is not UsdPreviewSurface; a default pbr material is used")
            return p
        shader = UsdShade.Shader(surface.GetPrim())
        f = str(shader.GetPath())
        spec = self.source(shader, "useSpecularWorkflow")
        if spec and spec[0]:
            warn(self.model, self.file, f"{f}.inputs:useSpecularWorkflow",
                 "the specular workflow is read as metallic = 0")
        p["metallic"], p["roughness"] = 0.0, 0.5  # UsdPreviewSurface defaults
        p["base_color"] = [0.18] * 3
        if (s := self.source(shader, "diffuseColor")) is not None:
            value, tex, _ = s
            if tex is None:
                p["base_color"] = [float(x) for x in value]
            else:
                p["base_color_texture"] = self.texture_pixels(tex, "srgb",
                                                              f"{f}.inputs:diffuseColor")
                p["base_color"] = [float(x) for x in self._scale(tex)[:3]]
        channels: dict[str, tuple[pbr.Texture, int]] = {}
        for name in ("metallic", "roughness"):
            if (s := self.source(shader, name)) is None:
                continue
            value, tex, out = s
            if tex is None:
                p[name] = float(value)
                continue
            t = self.texture_pixels(tex, "linear", f"{f}.inputs:{name}")
            c = _CHANNEL.get(out, 0)
            channels[name] = (t, c)
            p[name] = float(self._scale(tex)[c])
        if channels:
            p["metallic_roughness_texture"] = self._combine(channels, f)
        if (s := self.source(shader, "normal")) is not None and s[1] is not None:
            p["normal_texture"] = self.texture_pixels(s[1], "linear", f"{f}.inputs:normal")
            p["normal_scale"] = float(self._scale(s[1])[0] / 2.0)
        if (s := self.source(shader, "occlusion")) is not None and s[1] is not None:
            p["occlusion_texture"] = self.texture_pixels(s[1], "linear",
                                                         f"{f}.inputs:occlusion")
        if (s := self.source(shader, "emissiveColor")) is not None:
            value, tex, _ = s
            if tex is None:
                p["emissive"] = [float(x) for x in value]
            else:
                p["emissive_texture"] = self.texture_pixels(tex, "srgb",
                                                            f"{f}.inputs:emissiveColor")
                p["emissive"] = [float(x) for x in self._scale(tex)[:3]]
        if (s := self.source(shader, "opacity")) is not None:
            value, tex, _ = s
            p["alpha"] = float(self._scale(tex)[3]) if tex is not None else float(value)
            threshold = self.source(shader, "opacityThreshold")
            cutoff = float(threshold[0]) if threshold and threshold[0] is not None else 0.0
            if cutoff > 0:
                p["alpha_mode"], p["alpha_cutoff"] = "mask", cutoff
            elif tex is not None or p["alpha"] < 1.0:
                p["alpha_mode"] = "blend"
        if (s := self.source(shader, "ior")) is not None and s[0] is not None:
            p["ior"] = float(s[0])
        return pbr.check_factors(p, self.file, f)

    def _combine(self, channels: dict[str, tuple[pbr.Texture, int]], field: str) -> pbr.Texture:
        """One glTF-layout texture (G roughness, B metallic) from the USD channels."""
        shapes = {t.pixels.shape[:2] for t, _ in channels.values()}
        if len(shapes) > 1:
            raise ModelError(f"metallic and roughness textures differ in size {sorted(shapes)}",
                             f"{field}.inputs:metallic")
        h, w = shapes.pop()
        out = np.ones((h, w, 3), np.float32)
        for name, slot in (("roughness", 1), ("metallic", 2)):
            if name in channels:
                t, c = channels[name]
                out[..., slot] = t.pixels[..., min(c, t.pixels.shape[2] - 1)]
        sources = "+".join(sorted({t.source for t, _ in channels.values()}))
        return pbr.Texture(sources, out)


def _primvar(api: Any, names: tuple[str, ...]) -> Any:
    for n in names:
        pv = api.GetPrimvar(n)
        if pv and pv.HasValue():
            return pv
    return None


def _corner_values(pv: Any, n_points: int, corners: np.ndarray, face_of_corner: np.ndarray,
                   time: Any, width: int, field: str) -> np.ndarray:
    """A primvar's values at every polygon corner ``(C, width)``."""
    values = np.asarray(pv.ComputeFlattened(time), np.float64).reshape(-1, width)
    interp = pv.GetInterpolation()
    if interp in ("vertex", "varying"):
        idx = corners
    elif interp == "faceVarying":
        idx = np.arange(len(corners))
    elif interp == "uniform":
        idx = face_of_corner
    else:  # constant
        idx = np.zeros(len(corners), np.int64)
    if len(idx) and idx.max() >= len(values):
        raise ModelError(f"{interp} primvar has {len(values)} values, too few", field)
    return values[idx]


def read_usd(path: str | Path, select: str | None = None) -> Model:
    """Read a USD stage (any of its file formats, USDZ packages included) into parts in
    arlight's world (metres, +Y up).

    Raises:
        ModelError: naming the prim path and attribute at fault.
    """
    from pxr import Usd, UsdGeom, UsdSkel

    path = Path(path)
    file = str(path)
    model = Model(parts=[])
    stage = Usd.Stage.Open(file)
    if stage is None:
        raise ModelError("not a readable USD stage", "/")
    mpu = float(UsdGeom.GetStageMetersPerUnit(stage))
    if not np.isfinite(mpu) or mpu <= 0:
        raise ModelError(f"metersPerUnit = {mpu}", "metersPerUnit")
    up = UsdGeom.GetStageUpAxis(stage)
    to_arlight = np.diag([mpu, mpu, mpu, 1.0])
    if up == UsdGeom.Tokens.z:
        to_arlight = _Z_UP @ to_arlight
    root = stage.GetPseudoRoot()
    if select is not None:
        root = stage.GetPrimAtPath(select) if select.startswith("/") else None
        if not root:
            raise ModelError(f"no prim at path {select!r} (give an absolute prim path)", "/")
    time = Usd.TimeCode.EarliestTime()
    xforms = UsdGeom.XformCache(time)
    materials = _Materials(file, model)
    meshes = []
    for prim in Usd.PrimRange(root, Usd.TraverseInstanceProxies()):
        img = UsdGeom.Imageable(prim)
        if img and (img.ComputeVisibility(time) == UsdGeom.Tokens.invisible
                    or img.ComputePurpose() in (UsdGeom.Tokens.guide, UsdGeom.Tokens.proxy)):
            continue
        if prim.IsA(UsdSkel.Root) or prim.HasAPI(UsdSkel.BindingAPI):
            warn(model, file, str(prim.GetPath()), "skeletal binding not applied; the rest "
                 "pose is loaded")
        if prim.IsA(UsdGeom.Mesh):
            meshes.append(prim)
    tris = sum(int(np.maximum(np.asarray(UsdGeom.Mesh(m).GetFaceVertexCountsAttr().Get(time)
                                         or [], np.int64) - 2, 0).sum()) for m in meshes)
    if tris > MAX_TRIANGLES:
        raise ModelError(f"{tris} triangles, more than the {MAX_TRIANGLES} allowed", "/")
    for prim in meshes:
        world = to_arlight @ np.asarray(xforms.GetLocalToWorldTransform(prim), np.float64).T
        part = _mesh_part(prim, world, time, materials, model, file)
        if part is not None:
            model.parts.append(part)
    return model


def _mesh_part(prim: Any, world: np.ndarray, time: Any, materials: _Materials, model: Model,
               file: str) -> ModelPart | None:
    from pxr import UsdGeom

    mesh = UsdGeom.Mesh(prim)
    where = str(prim.GetPath())
    points_attr = mesh.GetPointsAttr()
    if points_attr.GetNumTimeSamples() > 1:
        warn(model, file, f"{where}.points", "animated points not applied; the earliest "
             "time sample is loaded")
    if UsdGeom.PrimvarsAPI(prim).HasPrimvar("skel:jointIndices") or \
            prim.GetChildren() and any(c.GetTypeName() == "BlendShape"
                                       for c in prim.GetChildren()):
        warn(model, file, where, "blend shapes / skinning not applied; the rest pose is loaded")
    pts = np.asarray(points_attr.Get(time) or [], np.float64).reshape(-1, 3)
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(time) or [], np.int64)
    corners = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(time) or [], np.int64)
    if len(pts) == 0 or len(counts) == 0:
        return None
    if counts.sum() != len(corners) or counts.min() < 3:
        raise ModelError("faceVertexCounts do not match faceVertexIndices (or a face has "
                         "fewer than 3 vertices)", f"{where}.faceVertexCounts")
    if corners.min() < 0 or corners.max() >= len(pts):
        raise ModelError(f"faceVertexIndices reach point {int(corners.max())} of {len(pts)}",
                         f"{where}.faceVertexIndices")
    face_of_corner = np.repeat(np.arange(len(counts)), counts)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    # fan triangulation: corners (s, s+k, s+k+1) for k = 1..n-2
    f_idx = np.repeat(np.arange(len(counts)), counts - 2)
    k = np.arange(len(f_idx)) - np.repeat(np.cumsum(counts - 2) - (counts - 2), counts - 2) + 1
    tri = np.stack([start[f_idx], start[f_idx] + k, start[f_idx] + k + 1], axis=1)
    if mesh.GetOrientationAttr().Get() == UsdGeom.Tokens.leftHanded:
        tri = tri[:, ::-1]
    m3 = world[:3, :3]
    det = np.linalg.det(m3)
    if det < 0:
        tri = tri[:, ::-1]
    vertices = pts[corners] @ m3.T + world[:3, 3]
    api = UsdGeom.PrimvarsAPI(prim)
    normals = None
    pv = _primvar(api, ("normals",))
    if pv is not None:
        n = _corner_values(pv, len(pts), corners, face_of_corner, time, 3, f"{where}.normals")
    elif mesh.GetNormalsAttr().HasValue():
        raw = np.asarray(mesh.GetNormalsAttr().Get(time), np.float64).reshape(-1, 3)
        interp = mesh.GetNormalsInterpolation()
        n = raw[corners] if interp in ("vertex", "varying") else (
            raw if interp == "faceVarying" else raw[face_of_corner])
        if len(n) != len(corners):
            raise ModelError("normals do not match the faces", f"{where}.normals")
    else:
        n = None
    if n is not None:
        n = n @ np.linalg.inv(m3)
        length = np.linalg.norm(n, axis=1, keepdims=True)
        normals = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
    uv = None
    pv = _primvar(api, ("st", "st0", "UVMap", "uv"))
    if pv is not None:
        st = _corner_values(pv, len(pts), corners, face_of_corner, time, 2, f"{where}.st")
        uv = np.stack([st[:, 0], 1.0 - st[:, 1]], axis=1)
    material, mat_name = materials.material(prim)
    if uv is None and pbr.has_textures(material):
        raise ModelError(f"material {mat_name!r} has textures but the mesh has no st primvar",
                         f"{where}.primvars:st")
    return ModelPart(where, vertices, tri, uv, normals, None, material, mat_name)
