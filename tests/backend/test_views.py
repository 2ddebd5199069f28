"""The µ/ρ views: role filtering, batched ray queries and the envmap convention."""

import numpy as np
import pytest

from arlight.backend.mitsuba_scene import ROLE_REAL, ROLE_VIRTUAL, build_views
from arlight.backend.rays import intersect, visible
from arlight.scene.load import parse_scene


def _plane_and_virtual_box():
    return parse_scene({
        "camera": {"resolution": [4, 4], "fov_y_deg": 40,
                   "look_at": {"origin": [0, 3, 0.01], "target": [0, 0, 0]}},
        "shapes": [
            {"name": "plane", "role": "real", "type": "rectangle", "size": [4, 4],
             "normal": [0, 1, 0]},
            {"name": "vbox", "role": "virtual", "type": "box", "size": [1, 1, 1],
             "transform": {"translate": [0, 1, 0]}},
        ], "lights": []})


def test_real_rays_pass_through_virtual_objects():
    """Kán checklist 1: a real ray through a virtual box reports the real plane behind it."""
    sc = _plane_and_virtual_box()
    views = build_views(sc)
    o = np.array([[0.1, 3.0, 0.2], [1.5, 3.0, 1.5]])
    d = np.array([[0, -1.0, 0], [0, -1.0, 0]])
    real = intersect(views.real, o, d, sc.shapes)
    mixed = intersect(views.mixed, o, d, sc.shapes)
    assert np.allclose(real.t, [3.0, 3.0], atol=1e-5)
    assert list(real.role) == [ROLE_REAL, ROLE_REAL] and list(real.shape) == [0, 0]
    assert np.isclose(mixed.t[0], 1.5, atol=1e-5) and mixed.role[0] == ROLE_VIRTUAL
    assert mixed.shape[0] == 1 and mixed.role[1] == ROLE_REAL
    assert np.allclose(mixed.position[0], [0.1, 1.5, 0.2], atol=1e-5)
    assert np.allclose(mixed.normal[0], [0, 1, 0], atol=1e-5)
    assert list(real.material) == [0, 0]


def test_misses_and_visibility():
    sc = _plane_and_virtual_box()
    views = build_views(sc)
    hits = intersect(views.mixed, np.array([[0, 3.0, 0]]), np.array([[0, 1.0, 0]]))
    assert not hits.hit[0] and hits.role[0] == -1 and hits.shape[0] == -1
    a = np.array([[0, 0.01, 0], [1.8, 0.01, 1.8]])
    b = np.array([[0, 2.5, 0], [1.8, 2.5, 1.8]])
    assert list(visible(views.real, a, b)) == [True, True]
    assert list(visible(views.mixed, a, b)) == [False, True]


def test_no_virtual_objects_shares_one_view():
    sc = _plane_and_virtual_box().without_virtual()
    views = build_views(sc)
    assert views.real is views.mixed


def test_envmap_orientation_matches_docs():
    """A hot pixel at (u, v) must be seen along the direction docs/conventions.md gives."""
    import drjit as dr
    import mitsuba as mi

    from arlight.backend.mitsuba_scene import describe_light, load_object
    from arlight.scene.model import Light

    h, w = 32, 64
    img = np.zeros((h, w, 3), np.float32)
    row, col = 9, 40
    img[row, col] = 1000.0
    light = Light("env", "envmap", {"scale": 1.0, "rotation_deg": 0.0}, radiance_map=img)
    scene = mi.load_dict({"type": "scene", "env": load_object("env", describe_light(light))})
    u, v = (col + 0.5) / w, (row + 0.5) / h
    phi, theta = 2 * np.pi * u, np.pi * v
    d = [np.sin(theta) * np.sin(phi), np.cos(theta), -np.sin(theta) * np.cos(phi)]
    si = dr.zeros(mi.SurfaceInteraction3f)
    si.wi = mi.Vector3f(*[-float(x) for x in d])
    hot = float(np.array(scene.environment().eval(si))[0, 0])
    si.wi = mi.Vector3f(*[float(x) for x in d])  # the opposite direction is dark
    cold = float(np.array(scene.environment().eval(si))[0, 0])
    assert hot > 100.0 and cold == 0.0


def _textured_world(tmp_path):
    """Every kind of input a description carries: mesh with UVs, texture file, Phong,
    area light, spot light (a look_at transform) and an environment map (a rotation)."""
    import trimesh

    from arlight.io.images import write_png
    from tests.conftest import area_light_scene, env_mirror_scene

    mesh = trimesh.creation.box()
    mesh.visual = trimesh.visual.TextureVisuals(uv=np.random.default_rng(0).random(
        (len(mesh.vertices), 2)))
    mesh.export(tmp_path / "m.obj")
    write_png(tmp_path / "t.png", np.full((4, 4, 3), 200, np.uint8))
    d = area_light_scene(8, 6)
    d["shapes"].append({"role": "virtual", "type": "mesh", "file": "m.obj",
                        "material": {"type": "diffuse", "texture": "t.png"}})
    d["lights"].append(env_mirror_scene()["lights"][0])
    d["lights"].append({"type": "spot", "position": [0, 2, 0], "target": [0, 0, 0],
                        "intensity": 3.0})
    return parse_scene(d, base_dir=tmp_path)


def test_description_is_plain_data(tmp_path):
    """Translation yields only plain data (the cache key hashes it): a Mitsuba object (a
    Bitmap, a Transform) slipping into a description would fail here, and the arrays are the
    decoded file contents."""
    from arlight.backend.mitsuba_scene import describe_views

    desc = describe_views(_textured_world(tmp_path))
    arrays = {}

    def walk(x, path):
        if isinstance(x, dict):
            for k, v in x.items():
                assert isinstance(k, str), path
                walk(v, f"{path}.{k}")
        elif isinstance(x, list):
            for i, v in enumerate(x):
                walk(v, f"{path}[{i}]")
        elif isinstance(x, np.ndarray):
            arrays[path] = x
        else:
            assert x is None or isinstance(x, str | bool | int | float), (path, type(x))

    walk(desc, "")
    names = {p.rsplit(".", 1)[-1] for p in arrays}
    assert names == {"to_world", "bitmap", "vertices", "faces", "uv", "normals"}, names
    tex = [a for p, a in arrays.items() if p.endswith("reflectance.bitmap")]
    assert len(tex) == 1 and np.allclose(tex[0], (200 / 255) ** 2.2, atol=0.02)  # sRGB-decoded


def test_every_schema_type_has_one_translation():
    """Material and light translation is one table entry per type: a type the schema accepts
    without an entry (or an entry for a type that no longer exists) fails here."""
    from arlight.backend.mitsuba_scene import LIGHTS, MATERIALS, SHAPES
    from arlight.scene import schema

    assert set(MATERIALS) == set(schema.MATERIAL_TYPES)
    assert set(LIGHTS) == set(schema.LIGHT_TYPES)
    assert set(SHAPES) == set(schema.SHAPE_TYPES) - set(schema.EXPANDED_SHAPE_TYPES)


def test_build_views_loads_the_description(tmp_path):
    """The methods' views are loaded from the same description the synthetic photos hash:
    every described object is in the loaded scene, with its id, and nothing else."""
    from arlight.backend.mitsuba_scene import describe_views, is_shape_node

    sc = _textured_world(tmp_path)
    desc = describe_views(sc)
    views = build_views(sc)
    for name, view in (("real", views.real), ("mixed", views.mixed)):
        objects = desc[name]["objects"]
        shape_ids = sorted(sh.id() for sh in view.scene.shapes())
        described = sorted(k for k, v in objects.items() if is_shape_node(v))
        assert shape_ids == described
        assert len(view.scene.emitters()) == len(sc.lights)


def _sensor_rays(camera, uv, lens_sample=(0.5, 0.5)):
    import mitsuba as mi

    from arlight.backend.mitsuba_scene import mitsuba_sensor

    sensor = mitsuba_sensor(camera, 1)
    pos = mi.Point2f(uv[:, 0] / camera.width, uv[:, 1] / camera.height)
    ray, _ = sensor.sample_ray(0.0, 0.5, pos, mi.Point2f(*lens_sample))
    return np.array(ray.o).T, np.array(ray.d).T


def test_pinhole_sensor_sees_what_the_camera_sees():
    """Mitsuba's sensor and ``Camera.pixel_rays`` agree on the ray through every film point,
    with an off-centre principal point and a non-square image: catches a flipped x or y axis,
    a principal-point offset with the wrong sign or units, and a wrong field of view."""
    from arlight.scene.camera import Camera, look_at

    cam = Camera(24, 18, 20.0, 20.0, 9.3, 11.1,
                 world_from_camera=look_at([0.3, 0.9, 2.2], [0.0, 0.25, 0.0]))
    uv = np.array([[0.0, 0.0], [24.0, 18.0], [5.5, 13.25], [23.0, 1.0], [9.3, 11.1]])
    o, d = _sensor_rays(cam, uv)
    o_ref, d_ref = cam.pixel_rays(uv)
    assert np.abs(d - d_ref).max() < 1e-6
    assert np.abs(o - o_ref).max() < 2e-4  # Mitsuba starts rays at its near clip (1e-4 m)


def test_thinlens_sensor_focuses_like_the_camera():
    """Thin lens: the chief ray is the pinhole ray, and a ray from an off-centre lens point
    is the camera's ray from the mirrored lens point (same focal plane z = focus_distance,
    same aperture radius): catches a wrong focus distance or aperture scale."""
    import mitsuba as mi

    from arlight.scene.camera import Camera, look_at

    cam = Camera(24, 18, 20.0, 20.0, 12.0, 9.0, aperture_radius=0.05, focus_distance=1.7,
                 world_from_camera=look_at([0.3, 0.9, 2.2], [0.0, 0.25, 0.0]))
    uv = np.array([[0.0, 0.0], [24.0, 18.0], [5.5, 13.25]])
    for sample in ((0.5, 0.5), (0.9, 0.3), (0.1, 0.75)):
        o, d = _sensor_rays(cam, uv, sample)
        lens = np.array(mi.warp.square_to_uniform_disk_concentric(
            mi.ScalarPoint2f(*sample))).ravel()
        o_ref, d_ref = cam.pixel_rays(uv, np.tile(-lens, (len(uv), 1)))
        assert np.abs(d - d_ref).max() < 1e-6
        assert np.abs(o - o_ref).max() < 2e-4


def test_sensor_refuses_what_mitsuba_cannot_model():
    """A square aperture, non-square pixels and a lens with an off-centre principal point
    have no Mitsuba sensor: each is an InputError naming the field, not a silently
    different camera."""
    from dataclasses import replace

    from arlight.backend.mitsuba_scene import describe_sensor
    from arlight.errors import InputError
    from arlight.scene.camera import Camera

    cam = Camera(8, 6, 10.0, 10.0, 4.0, 3.0)
    describe_sensor(cam, 4)
    cases = [(replace(cam, aperture_radius=0.1, aperture_shape="square"),
              "camera.aperture_shape", "square aperture"),
             (replace(cam, fy=11.0), "camera.intrinsics", "square pixels"),
             (replace(cam, aperture_radius=0.1, cx=4.5), "camera.intrinsics", "principal")]
    for bad, field, words in cases:
        with pytest.raises(InputError) as err:
            describe_sensor(bad, 4)
        assert err.value.field == field and words in str(err.value)
