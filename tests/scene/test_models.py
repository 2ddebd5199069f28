"""glTF / GLB and USD / USDZ virtual objects with the ``pbr`` material (issue #34).

The bundled pair (``src/arlight/data/models``, made by ``tools/make_pbr_models.py``) exists
three ways: a GLB (metres, +Y up, a rotated root node), a USDZ (centimetres, Z up) and a
hand-written equivalent (world-space PLY meshes + PNG textures). The acceptance test renders
all three with ``reference`` and compares them with each other and with Mitsuba's own
``path`` integrator on a scene built here from the PLY and PNG files by Mitsuba's own loaders.
"""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest
from PIL import Image

from arlight.errors import InputError
from arlight.scene.load import parse_scene
from arlight.scene.models import ModelWarning, read_model
from tests.scene.model_files import GLB, HAND, ROOT, USDZ, gltf, png_header_only, usda

ENVMAP = ROOT / "src" / "arlight" / "data" / "demo" / "lebombo_512x256.hdr"
GOLD = [1.0, 0.766, 0.336]
# generator constants, restated: root yaw 90° about +Y; body r = 5 cm at (0, 5, -3) cm and
# ball r = 3 cm at (0, 3, 7) cm in the root's frame -> centres (-3, 5, 0) and (7, 3, 0) cm
BODY_CENTRE, BODY_R = np.array([-0.03, 0.05, 0.0]), 0.05
BALL_CENTRE, BALL_R = np.array([0.07, 0.03, 0.0]), 0.03


def _scene(shapes: list[dict], w: int = 64, h: int = 48) -> dict:
    return {"camera": {"resolution": [w, h], "fov_y_deg": 35,
                       "look_at": {"origin": [0.0, 0.13, 0.24], "target": [0.01, 0.04, 0.0]}},
            "shapes": [{"name": "table", "role": "real", "type": "rectangle", "size": [1, 1],
                        "normal": [0, 1, 0], "material": {"type": "diffuse", "albedo": 0.5}},
                       *shapes],
            "lights": [{"type": "envmap", "file": str(ENVMAP)}]}


def _model(path, **kw) -> list[dict]:
    return [{"name": "obj", "role": "virtual", "type": "model", "file": str(path), **kw}]


HAND_SHAPES = [
    {"name": "body", "role": "virtual", "type": "mesh", "file": str(HAND / "body.ply"),
     "material": {"type": "pbr", "base_color_texture": str(HAND / "base_color.png"),
                  "metallic_roughness_texture": str(HAND / "metallic_roughness.png"),
                  "normal_texture": str(HAND / "normal.png")}},
    {"name": "ball", "role": "virtual", "type": "mesh", "file": str(HAND / "ball.ply"),
     "material": {"type": "pbr", "base_color": GOLD, "metallic": 1.0, "roughness": 0.25}},
]


# ------------------------------------------------------------------ geometry and conventions

def _part(path, name: str):
    """The part of the bundled pair whose name contains ``name`` (glTF ``body.0``, USD
    ``/pbr_pair/body/mesh``)."""
    (part,) = [p for p in read_model(path).parts if name in p.name]
    return part


@pytest.mark.parametrize("path", [GLB, USDZ], ids=["glb", "usdz"])
def test_units_up_axis_and_hierarchy_give_the_generators_world(path):
    """Every vertex lies on its sphere, centred where the generator's constants put it.
    Rejects: USD's metersPerUnit ignored (100× too large), upAxis ignored (y and z swapped),
    the glTF root node's rotation dropped (centres at x = 0), a column-/row-major mix-up."""
    for part, c, r in ((_part(path, "body"), BODY_CENTRE, BODY_R),
                       (_part(path, "ball"), BALL_CENTRE, BALL_R)):
        d = np.linalg.norm(part.vertices - c, axis=1)
        assert np.allclose(d, r, atol=2e-6), (part.name, d.min(), d.max())
        # file normals are the outward sphere normals, turned with the nodes
        assert np.allclose(part.normals, (part.vertices - c) / r, atol=1e-5)


def test_usd_st_is_flipped_to_the_top_left_origin():
    """USD's ``st`` has its origin at the bottom left; arlight (glTF, Mitsuba) at the top
    left: v must be θ/π (0 at the sphere's top, +Y), as the generator's glTF has it.
    Rejects: ``st`` used unflipped (v = 1 − θ/π)."""
    for path in (GLB, USDZ):
        body = _part(path, "body")
        y = (body.vertices[:, 1] - BODY_CENTRE[1]) / BODY_R
        theta = np.arccos(np.clip(y, -1, 1))
        assert np.allclose(body.uv[:, 1], theta / np.pi, atol=1e-5), path.name


def test_textures_decode_as_gltf_defines_and_reach_principled_channels():
    """Base colour: sRGB-decoded (computed here from the PNG's codes with the IEC formula);
    metallic-roughness: G is roughness, B metallic, times the factors, linear.
    Rejects: no sRGB decode, G and B swapped, factors not multiplied."""
    from arlight.backend.mitsuba_scene import describe_material
    from arlight.scene.model import Material

    codes = np.asarray(Image.open(HAND / "base_color.png").convert("RGB"), np.float64) / 255
    srgb = np.where(codes <= 0.04045, codes / 12.92, ((codes + 0.055) / 1.055) ** 2.4)
    mr = np.asarray(Image.open(HAND / "metallic_roughness.png").convert("RGB"),
                    np.float64) / 255
    for path in (GLB, USDZ):
        body = _part(path, "body")
        tex = body.material["base_color_texture"].pixels
        assert np.allclose(tex[..., :3], srgb, atol=1e-6), path.name
        params = {**body.material, "roughness": 0.5, "metallic": 0.8}
        node = describe_material(Material("m", "pbr", params))
        node = node["bsdf"]["bsdf"]  # twosided -> normalmap -> principled
        assert node["type"] == "principled"
        assert np.allclose(node["roughness"]["bitmap"][..., 0], 0.5 * mr[..., 1], atol=1e-6)
        assert np.allclose(node["metallic"]["bitmap"][..., 0], 0.8 * mr[..., 2], atol=1e-6)


def test_alpha_transmission_and_normal_scale_nodes():
    """``mask`` thresholds alpha at the cutoff, ``blend`` keeps it; transmission drops the
    two-sided wrapper (Mitsuba refuses twosided around a transmissive BSDF) and sets
    spec_trans and eta; ``normal_scale`` scales the map's x, y.
    Rejects: mask mode passed through unthresholded, transmission ignored."""
    from arlight.backend.mitsuba_scene import describe_material
    from arlight.scene.model import Material
    from arlight.scene.pbr import Texture, default_params

    rgba = np.zeros((2, 2, 4), np.float32)
    rgba[..., 3] = [[0.2, 0.6], [0.5, 0.9]]
    p = {**default_params(), "base_color_texture": Texture("t", rgba), "alpha": 1.0,
         "alpha_mode": "mask", "alpha_cutoff": 0.55}
    node = describe_material(Material("m", "pbr", p))
    assert node["type"] == "mask"
    assert np.array_equal(node["opacity"]["bitmap"][..., 0], [[0, 1], [0, 1]])
    node = describe_material(Material("m", "pbr", {**p, "alpha_mode": "blend", "alpha": 0.5}))
    assert np.allclose(node["opacity"]["bitmap"][..., 0], 0.5 * rgba[..., 3])
    glass = describe_material(Material("m", "pbr", {**default_params(), "transmission": 0.9,
                                                    "ior": 1.33, "metallic": 0.0}))
    assert glass["type"] == "principled"
    assert (glass["spec_trans"], glass["eta"]) == (0.9, 1.33)
    tilted = np.array([[[0.75, 0.5, 1.0]]], np.float32)  # n = 2c − 1 = (0.5, 0, 1)
    node = describe_material(Material("m", "pbr", {**default_params(),
                                                   "normal_texture": Texture("n", tilted),
                                                   "normal_scale": 2.0}))
    n = 2 * node["bsdf"]["normalmap"]["bitmap"][0, 0] - 1
    assert np.allclose(n, np.array([1.0, 0, 1]) / np.sqrt(2), atol=1e-6)


def test_select_a_node_or_prim():
    """``select`` keeps one node (glTF name) or prim subtree (USD path), with its parents'
    transforms. Rejects: the selection ignored, the parents' transforms dropped."""
    for path, sel in ((GLB, "ball"), (USDZ, "/pbr_pair/ball")):
        parts = read_model(path, sel).parts
        assert len(parts) == 1
        d = np.linalg.norm(parts[0].vertices - BALL_CENTRE, axis=1)
        assert np.allclose(d, BALL_R, atol=2e-6)
    with pytest.raises(InputError, match="no node named 'nope'"):
        read_model(GLB, "nope")


def test_model_entry_expands_poses_and_saves_as_one(tmp_path):
    """A model entry becomes one mesh shape per part, named ``<entry>/<part>``; an object
    transform by the entry's name moves every part; saving writes one ``type = "model"``
    entry that loads back to the same geometry. Rejects: parts left behind by a pose, the
    saved scene inlining parts (or losing the node transforms on reload)."""
    from arlight.scene.save import save_scene

    d = _scene(_model(GLB, transform={"translate": [0.1, 0, 0]}))
    d["frame"] = {"object_transforms": {"obj": {"translate": [0, 0.2, 0]}}}
    scene = parse_scene(d, tmp_path)
    parts = [s for s in scene.shapes if s.group == "obj"]
    assert len(parts) == 2 and all(s.name.startswith("obj/") for s in parts)
    assert all(s.type == "mesh" and s.material.type == "pbr" for s in parts)
    for s in parts:
        assert np.allclose(s.to_world[:3, 3], [0.1, 0.2, 0])
    out = save_scene(scene, tmp_path / "saved.toml")
    text = out.read_text()
    assert text.count('type = "model"') == 1 and "pbr_pair.glb" in text
    again = parse_scene(__import__("tomllib").loads(text), tmp_path)
    for a, b in zip(parts, [s for s in again.shapes if s.group == "obj"], strict=True):
        assert a.name == b.name
        assert np.array_equal(a.mesh.vertices, b.mesh.vertices)
        assert np.allclose(a.to_world, b.to_world)


def test_real_time_methods_state_why_they_skip_pbr():
    """Every real-time method but ``ibl`` refuses a pbr object with a reason naming the
    material type (shown by ``arlight methods``); the path tracers and ``ibl`` accept it.
    Rejects: a method that renders pbr silently as its default material."""
    from arlight.methods import get_method

    scene = parse_scene(_scene(_model(GLB)))
    for name in ("dlpv", "dir", "dvct", "prt", "probeless", "nearfield"):
        reason = get_method(name).spec.unsupported_reason(scene)
        assert reason is not None and "pbr" in reason, (name, reason)
    for name in ("reference", "onepass", "dic", "ibl"):
        assert get_method(name).spec.unsupported_reason(scene) is None, name


# ------------------------------------------------------------------ bad input

def _error(path, select=None) -> str:
    with pytest.raises(InputError) as exc:
        read_model(path, select)
    text = str(exc.value)
    assert "\n" not in text and str(path) in text
    return text


@pytest.mark.parametrize("kind, kw, needle", [
    ("draco", {"extension": "KHR_draco_mesh_compression"}, "KHR_draco_mesh_compression"),
    ("ktx2", {"extension": "KHR_texture_basisu"}, "textures[0].extensions.KHR_texture_basisu"),
    ("required", {"required": "EXT_foo"}, "extensionsRequired"),
    ("missing_texture", {"image_uri": "nope.png"}, "images[0].uri"),
    ("degenerate", {"degenerate": True}, "degenerate"),
    ("nonmanifold", {"nonmanifold": True}, "non-manifold"),
    ("huge_scale", {"node_scale": 1e6}, "scale"),
    ("tiny_scale", {"scale": 1e-6}, "scale"),
])
def test_bad_gltf_is_one_line_naming_file_and_field(tmp_path, kind, kw, needle):
    path = gltf(tmp_path / f"{kind}.gltf", **kw)
    assert needle in _error(path)


def test_huge_texture_is_refused_from_its_header(tmp_path):
    """A 5000×5000 texture is refused before decoding: the PNG holds only a header (a
    decoder would fail on it differently). Rejects: decoding first, no size bound."""
    png_header_only(tmp_path / "huge.png", 5000, 5000)
    text = _error(gltf(tmp_path / "huge.gltf", image_uri="huge.png"))
    assert "5000×5000" in text and "images[0]" in text


def test_huge_texture_in_a_scene_file_is_refused_from_its_header(tmp_path):
    png_header_only(tmp_path / "huge.png", 5000, 5000)
    with pytest.raises(InputError, match=r"shapes\[0\].material.base_color_texture.*5000×5000"):
        parse_scene({"shapes": [{"role": "virtual", "type": "sphere",
                                 "material": {"type": "pbr",
                                              "base_color_texture": "huge.png"}}]}, tmp_path)


@pytest.mark.parametrize("kw, where", [({"skin": True}, "nodes[0].skin"),
                                        ({"morph": True}, "targets"),
                                        ({"animation": True}, "animations")])
def test_skin_morph_animation_load_the_static_pose_with_a_warning(tmp_path, kw, where):
    with pytest.warns(ModelWarning, match=re.escape(where)):
        model = read_model(gltf(tmp_path / "a.glb", **kw))
    assert np.allclose(model.parts[0].vertices[:3], [[0, 0, 0], [1, 0, 0], [0, 1, 0]])


def test_usd_bad_input(tmp_path):
    """A missing UsdUVTexture file, a kilometre unit making a 100 km object, garbage."""
    assert "inputs:file" in _error(usda(tmp_path / "t.usda", texture="nope.png"))
    assert "scale" in _error(usda(tmp_path / "km.usda", meters_per_unit=1000.0, size=100.0))
    (tmp_path / "g.usdz").write_bytes(b"PK garbage")
    _error(tmp_path / "g.usdz")


def test_usd_centimetres_z_up_convert_to_metres_y_up(tmp_path):
    """A Z-up centimetre triangle (50 cm along USD +x and +y): USD +y becomes arlight −z."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        part = read_model(usda(tmp_path / "cm.usda", meters_per_unit=0.01, up="Z",
                               size=50.0)).parts[0]
    assert np.allclose(part.vertices, [[0, 0, 0], [0.5, 0, 0], [0, 0, -0.5]], atol=1e-7)


# ------------------------------------------------------------------ acceptance render

@pytest.fixture(scope="module")
def ground_truth():
    """Mitsuba's own ``path`` integrator on the hand-written pair, built with Mitsuba's own
    PLY and PNG loaders (its sRGB decoding, its UV reading), 32 × 8 spp batches: mean and
    standard error per pixel."""
    import mitsuba as mi

    from arlight.backend.mitsuba_scene import mitsuba_sensor
    from arlight.jit import ensure_variant

    ensure_variant()

    def channel(c: int) -> dict:
        a = np.asarray(Image.open(HAND / "metallic_roughness.png").convert("RGB"),
                       np.float32)[..., c:c + 1] / 255.0
        return {"type": "bitmap", "bitmap": mi.Bitmap(np.ascontiguousarray(a)), "raw": True}

    def twosided(b: dict) -> dict:
        return {"type": "twosided", "bsdf": b}

    scene = mi.load_dict({
        "type": "scene", "integrator": {"type": "path", "max_depth": 6},
        "table": {"type": "rectangle", "to_world": mi.ScalarTransform4f().rotate(
            [1, 0, 0], -90).scale([0.5, 0.5, 1]), "bsdf": twosided(
            {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.5] * 3}})},
        "body": {"type": "ply", "filename": str(HAND / "body.ply"), "bsdf": twosided({
            "type": "normalmap",
            "normalmap": {"type": "bitmap", "filename": str(HAND / "normal.png"), "raw": True},
            "bsdf": {"type": "principled",
                     "base_color": {"type": "bitmap",
                                    "filename": str(HAND / "base_color.png")},
                     "roughness": channel(1), "metallic": channel(2)}})},
        "ball": {"type": "ply", "filename": str(HAND / "ball.ply"), "bsdf": twosided({
            "type": "principled", "base_color": {"type": "rgb", "value": GOLD},
            "metallic": 1.0, "roughness": 0.25})},
        "env": {"type": "envmap", "filename": str(ENVMAP)}})
    sensor = mitsuba_sensor(parse_scene(_scene([])).camera, 8)
    b = np.stack([np.array(mi.render(scene, sensor=sensor, spp=8, seed=500 + i))[..., :3]
                  for i in range(32)])
    return b.mean(axis=0), b.std(axis=0, ddof=1) / np.sqrt(len(b))


def test_glb_usdz_and_hand_written_render_alike_and_like_ground_truth(ground_truth):
    """Acceptance (issue #34): the GLB, the USDZ and the hand-written scene, rendered by
    ``reference``, agree with each other and with the independent ground truth within
    3 SE on ≥ 99 % of pixels, and on the object's own pixels the mean differs by < 3 SE.
    Rejects (each tried by patching, measured against the ground truth or the other files):
    no sRGB decode of the base colour (object mean +70 SE), G/B channels swapped (−60 SE),
    the normal map dropped (+13 SE, 95 % of object pixels), USD's up axis ignored (40 % of
    object pixels). The st flip has its own test above."""
    from arlight.methods import RenderSettings, get_method
    from arlight.stats import agreement_fraction

    gt, gt_se = ground_truth
    ref = get_method("reference")
    runs = {}
    for i, (name, shapes) in enumerate((("hand", HAND_SHAPES), ("glb", _model(GLB)),
                                         ("usdz", _model(USDZ)))):
        scene = parse_scene(_scene(shapes))
        scene = scene.with_frame(np.full((48, 64, 3), 0.25, np.float32))
        r = ref(scene, RenderSettings(spp=64, max_depth=6, seed=11 + i))
        runs[name] = (r.mixed, r.stderr["mixed"], r.stats["stderr_dof"], r.mask)
    mask = runs["hand"][3] > 0.99  # pixels wholly on the object
    assert mask.sum() > 150
    pairs = [("hand", "glb"), ("hand", "usdz"), ("glb", "usdz")]
    report = []
    for a, b in pairs + [(n, "ground truth") for n in runs]:
        ia, sa, da, _ = runs[a]
        ib, sb, db = (gt, gt_se, np.inf) if b == "ground truth" else runs[b][:3]
        frac = agreement_fraction(ia, sa, ib, sb, dof_a=da, dof_b=db)
        frac_obj = agreement_fraction(ia[mask], sa[mask], ib[mask], sb[mask], dof_a=da,
                                      dof_b=db)
        diff = ia[mask].mean() - ib[mask].mean()
        se = np.sqrt((sa[mask] ** 2).sum() + (sb[mask] ** 2).sum()) / sa[mask].size
        report.append(f"{a} vs {b}: {frac:.4f} of pixels, {frac_obj:.4f} of object pixels "
                      f"within 3 SE; object mean difference {diff / se:+.2f} SE")
        assert frac >= 0.99 and frac_obj >= 0.99 and abs(diff / se) < 3, report[-1]
    print("\n".join(report))


# ------------------------------------------------------------------ applications

@pytest.mark.parametrize("path", [GLB, USDZ], ids=["glb", "usdz"])
def test_insert_places_a_model_by_its_bottom_centre(path, tmp_path):
    """``insert --object model`` writes a ``type = "model"`` entry (the file's materials,
    no --color) whose parts' bounding box stands with its bottom centre at ``--at``.
    Rejects: a model read through trimesh (no node transforms, no units: the box lands
    elsewhere), a diffuse material forced onto it."""
    from arlight.insert.pipeline import InsertRequest, _object_shape

    req = InsertRequest(photo=tmp_path / "p.png", calib=tmp_path / "c.json", marker="m",
                        light="sun:0,1,0:1", object=path, at=(0.1, 0.0, 0.2), scale=2.0)
    table, _ = _object_shape(req)
    assert table["type"] == "model" and "material" not in table
    scene = parse_scene(_scene([table]))
    v = np.concatenate([s.mesh.vertices @ s.to_world[:3, :3].T + s.to_world[:3, 3]
                        for s in scene.virtual_shapes])
    lo, hi = v.min(axis=0), v.max(axis=0)
    assert np.allclose([(lo[0] + hi[0]) / 2, lo[1], (lo[2] + hi[2]) / 2], [0.1, 0.0, 0.2],
                       atol=1e-5)
    # the pair is 18 cm along x (body left edge -8 cm to ball right edge +10 cm), scaled 2×
    assert np.isclose(hi[0] - lo[0], 0.36, atol=1e-4)


def test_studio_lists_a_model_as_one_object():
    """The studio's object list has the model entry, not its parts, so dragging it moves
    the whole object. Rejects: one studio object per part (the parts drift apart)."""
    from arlight.studio.picking import Proxy

    scene = parse_scene(_scene(_model(GLB)))
    proxy = Proxy(scene)
    assert proxy.virtual_names == ["obj"]
    anchor = proxy.rest_poses()["obj"]
    assert anchor is not None
    # the object's anchor is the base centre of both parts together (x from -8 to 10 cm)
    assert np.isclose(proxy.anchors["obj"][0], 0.01, atol=1e-3)


def test_onepass_renders_a_pbr_model_like_reference():
    """``onepass`` (Kán's one-pass rules, its own integrator) on the GLB agrees with
    ``reference`` within 3 SE (composite, and on the object's pixels): catches one-pass
    rules that handle the principled BSDF (glossy, normal-mapped, two-sided) differently
    from Mitsuba's path tracer (not tried by mutation: onepass is another issue's).
    ``dic`` is biased by design (irradiance caching) and agrees with ``reference`` on this
    scene as well as on the same scene with diffuse/roughconductor materials (96 % of
    pixels, measured by hand), so it is not tested here."""
    from arlight.methods import RenderSettings, get_method
    from arlight.stats import agreement_fraction

    scene = parse_scene(_scene(_model(GLB))).with_frame(np.full((48, 64, 3), 0.25,
                                                                np.float32))
    ref = get_method("reference")(scene, RenderSettings(spp=32, max_depth=6, seed=3))
    one = get_method("onepass")(scene, RenderSettings(spp=32, max_depth=6, seed=4))
    mask = ref.mask > 0.99
    kw = {"dof_a": one.stats["stderr_dof"], "dof_b": ref.stats["stderr_dof"]}
    a, sa = one.composite, one.stderr["composite"]
    b, sb = ref.composite, ref.stderr["composite"]
    assert agreement_fraction(a, sa, b, sb, **kw) >= 0.99
    assert agreement_fraction(a[mask], sa[mask], b[mask], sb[mask], **kw) >= 0.99


def test_hand_written_pbr_saves_its_texture_paths(tmp_path):
    """A scene file's pbr textures are decoded on load and written back as their files
    (relative to the saved scene). Rejects: decoded pixels written into the TOML, absolute
    paths where a relative one fits, the texture lost on reload."""
    import shutil

    from arlight.scene.save import save_scene

    for name in ("body.ply", "base_color.png", "normal.png", "metallic_roughness.png"):
        shutil.copy(HAND / name, tmp_path / name)
    shapes = [dict(HAND_SHAPES[0], file="body.ply", material={
        "type": "pbr", "base_color_texture": "base_color.png", "normal_texture": "normal.png",
        "roughness": 0.4})]
    scene = parse_scene(_scene(shapes), tmp_path)
    text = save_scene(scene, tmp_path / "saved.toml").read_text()
    assert 'base_color_texture = "base_color.png"' in text
    again = parse_scene(__import__("tomllib").loads(text), tmp_path)
    a, b = scene.shapes[1].material.params, again.shapes[1].material.params
    assert np.array_equal(a["base_color_texture"].pixels, b["base_color_texture"].pixels)
    assert a["roughness"] == b["roughness"] == 0.4


def _ibl_and_reference(shapes: list[dict]):
    from arlight.methods import RenderSettings, get_method

    scene = parse_scene(_scene(shapes)).with_frame(np.full((48, 64, 3), 0.25, np.float32))
    settings = RenderSettings(spp=16, max_depth=6, seed=3)
    return get_method("ibl")(scene, settings), get_method("reference")(scene, settings)


def test_ibl_approximates_pbr_as_diffuse_plus_ggx():
    """``ibl`` shades pbr as one diffuse and one GGX lobe: a metallic pbr has no diffuse
    lobe, α = roughness² and Schlick F0 = its base colour (F90 = 1, as Mitsuba's
    ``principled``; a ``roughconductor`` has F90 = its reflectance, so the two no longer
    render identically since the split sum); on the textured pair its error against
    ``reference`` (object pixels' mean) is no larger than ibl's own error on the same scene
    with diffuse (textured) + roughconductor materials (ibl's approximations). Rejects:
    α = roughness (not squared), the base colour's diffuse left on for metals, a metal's F0
    not its base colour, a metal shaded without its GGX lobe. Not rejected (tried): the
    dielectric 4 % F0 dropped — it lies within ibl's own error here."""
    from arlight.realtime.ibl_shading import pbr_lobes

    ball = parse_scene(_scene(_model(GLB, select="ball"))).world.virtual_shapes[0]
    assert ball.material.type == "pbr" and ball.material.params["metallic"] == 1.0
    diffuse, alpha, f0 = pbr_lobes(ball.material.params)
    assert diffuse == 0.0 and alpha == pytest.approx(0.25 ** 2)
    assert np.allclose(f0, GOLD, atol=2e-3)
    ibl, ref = _ibl_and_reference(_model(GLB))
    substitute = [dict(HAND_SHAPES[0], material={"type": "diffuse",
                                                  "texture": str(HAND / "base_color.png")}),
                  dict(HAND_SHAPES[1], material={"type": "roughconductor",
                                                  "alpha": 0.25 ** 2, "reflectance": GOLD})]
    ibl0, ref0 = _ibl_and_reference(substitute)
    mask = ref.mask > 0.99
    err = np.abs(ibl.mixed[mask].mean(0) / ref.mixed[mask].mean(0) - 1)
    err0 = np.abs(ibl0.mixed[mask].mean(0) / ref0.mixed[mask].mean(0) - 1)
    # split sum: pbr's grazing Fresnel rises to 1 (F90), the substitute's stays at its
    # reflectance, so the two approximations differ by a few per cent (measured 0.18–0.19
    # against 0.13–0.15); a metal without its GGX lobe or with its diffuse lobe on is off
    # by far more
    assert np.all(err <= err0 + 0.06), (err, err0)


def test_sequence_moves_a_model_by_its_entry_name(tmp_path):
    """``arlight sequence --objects`` may name a model entry: every part gets the frame's
    motion. Rejects: the name refused as unknown (the check knew only part names), or
    only one part moved."""
    import json

    from arlight.methods import RenderSettings
    from arlight.scene.load import load_scene
    from arlight.scene.model import ARScene
    from arlight.sequence.build import build_job
    from arlight.sequence.frames import FrameSource
    from tests.sequence.conftest import make_tiny

    tiny = make_tiny(tmp_path / "tiny", n=3)
    d = json.loads(tiny.scene.read_text())
    d["shapes"] = [s for s in d["shapes"] if s["name"] != "ball"]
    d["shapes"].append({"name": "ball", "role": "virtual", "type": "model", "file": str(GLB),
                        "transform": {"scale": 3.0, "translate": [0.15, 0.0, 0.1]}})
    tiny.scene.write_text(json.dumps(d))
    scene = load_scene(tiny.scene)
    src = FrameSource(tiny.frames)
    job = build_job(scene, src, "reference", RenderSettings(spp=1), poses=tiny.poses,
                    objects=tiny.objects)
    frame = list(src)[2]
    posed = ARScene.compose(scene.world, job.view(frame))
    moved = [p.to_world for p in posed.shapes if p.group == "ball"]
    rest = [s.to_world for s in scene.shapes if s.group == "ball"]
    assert len(moved) == 2
    assert all(not np.allclose(m, r) for m, r in zip(moved, rest, strict=True))
    assert np.allclose(moved[0], moved[1])
