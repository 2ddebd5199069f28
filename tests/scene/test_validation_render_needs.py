"""Validation that matches what rendering needs (issue 9): images decoded on load, size and
extent caps, every documented form of `rotate`, `two_sided`, the `[render]` table."""

from __future__ import annotations

import json

import numpy as np
import pytest

from arlight.errors import InputError
from arlight.io.images import write_exr, write_png
from arlight.scene.load import parse_scene, read_render_table

CAM = {"resolution": [8, 6], "fov_y_deg": 40,
       "look_at": {"origin": [0, 1, 3], "target": [0, 0, 0]}}


def _scene(**extra) -> dict:
    d = {"camera": dict(CAM), "shapes": [{"role": "real", "type": "rectangle",
                                          "normal": [0, 1, 0]}]}
    d.update(extra)
    return d


def _fails(d: dict, field: str, match: str = "", base=".") -> None:
    with pytest.raises(InputError) as info:
        parse_scene(d, base)
    assert info.value.field == field, (info.value.field, str(info.value))
    assert match in str(info.value)


def test_garbage_texture_fails_on_load_naming_the_field(tmp_path):
    (tmp_path / "bad.png").write_bytes(b"\x89PNG\r\n\x1a\n this is not an image")
    d = _scene()
    d["shapes"][0]["material"] = {"type": "diffuse", "texture": "bad.png"}
    _fails(d, "shapes[0].material.texture", "bad.png", tmp_path)
    d["materials"] = {"wood": {"type": "diffuse", "texture": "bad.png"}}
    d["shapes"][0]["material"] = "wood"
    _fails(d, "materials.wood.texture", "", tmp_path)


def test_envmap_must_be_hdr_and_shaped_for_its_mapping(tmp_path):
    write_png(tmp_path / "ldr.png", np.full((8, 16, 3), 128, np.uint8))
    write_exr(tmp_path / "square.exr", np.ones((16, 16, 3), np.float32))
    write_exr(tmp_path / "wide.exr", np.ones((16, 32, 3), np.float32))
    env = {"type": "envmap"}
    _fails(_scene(lights=[{**env, "file": "ldr.png"}]), "lights[0].file", "HDR", tmp_path)
    _fails(_scene(lights=[{**env, "file": "square.exr"}]), "lights[0].file", "twice",
           tmp_path)
    _fails(_scene(lights=[{**env, "file": "wide.exr", "mapping": "angular"}]),
           "lights[0].file", "square", tmp_path)
    parse_scene(_scene(lights=[{**env, "file": "wide.exr"}]), tmp_path)
    parse_scene(_scene(lights=[{**env, "file": "square.exr", "mapping": "angular"}]), tmp_path)


@pytest.mark.parametrize("where,value,field", [
    ("translate", [1e39, 0, 0], "shapes[0].transform.translate"),
    ("scale", 1e30, "shapes[0].transform.scale"),
    ("scale", 1e-9, "shapes[0].transform.scale"),
    ("matrix", [[1e7, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
     "shapes[0].transform.matrix[0]"),
])
def test_object_extent_caps(where, value, field):
    d = _scene()
    d["shapes"][0]["transform"] = {where: value}
    _fails(d, field, "")


@pytest.mark.parametrize("key,value,field", [
    ("aperture_radius", 1e30, "camera.aperture_radius"),
    ("focus_distance", 1e9, "camera.focus_distance"),
    ("exposure", 1e6, "camera.exposure"),
])
def test_camera_caps(key, value, field):
    d = _scene()
    d["camera"][key] = value
    _fails(d, field, "<=")


def test_camera_origin_and_sizes_capped():
    d = _scene()
    d["camera"]["look_at"] = {"origin": [0, 1e39, 3], "target": [0, 0, 0]}
    _fails(d, "camera.look_at.origin", "<=")
    d = _scene()
    d["shapes"][0]["size"] = [1e7, 1]
    _fails(d, "shapes[0].size", "<=")
    d = _scene(lights=[{"type": "sh", "coefficients": [[1, 1, 1]], "resolution": 10**6}])
    _fails(d, "lights[0].resolution", "<=")


def test_every_rotate_form_gives_the_same_matrix():
    forms = [[0, 1, 0, 30], [[0, 1, 0, 30]], {"axis": [0, 1, 0], "angle": 30},
             [{"axis": [0, 1, 0], "angle": 30}], [[0, 1, 0, 10], {"axis": [0, 2, 0], "angle": 20}]]
    mats = []
    for rot in forms:
        d = _scene()
        d["shapes"][0]["transform"] = {"rotate": rot, "translate": [1, 2, 3]}
        mats.append(parse_scene(d).shapes[0].to_world)
    for m in mats[1:]:
        np.testing.assert_allclose(m, mats[0], atol=1e-12)
    # right-handed: +30° about +y takes +x towards −z (counter-clockwise seen from above)
    x = mats[0][:3, :3] @ np.array([1.0, 0, 0])
    assert x[2] < 0 and x[0] > 0


@pytest.mark.parametrize("rot,field", [
    ({"axis": [0, 1, 0]}, "shapes[0].transform.rotate.angle"),
    ({"axis": [0, 1, 0], "angle": 3, "turns": 1}, "shapes[0].transform.rotate.turns"),
    ([{"axis": [0, 0, 0], "angle": 3}], "shapes[0].transform.rotate[0]"),
    ("x", "shapes[0].transform.rotate"),
])
def test_bad_rotate_forms_name_the_field(rot, field):
    d = _scene()
    d["shapes"][0]["transform"] = {"rotate": rot}
    _fails(d, field)


def test_two_sided_flag_reaches_the_bsdf():
    from arlight.backend.mitsuba_scene import describe_material

    d = _scene()
    d["shapes"][0]["material"] = {"type": "diffuse", "two_sided": False}
    one = parse_scene(d).shapes[0].material
    assert describe_material(one)["type"] == "diffuse"
    d["shapes"][0]["material"] = {"type": "mirror"}
    assert describe_material(parse_scene(d).shapes[0].material)["type"] == "twosided"


def test_render_table_is_validated_and_read(tmp_path):
    d = _scene(render={"method": "onepass", "spp": 16, "max_depth": 3,
                       "options": {"reproject": False}})
    (tmp_path / "r.json").write_text(json.dumps(d))
    (tmp_path / "n.json").write_text(json.dumps(_scene()))
    assert read_render_table(tmp_path / "r.json") == {
        "method": "onepass", "spp": 16, "max_depth": 3, "options": {"reproject": False}}
    assert read_render_table(tmp_path / "n.json") == {}
    _fails(_scene(render={"spp": 0}), "render.spp", ">=")
    _fails(_scene(render={"max_depth": 0}), "render.max_depth")
    _fails(_scene(render={"sample_count": 4}), "render.sample_count", "unknown field")
    _fails(_scene(render={"options": {"a": [1]}}), "render.options.a")


def test_render_settings_precedence_and_frame_option(tmp_path):
    from arlight.scene.load import load_scene, render_settings_for
    from arlight.scene.save import save_scene

    d = _scene(render={"method": "onepass", "spp": 16, "seed": 4,
                       "options": {"reproject": False, "mode": "twopass"}})
    path = save_scene(parse_scene(d), tmp_path / "s.toml")  # [render] survives saving
    got = render_settings_for(path, spp=9, options={"mode": "onepass"})
    assert got == {"method": "onepass", "spp": 9, "max_depth": 8, "seed": 4,
                   "options": {"reproject": False, "mode": "onepass"}}
    write_png(tmp_path / "f.png", np.full((6, 8, 3), 200, np.uint8))
    sc = load_scene(path, frame=tmp_path / "f.png")
    assert sc.frame is not None and sc.frame_codes is not None
    write_png(tmp_path / "small.png", np.full((3, 4, 3), 200, np.uint8))
    with pytest.raises(InputError) as info:
        load_scene(path, frame=tmp_path / "small.png")
    assert info.value.field == "--frame"
