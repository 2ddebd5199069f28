"""Scene files: valid scenes load; bad input names the file and the field."""

import json
import math

import numpy as np
import pytest
import trimesh

from arlight.errors import InputError
from arlight.io.images import write_exr, write_png
from arlight.scene.load import load_scene, parse_scene
from tests.conftest import area_light_scene


def write_scene(tmp_path, d, name="scene.json"):
    p = tmp_path / name
    p.write_text(json.dumps(d))
    return p


def test_area_light_scene_loads():
    sc = parse_scene(area_light_scene())
    assert [s.role for s in sc.shapes] == ["real", "real", "real", "virtual"]
    assert sc.has_virtual and len(sc.virtual_shapes) == 1
    assert sc.camera.width == 40 and sc.camera.height == 30
    # rectangle normal [0,1,0] rotates local +z onto +y
    floor = sc.shapes[0]
    assert np.allclose(floor.to_world[:3, :3] @ [0, 0, 1], [0, 1, 0])


def test_toml_scene_with_frame_and_mesh(tmp_path):
    trimesh.creation.box().export(tmp_path / "box.ply")
    write_png(tmp_path / "frame.png", np.full((6, 8, 3), 128, np.uint8))
    (tmp_path / "s.toml").write_text("""
[camera]
resolution = [8, 6]
intrinsics = { fx = 10.0, fy = 10.0, cx = 4.0, cy = 3.0 }
world_from_camera = [[1,0,0,0],[0,-1,0,1],[0,0,-1,3],[0,0,0,1]]
[frame]
image = "frame.png"
[[shapes]]
role = "virtual"
type = "mesh"
file = "box.ply"
transform = { scale = 0.5, rotate = [[0,1,0,45]], translate = [0, 0.25, 0] }
[[lights]]
type = "point"
position = [0, 2, 0]
intensity = 5.0
""")
    sc = load_scene(tmp_path / "s.toml")
    assert sc.frame.shape == (6, 8, 3) and sc.frame_codes.dtype == np.uint8
    assert sc.shapes[0].mesh.faces.shape == (12, 3)
    assert sc.lights[0].params["intensity"] == [5.0] * 3


def _expect_error(tmp_path, d, field_part, message_part):
    p = write_scene(tmp_path, d)
    with pytest.raises(InputError) as err:
        load_scene(p)
    text = str(err.value)
    assert str(p) in text, text
    assert field_part in text and message_part in text, text
    return err.value


def test_missing_file_is_named(tmp_path):
    with pytest.raises(InputError, match="scene file not found"):
        load_scene(tmp_path / "nope.toml")
    d = area_light_scene()
    d["shapes"][0] = {"role": "real", "type": "mesh", "file": "missing.ply"}
    _expect_error(tmp_path, d, "shapes[0].file", "file not found")


def test_unknown_material_type(tmp_path):
    d = area_light_scene()
    d["shapes"][1]["material"] = {"type": "velvet"}
    _expect_error(tmp_path, d, "shapes[1].material.type", "unknown material type 'velvet'")


def test_unknown_material_name(tmp_path):
    d = area_light_scene()
    d["shapes"][1]["material"] = "marble"
    _expect_error(tmp_path, d, "shapes[1].material", "unknown material 'marble'")


def test_unknown_light_type(tmp_path):
    d = area_light_scene()
    d["lights"].append({"type": "laser"})
    _expect_error(tmp_path, d, "lights[1].type", "unknown light type 'laser'")


def test_wrong_value_types(tmp_path):
    d = area_light_scene()
    d["shapes"][3]["radius"] = "big"
    _expect_error(tmp_path, d, "shapes[3].radius", "expected a number")
    d = area_light_scene()
    d["camera"]["resolution"] = [40]
    _expect_error(tmp_path, d, "camera.resolution", "list of 2 numbers")
    d = area_light_scene()
    d["shapes"][0]["role"] = "imaginary"
    _expect_error(tmp_path, d, "shapes[0].role", "unknown value 'imaginary'")
    d = area_light_scene()
    d["shapes"][0]["colour"] = 1
    _expect_error(tmp_path, d, "shapes[0].colour", "unknown field")


def test_negative_radiance_rejected(tmp_path):
    d = area_light_scene()
    d["lights"][0]["radiance"] = [1.0, -2.0, 1.0]
    _expect_error(tmp_path, d, "lights[0].radiance", "negative value")
    d = area_light_scene()
    write_exr(tmp_path / "env.exr", np.full((8, 16, 3), -1.0, np.float32))
    d["lights"] = [{"type": "envmap", "file": "env.exr"}]
    _expect_error(tmp_path, d, "lights[0].file", "negative radiance")


def test_nan_pixels_in_hdr_frame(tmp_path):
    img = np.ones((30, 40, 3), np.float32)
    img[3, 4, 1] = math.nan
    img[5, 6, 0] = math.inf
    write_exr(tmp_path / "frame.exr", img)
    d = area_light_scene()
    d["frame"] = {"image": "frame.exr"}
    _expect_error(tmp_path, d, "frame.image", "2 NaN/Inf values")


def test_frame_size_must_match_camera(tmp_path):
    write_png(tmp_path / "frame.png", np.zeros((31, 40, 3), np.uint8))
    d = area_light_scene()
    d["frame"] = {"image": "frame.png"}
    _expect_error(tmp_path, d, "frame.image", "image is 40×31 but the camera resolution is "
                                              "40×30")


def test_mesh_without_faces(tmp_path):
    (tmp_path / "empty.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    d = area_light_scene()
    d["shapes"].append({"role": "virtual", "type": "mesh", "file": "empty.obj"})
    _expect_error(tmp_path, d, "shapes[4].file", "has no faces")


def test_phong_energy_conservation(tmp_path):
    d = area_light_scene()
    d["shapes"][3]["material"] = {"type": "phong", "kd": 0.7, "ks": 0.5}
    _expect_error(tmp_path, d, "shapes[3].material.ks", "must not exceed 1")


def test_toml_syntax_error_named(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text("[camera\nresolution = 1")
    with pytest.raises(InputError, match="syntax error"):
        load_scene(p)


def test_camera_needs_exactly_one_pose_and_projection(tmp_path):
    d = area_light_scene()
    d["camera"]["intrinsics"] = {"fx": 1, "fy": 1, "cx": 0, "cy": 0}
    _expect_error(tmp_path, d, "camera", "exactly one of `fov_y_deg` and `intrinsics`")


@pytest.mark.parametrize("suffix", ["ply", "obj", "glb", "stl", "off"])
def test_mesh_formats(tmp_path, suffix):
    trimesh.creation.icosphere(subdivisions=1).export(tmp_path / f"m.{suffix}")
    d = area_light_scene()
    d["shapes"].append({"role": "virtual", "type": "mesh", "file": f"m.{suffix}"})
    sc = parse_scene(d, base_dir=tmp_path)
    assert sc.shapes[-1].mesh.faces.shape == (80, 3)
