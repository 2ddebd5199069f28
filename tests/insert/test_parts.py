"""The parts of ``arlight insert``: target and calibration parsing, light tables, the
irradiance model the albedo rests on (checked against Mitsuba's own render)."""

from __future__ import annotations

import json

import numpy as np
import pytest

import arlight
from arlight.errors import InputError
from arlight.insert.albedo import PlaneRegion, estimate_albedo
from arlight.insert.lighting import light_tables, plane_irradiance
from arlight.insert.proxy import parse_box, plane_shape
from arlight.insert.registration import (
    WORLD_FROM_BOARD,
    Calibration,
    load_calibration,
    parse_marker,
)
from arlight.scene.load import parse_scene
from arlight.synthetic import synthesize

DEMO = arlight.__file__.replace("__init__.py", "data/demo/")


def test_board_frame_is_a_rotation_with_up_out_of_the_board():
    """Rejects a reflection (det −1) or a frame whose up is the board's +z (into the table)."""
    r = WORLD_FROM_BOARD[:3, :3]
    np.testing.assert_allclose(r @ r.T, np.eye(3))
    assert np.linalg.det(r) == pytest.approx(1.0)
    np.testing.assert_allclose(r @ [0, 0, -1], [0, 1, 0])  # out of the board = up


def test_marker_forms(tmp_path):
    """The inline and TOML forms give the same target; bad ones name the field or file.
    Rejects: squares read as (rows, cols), a TOML error without the file's name."""
    m = parse_marker("charuco:5x7:0.04:0.02:DICT_6X6_250")
    assert m.squares == (5, 7) and m.extent == pytest.approx((0.2, 0.28))
    f = tmp_path / "board.toml"
    f.write_text('type = "charuco"\nsquares = [5, 7]\nsquare_length = 0.04\n'
                 'marker_length = 0.02\ndictionary = "DICT_6X6_250"\n')
    assert parse_marker(str(f)) == m
    a = parse_marker("aruco:0.05:DICT_4X4_50:3")
    assert a.kind == "aruco" and a.marker_id == 3
    np.testing.assert_allclose(a.centre_world(), 0)
    for bad in ("charuco:5x7:0.02:0.04:DICT_6X6_250", "charuco:1x7:0.04:0.02:DICT_6X6_250",
                "qr:1", "aruco:-1:DICT_4X4_50"):
        with pytest.raises(InputError, match="--marker"):
            parse_marker(bad)
    f.write_text('type = "charuco"\ncolour = 1\n')
    with pytest.raises(InputError, match="board.toml: colour"):
        parse_marker(str(f))


def test_calibration_files_and_size_check(tmp_path):
    """JSON and OpenCV YAML read the same; a photo of another size is refused naming the
    calibration file. Rejects: a size check that passes any resolution."""
    import cv2

    K = np.array([[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])
    (tmp_path / "c.json").write_text(json.dumps({"K": K.tolist(), "dist": [0.1, 0, 0, 0, 0],
                                                 "size": [640, 480]}))
    fs = cv2.FileStorage(str(tmp_path / "c.yml"), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 640)
    fs.write("image_height", 480)
    fs.write("camera_matrix", K)
    fs.write("distortion_coefficients", np.array([[0.1, 0, 0, 0, 0]]))
    fs.release()
    a, b = load_calibration(tmp_path / "c.json"), load_calibration(tmp_path / "c.yml")
    np.testing.assert_allclose(a.K, b.K)
    np.testing.assert_allclose(a.dist, b.dist)
    assert a.size == b.size == (640, 480)
    a.check_size(640, 480, "p.png")
    with pytest.raises(InputError, match="c.yml: image_width: calibrated for 640×480"):
        b.check_size(1280, 960, "p.png")
    with pytest.raises(InputError, match="principal point"):
        Calibration(K=K, dist=np.zeros(5), size=None, source="x").check_size(160, 120, "p")


def test_light_tables_rotate_like_an_envmap(tmp_path):
    """A LightEstimate's main light turned by ``rotation_deg`` about +Y goes where an
    envmap's ``rotation_deg`` takes the same direction (+X → −Z at 90°); the inline sun is
    the direction *towards* the sun. Rejects a rotation of the opposite sense, a sun whose
    direction is not negated into the travel direction."""
    from arlight.light.estimate import LightEstimate

    est = LightEstimate(main_direction=np.array([1.0, 0, 0]), main_irradiance=np.ones(3))
    est.save(tmp_path / "e.json")
    tabs = light_tables(str(tmp_path / "e.json"), rotation_deg=90.0)
    sun = next(t for t in tabs if t["type"] == "directional")
    np.testing.assert_allclose(sun["direction"], [0, 0, 1], atol=1e-12)  # travels to +Z
    tabs = light_tables("sun:0,1,0:2:0.5", scale=2.0)
    assert tabs[0]["direction"] == [-0.0, -1.0, -0.0] and tabs[0]["irradiance"] == [4.0] * 3
    assert tabs[1] == {"type": "constant", "radiance": [1.0] * 3}


def test_plane_irradiance_matches_mitsuba(tmp_path):
    """π·L/E of a grey plane (albedo 0.5) rendered by Mitsuba (:mod:`arlight.synthetic`)
    under a rotated HDR panorama plus a spot light is 0.5 within 3 %: the irradiance model
    behind the albedo (cosine-weighted upper hemisphere of the map, the spot's I·cos/r²) is
    Mitsuba's. Rejects the map's irradiance off by 2×, the lower hemisphere counted in, a
    spot without its 1/r²."""
    lights = [{"type": "envmap", "file": DEMO + "lebombo_512x256.hdr", "rotation_deg": 37.0},
              {"type": "spot", "position": [0.1, 0.6, 0.0], "target": [0, 0, 0],
               "intensity": [0.3, 0.3, 0.3], "cutoff_deg": 60.0, "beam_width_deg": 50.0}]
    d = {"camera": {"resolution": [16, 12], "fov_y_deg": 30,
                    "look_at": {"origin": [0, 0.8, 0.5], "target": [0, 0, 0]}},
         "shapes": [plane_shape((-1, -1), (1, 1), {"type": "diffuse", "albedo": [0.5] * 3})],
         "lights": lights}
    scene = parse_scene(d, tmp_path)
    photo = synthesize(scene, spp=256, batches=16, cache_dir=tmp_path)
    region = PlaneRegion((-1, -1), (1, 1), (5, 5), (6, 6))  # no target in view
    est = estimate_albedo(photo.frame, scene.camera, scene.lights, region, mode="median")
    np.testing.assert_allclose(est.median, 0.5, rtol=0.03)
    assert plane_irradiance(scene.lights, np.zeros((1, 3))).shape == (1, 3)


def test_box_spec():
    """Rejects sizes of zero and albedo beyond 1."""
    b = parse_box("0.1,0.05,0.2:0.1,0.1,0.1:0.5,0.4,0.3")
    assert b.table(0, np.ones(3))["material"]["albedo"] == [0.5, 0.4, 0.3]
    for bad in ("0,0,0:0,1,1", "0,0,0:1,1,1:2,0,0", "1,2:1,1,1"):
        with pytest.raises(InputError, match="--box"):
            parse_box(bad)


def test_light_rig_file_is_read_by_the_schema_validator(tmp_path):
    """A ``--light`` rig (``.toml``) goes through the scene schema's Validator: errors name
    the file and the field (``sun[0].irradiance``, ``spot[0].cutoff_deg``), a spot has the
    scene's ``spot`` fields and defaults. Rejects the former hand checks, which reported a
    missing key as ``missing or malformed value (KeyError(...))`` without the field."""
    from arlight.insert.lighting import light_tables

    f = tmp_path / "rig.toml"
    f.write_text("ambient = 0.2\n[[sun]]\ndirection = [0, 1, 0]\nirradiance = 2\n"
                 "[[spot]]\nposition = [0, 2, 0]\ntarget = [0, 0, 0]\nintensity = 5\n")
    sun, spot, amb = light_tables(str(f))
    assert sun == {"type": "directional", "direction": [-0.0, -1.0, -0.0],
                   "irradiance": [2.0, 2.0, 2.0]}
    assert spot["type"] == "spot" and spot["cutoff_deg"] == 20.0 and spot["intensity"] == [5.0] * 3
    assert amb == {"type": "constant", "radiance": [0.2] * 3}
    for text, field in [("[[sun]]\ndirection = [0, 1, 0]\n", "sun[0].irradiance"),
                        ("[[sun]]\ndirection = [0, 0, 0]\nirradiance = 1\n", "sun[0].direction"),
                        ("[[spot]]\nposition = [0, 2, 0]\ntarget = [0, 0, 0]\nintensity = 1\n"
                         "cutoff_deg = 120\n", "spot[0].cutoff_deg"),
                        ("ambient = -1\n", "ambient"), ("sky = 1\n", "sky"),
                        ("sun = 3\n", "sun")]:
        f.write_text(text)
        with pytest.raises(InputError) as exc:
            light_tables(str(f))
        assert exc.value.file == str(f) and exc.value.field == field, str(exc.value)
