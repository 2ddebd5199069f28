"""Make the bundled PBR test assets of ``src/arlight/data/models/`` (issue #34).

One object pair, written three ways with the same geometry and materials:

* ``pbr_pair.glb`` — glTF 2.0 binary: a root node turned 90° about +Y holding two nodes,
  ``body`` (a sphere with a sRGB checker base colour, a bump normal map and a roughness
  gradient in the G channel of its metallic-roughness texture) and ``ball`` (a smaller
  gold metallic sphere, no textures); metres, +Y up, tangents included.
* ``pbr_pair.usdz`` — the same as a USD stage in **centimetres** (``metersPerUnit = 0.01``)
  and **Z up**, with ``UsdPreviewSurface`` materials and ``UsdUVTexture`` readers (so
  arlight's unit and axis conversion is exercised), packaged with its textures.
* ``pbr_pair/`` — the hand-written equivalent: ``body.ply`` and ``ball.ply`` in world
  space (transforms applied here with NumPy, independently of the importers) and the PNG
  textures, for a scene file with ``type = "mesh"`` shapes and ``type = "pbr"`` materials.

Everything is generated from formulas here (no third-party content); licence CC0-1.0 as
stated in ``src/arlight/data/ATTRIBUTION.md``. Run: ``.venv/bin/python tools/make_pbr_models.py``.
"""

from __future__ import annotations

import io
import shutil
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image

OUT = Path(__file__).resolve().parents[1] / "src" / "arlight" / "data" / "models"
TEX = 64  # texture size (px)
ROOT_YAW_DEG = 90.0  # the root node's rotation about +Y
BODY = {"radius": 0.05, "translate": [0.0, 0.05, -0.03]}  # in the root node's frame (m)
BALL = {"radius": 0.03, "translate": [0.0, 0.03, 0.07]}
GOLD = [1.0, 0.766, 0.336]
BALL_ROUGHNESS = 0.25
BODY_FACTORS = {"base_color": [1.0, 1.0, 1.0], "metallic": 1.0, "roughness": 1.0}


def sphere(radius: float, n_phi: int = 32, n_theta: int = 16):
    """A UV sphere: positions, normals, uv (v = 0 at the top, +Y), tangents (dp/du, w = 1),
    faces (counter-clockwise from outside)."""
    phi = np.linspace(0.0, 2 * np.pi, n_phi + 1)
    theta = np.linspace(0.0, np.pi, n_theta + 1)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    n = np.stack([np.sin(t) * np.sin(p), np.cos(t), np.sin(t) * np.cos(p)], axis=-1)
    tan = np.stack([np.cos(p), np.zeros_like(p), -np.sin(p)], axis=-1)
    uv = np.stack([p / (2 * np.pi), t / np.pi], axis=-1)
    idx = np.arange((n_theta + 1) * (n_phi + 1)).reshape(n_theta + 1, n_phi + 1)
    faces = []
    for i in range(n_theta):
        for j in range(n_phi):
            a, b, c, d = idx[i, j], idx[i + 1, j], idx[i + 1, j + 1], idx[i, j + 1]
            if i > 0:
                faces.append([a, b, d])
            if i < n_theta - 1:
                faces.append([b, c, d])
    nn = n.reshape(-1, 3)
    tt = np.concatenate([tan.reshape(-1, 3), np.ones((len(nn), 1))], axis=1)
    return (radius * nn, nn, uv.reshape(-1, 2), tt, np.asarray(faces, np.int64))


def textures() -> dict[str, np.ndarray]:
    """8-bit RGB(A) textures: sRGB checker base colour, bump normal map, G-roughness map."""
    y, x = np.mgrid[0:TEX, 0:TEX] + 0.5
    u, v = x / TEX, y / TEX
    check = ((np.floor(u * 8) + np.floor(v * 4)) % 2)[..., None]
    base = np.where(check > 0, [200, 60, 40], [230, 220, 190])
    k = 2 * np.pi * 6
    dhdu = 0.6 * np.cos(k * u) * np.sin(k * v / 2)
    dhdv = 0.3 * np.sin(k * u) * np.cos(k * v / 2)
    nrm = np.stack([-dhdu, dhdv, np.ones_like(u)], axis=-1)
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    mr = np.stack([np.zeros_like(u), 0.25 + 0.6 * v, np.zeros_like(u)], axis=-1)
    return {"base_color": base.astype(np.uint8),
            "normal": np.round((nrm + 1) / 2 * 255).astype(np.uint8),
            "metallic_roughness": np.round(mr * 255).astype(np.uint8)}


def png_bytes(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(a).save(buf, format="PNG", optimize=True)
    return buf.getvalue()


def rot_y(deg: float) -> np.ndarray:
    a = np.radians(deg)
    m = np.eye(4)
    m[[0, 0, 2, 2], [0, 2, 0, 2]] = [np.cos(a), np.sin(a), -np.sin(a), np.cos(a)]
    return m


def world_of(obj: dict) -> np.ndarray:
    t = np.eye(4)
    t[:3, 3] = obj["translate"]
    return rot_y(ROOT_YAW_DEG) @ t


def write_ply(path: Path, v, n, uv, f) -> None:
    """Binary little-endian PLY with x y z nx ny nz s t (float32) and uint32 triangles."""
    head = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(v)}\n"
            "property float x\nproperty float y\nproperty float z\n"
            "property float nx\nproperty float ny\nproperty float nz\n"
            "property float s\nproperty float t\n"
            f"element face {len(f)}\nproperty list uchar uint vertex_indices\nend_header\n"
            ).encode()
    verts = np.concatenate([v, n, uv], axis=1).astype("<f4").tobytes()
    faces = np.zeros(len(f), dtype=[("n", "u1"), ("i", "<u4", 3)])
    faces["n"], faces["i"] = 3, f
    path.write_bytes(head + verts + faces.tobytes())


def write_glb(path: Path, meshes: dict, tex: dict) -> None:
    import pygltflib as g

    blob = bytearray()
    views, accessors = [], []

    def add(data: np.ndarray, target: int | None, acc_type: str, ctype: int,
            minmax: bool = False) -> int:
        while len(blob) % 4:
            blob.append(0)
        raw = data.tobytes()
        views.append(g.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(raw),
                                  target=target))
        blob.extend(raw)
        acc = g.Accessor(bufferView=len(views) - 1, componentType=ctype,
                         count=len(data), type=acc_type)
        if minmax:
            acc.min, acc.max = data.min(axis=0).tolist(), data.max(axis=0).tolist()
        accessors.append(acc)
        return len(accessors) - 1

    images = []
    for name in ("base_color", "normal", "metallic_roughness"):
        data = png_bytes(tex[name])
        while len(blob) % 4:
            blob.append(0)
        views.append(g.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(data)))
        blob.extend(data)
        images.append(g.Image(bufferView=len(views) - 1, mimeType="image/png", name=name))
    materials = [
        g.Material(name="body", pbrMetallicRoughness=g.PbrMetallicRoughness(
            baseColorFactor=[*BODY_FACTORS["base_color"], 1.0],
            metallicFactor=BODY_FACTORS["metallic"], roughnessFactor=BODY_FACTORS["roughness"],
            baseColorTexture=g.TextureInfo(index=0),
            metallicRoughnessTexture=g.TextureInfo(index=2)),
            normalTexture=g.NormalMaterialTexture(index=1, scale=1.0), doubleSided=True),
        g.Material(name="gold", pbrMetallicRoughness=g.PbrMetallicRoughness(
            baseColorFactor=[*GOLD, 1.0], metallicFactor=1.0,
            roughnessFactor=BALL_ROUGHNESS), doubleSided=True),
    ]
    gl_meshes, nodes = [], []
    for i, (name, (v, n, uv, t, f)) in enumerate(meshes.items()):
        prim = g.Primitive(
            attributes=g.Attributes(
                POSITION=add(v.astype("<f4"), g.ARRAY_BUFFER, "VEC3", g.FLOAT, True),
                NORMAL=add(n.astype("<f4"), g.ARRAY_BUFFER, "VEC3", g.FLOAT),
                TANGENT=add(t.astype("<f4"), g.ARRAY_BUFFER, "VEC4", g.FLOAT),
                TEXCOORD_0=add(uv.astype("<f4"), g.ARRAY_BUFFER, "VEC2", g.FLOAT)),
            indices=add(f.reshape(-1).astype("<u4"), g.ELEMENT_ARRAY_BUFFER, "SCALAR",
                        g.UNSIGNED_INT), material=i)
        gl_meshes.append(g.Mesh(name=name, primitives=[prim]))
        obj = BODY if name == "body" else BALL
        nodes.append(g.Node(name=name, mesh=i, translation=obj["translate"]))
    half = np.radians(ROOT_YAW_DEG) / 2
    nodes.append(g.Node(name="pbr_pair", children=[0, 1],
                        rotation=[0.0, float(np.sin(half)), 0.0, float(np.cos(half))]))
    doc = g.GLTF2(asset=g.Asset(version="2.0", generator="arlight tools/make_pbr_models.py"),
                  scene=0, scenes=[g.Scene(nodes=[2])], nodes=nodes, meshes=gl_meshes,
                  materials=materials, textures=[g.Texture(source=i) for i in range(3)],
                  images=images, accessors=accessors, bufferViews=views,
                  buffers=[g.Buffer(byteLength=len(blob))])
    doc.set_binary_blob(bytes(blob))
    doc.save_binary(str(path))


def write_usdz(path: Path, meshes: dict, tex_dir: Path) -> None:
    """The pair as a Z-up, centimetre USD stage, packaged as USDZ with its textures."""
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, UsdUtils, Vt

    cm = 100.0
    to_usd = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # arlight (x, y, z) -> (x, -z, y)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for name in ("base_color", "normal", "metallic_roughness"):
            shutil.copy(tex_dir / f"{name}.png", tmp / f"{name}.png")
        usda = tmp / "pbr_pair.usda"
        stage = Usd.Stage.CreateNew(str(usda))
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
        UsdGeom.SetStageMetersPerUnit(stage, 0.01)
        root = UsdGeom.Xform.Define(stage, "/pbr_pair")
        stage.SetDefaultPrim(root.GetPrim())
        root.AddRotateZOp().Set(ROOT_YAW_DEG)

        def texture(mat_path: str, name: str, space: str, scale=None, bias=None):
            t = UsdShade.Shader.Define(stage, f"{mat_path}/{name}")
            t.CreateIdAttr("UsdUVTexture")
            t.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(f"{name}.png")
            t.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set(space)
            t.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(
                UsdShade.Shader.Get(stage, f"{mat_path}/st").ConnectableAPI(), "result")
            if scale is not None:
                t.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(*scale))
                t.CreateInput("bias", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(*bias))
            return t

        for name, (v, n, uv, _, f) in meshes.items():
            obj = BODY if name == "body" else BALL
            xf = UsdGeom.Xform.Define(stage, f"/pbr_pair/{name}")
            xf.AddTranslateOp().Set(Gf.Vec3d(*(to_usd @ np.asarray(obj["translate"]) * cm)))
            mesh = UsdGeom.Mesh.Define(stage, f"/pbr_pair/{name}/mesh")
            mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy((v @ to_usd.T * cm).astype("f4")))
            mesh.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(f)))
            mesh.CreateFaceVertexIndicesAttr(Vt.IntArray(f.reshape(-1).tolist()))
            mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
            mesh.CreateDoubleSidedAttr(True)
            api = UsdGeom.PrimvarsAPI(mesh)
            api.CreatePrimvar("normals", Sdf.ValueTypeNames.Normal3fArray,
                              UsdGeom.Tokens.vertex).Set(
                Vt.Vec3fArray.FromNumpy((n @ to_usd.T).astype("f4")))
            st = np.stack([uv[:, 0], 1.0 - uv[:, 1]], axis=1).astype("f4")  # USD: t up
            api.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                              UsdGeom.Tokens.vertex).Set(Vt.Vec2fArray.FromNumpy(st))
            mp = f"/pbr_pair/{name}/material"
            mat = UsdShade.Material.Define(stage, mp)
            surf = UsdShade.Shader.Define(stage, f"{mp}/surface")
            surf.CreateIdAttr("UsdPreviewSurface")
            if name == "body":
                reader = UsdShade.Shader.Define(stage, f"{mp}/st")
                reader.CreateIdAttr("UsdPrimvarReader_float2")
                reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("st")
                reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
                bc = texture(mp, "base_color", "sRGB")
                surf.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(
                    bc.ConnectableAPI(), "rgb")
                mr = texture(mp, "metallic_roughness", "raw")
                surf.CreateInput("roughness", Sdf.ValueTypeNames.Float).ConnectToSource(
                    mr.ConnectableAPI(), "g")
                surf.CreateInput("metallic", Sdf.ValueTypeNames.Float).ConnectToSource(
                    mr.ConnectableAPI(), "b")
                nm = texture(mp, "normal", "raw", (2, 2, 2, 1), (-1, -1, -1, 0))
                surf.CreateInput("normal", Sdf.ValueTypeNames.Normal3f).ConnectToSource(
                    nm.ConnectableAPI(), "rgb")
            else:
                surf.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*GOLD))
                surf.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(1.0)
                surf.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(BALL_ROUGHNESS)
            mat.CreateSurfaceOutput().ConnectToSource(surf.ConnectableAPI(), "surface")
            UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)
        stage.GetRootLayer().Save()
        if path.exists():
            path.unlink()
        if not UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(usda)), str(path)):
            raise RuntimeError("USDZ packaging failed")


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    hand = OUT / "pbr_pair"
    hand.mkdir(exist_ok=True)
    tex = textures()
    for name, a in tex.items():
        (hand / f"{name}.png").write_bytes(png_bytes(a))
    meshes = {"body": sphere(BODY["radius"]), "ball": sphere(BALL["radius"], 24, 12)}
    for name, (v, n, uv, _, f) in meshes.items():
        m = world_of(BODY if name == "body" else BALL)
        write_ply(hand / f"{name}.ply", v @ m[:3, :3].T + m[:3, 3], n @ m[:3, :3].T, uv, f)
    write_glb(OUT / "pbr_pair.glb", meshes, tex)
    write_usdz(OUT / "pbr_pair.usdz", meshes, hand)
    for p in sorted(OUT.rglob("*")):
        if p.is_file():
            print(f"{p.relative_to(OUT)}: {p.stat().st_size / 1024:.1f} KiB")


if __name__ == "__main__":
    main()
