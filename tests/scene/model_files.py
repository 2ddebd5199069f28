"""Small glTF / USD files for the model tests, written with pygltflib and pxr directly (not
through arlight's readers), each with one thing wrong on request."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
MODELS = ROOT / "src" / "arlight" / "data" / "models"
GLB = MODELS / "pbr_pair.glb"
USDZ = MODELS / "pbr_pair.usdz"
HAND = MODELS / "pbr_pair"


def png_header_only(path: Path, width: int, height: int) -> Path:
    """A PNG whose header claims ``width × height`` (no pixel data): a reader that checks the
    size before decoding refuses it without allocating anything."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    def part(kind: bytes, body: bytes) -> bytes:
        return (struct.pack(">I", len(body)) + kind + body
                + struct.pack(">I", zlib.crc32(kind + body)))

    data = b"\x89PNG\r\n\x1a\n" + part(b"IHDR", ihdr) + part(b"IDAT", b"") + part(b"IEND", b"")
    path.write_bytes(data)
    return path


def gltf(path: Path, *, scale: float = 1.0, degenerate: bool = False,
         extension: str | None = None, required: str | None = None,
         image_uri: str | None = None, skin: bool = False, morph: bool = False,
         animation: bool = False, node_scale: float = 1.0, nonmanifold: bool = False) -> Path:
    """A one-triangle glTF (``.glb`` or ``.gltf`` by ``path``'s suffix) with the fault asked
    for: ``degenerate`` (zero area), ``extension`` on the primitive
    (``KHR_draco_mesh_compression``) or texture (``KHR_texture_basisu``), a ``required``
    extension, a base colour texture at ``image_uri`` (external file), a ``skin``, morph
    targets, an animation, a node scale, three triangles on one edge (``nonmanifold``)."""
    import pygltflib as g

    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]],
                 np.float32) * scale
    if degenerate:
        v[2] = v[1]
    uv = np.array([[0, 0], [1, 0], [0, 1], [0, 1], [1, 1]], np.float32)
    # three triangles on the edge 0–1 make it non-manifold
    idx = np.array([0, 1, 2, 1, 0, 3, 0, 1, 4] if nonmanifold else [0, 1, 2], np.uint32)
    blob = v.tobytes() + uv.tobytes() + idx.tobytes()
    views = [g.BufferView(buffer=0, byteOffset=0, byteLength=v.nbytes),
             g.BufferView(buffer=0, byteOffset=v.nbytes, byteLength=uv.nbytes),
             g.BufferView(buffer=0, byteOffset=v.nbytes + uv.nbytes, byteLength=idx.nbytes)]
    accs = [g.Accessor(bufferView=0, componentType=g.FLOAT, count=len(v), type="VEC3",
                       min=v.min(0).tolist(), max=v.max(0).tolist()),
            g.Accessor(bufferView=1, componentType=g.FLOAT, count=len(v), type="VEC2"),
            g.Accessor(bufferView=2, componentType=g.UNSIGNED_INT, count=len(idx),
                       type="SCALAR")]
    prim = g.Primitive(attributes=g.Attributes(POSITION=0, TEXCOORD_0=1), indices=2,
                       material=0)
    mat = g.Material(name="m", pbrMetallicRoughness=g.PbrMetallicRoughness(
        baseColorFactor=[0.5, 0.5, 0.5, 1.0], metallicFactor=0.0))
    doc = g.GLTF2(asset=g.Asset(version="2.0"), scene=0, scenes=[g.Scene(nodes=[0])],
                  nodes=[g.Node(name="tri", mesh=0, scale=[node_scale] * 3)],
                  meshes=[g.Mesh(primitives=[prim])], materials=[mat], accessors=accs,
                  bufferViews=views, buffers=[g.Buffer(byteLength=len(blob))])
    if extension == "KHR_draco_mesh_compression":
        prim.extensions = {extension: {"bufferView": 0, "attributes": {"POSITION": 0}}}
        doc.extensionsUsed = [extension]
    if image_uri is not None or extension == "KHR_texture_basisu":
        doc.images = [g.Image(uri=image_uri or "tex.ktx2")]
        tex = g.Texture(source=0)
        if extension == "KHR_texture_basisu":
            tex.source = None
            tex.extensions = {extension: {"source": 0}}
        doc.textures = [tex]
        mat.pbrMetallicRoughness.baseColorTexture = g.TextureInfo(index=0)
    if required is not None:
        doc.extensionsRequired = [required]
        doc.extensionsUsed = [required]
    if skin:
        doc.nodes[0].skin = 0
        doc.nodes.append(g.Node(name="joint"))
        doc.skins = [g.Skin(joints=[1])]
    if morph:
        prim.targets = [{"POSITION": 0}]
    if animation:
        doc.animations = [g.Animation(channels=[], samplers=[])]
    doc.set_binary_blob(blob)
    if path.suffix == ".glb":
        doc.save_binary(str(path))
    else:
        doc.convert_buffers(g.BufferFormat.DATAURI)
        doc.save_json(str(path))
    return path


def usda(path: Path, *, meters_per_unit: float = 1.0, up: str = "Y",
         texture: str | None = None, size: float = 1.0) -> Path:
    """A one-triangle USD stage with a UsdPreviewSurface; ``texture``: a diffuse texture
    file name (which may be missing)."""
    from pxr import Sdf, Usd, UsdGeom, UsdShade

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, meters_per_unit)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z if up == "Z" else UsdGeom.Tokens.y)
    mesh = UsdGeom.Mesh.Define(stage, "/tri")
    mesh.CreatePointsAttr([(0, 0, 0), (size, 0, 0), (0, size, 0)])
    mesh.CreateFaceVertexCountsAttr([3])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2])
    UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(
        "st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex).Set(
        [(0, 0), (1, 0), (0, 1)])
    mat = UsdShade.Material.Define(stage, "/mat")
    surf = UsdShade.Shader.Define(stage, "/mat/surface")
    surf.CreateIdAttr("UsdPreviewSurface")
    if texture is not None:
        t = UsdShade.Shader.Define(stage, "/mat/tex")
        t.CreateIdAttr("UsdUVTexture")
        t.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(texture)
        surf.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(
            t.ConnectableAPI(), "rgb")
    mat.CreateSurfaceOutput().ConnectToSource(surf.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)
    stage.GetRootLayer().Save()
    return path
