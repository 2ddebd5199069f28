"""World vs. view: the static world, per-frame views, saving scenes and reading them back."""

from __future__ import annotations

import glob

import numpy as np
import pytest

from arlight.errors import InputError
from arlight.io.images import write_exr, write_png
from arlight.scene.load import load_scene, load_view, load_world, parse_scene, parse_view
from arlight.scene.model import ARScene, FrameView
from arlight.scene.save import save_scene, to_toml
from tests.conftest import area_light_scene

DATA_SCENES = ["src/arlight/data/demo/scene.toml",
               *sorted(glob.glob("src/arlight/data/scenes/*/world.toml"))]


def _frame_files(tmp_path, w=40, h=30):
    rng = np.random.default_rng(1)
    codes = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    depth = rng.uniform(0.5, 3.0, (h, w)).astype(np.float32)
    depth[0, :5] = np.nan  # unknown
    write_png(tmp_path / "f.png", codes)
    write_exr(tmp_path / "d.exr", depth)
    return codes, depth


def test_view_reads_frame_depth_timestamp_and_object_transforms(tmp_path):
    """Catches: a view field read but dropped, depth read as RGB, a transform applied on the
    wrong side (object space instead of world space)."""
    codes, depth = _frame_files(tmp_path)
    d = area_light_scene()
    d["frame"] = {"image": "f.png", "depth": "d.exr", "timestamp": 1.25,
                  "object_transforms": {"ball": {"translate": [0.1, 0, 0]},
                                        "box": {"rotate": [0, 1, 0, 90]}}}
    scene = parse_scene(d, base_dir=tmp_path)
    assert np.array_equal(scene.frame_codes, codes)
    assert np.array_equal(scene.depth, depth, equal_nan=True) and scene.timestamp == 1.25
    rest = {s.name: s for s in parse_scene(area_light_scene()).shapes}
    posed = {s.name: s for s in scene.shapes}
    assert np.allclose(posed["ball"].to_world[:3, 3], rest["ball"].to_world[:3, 3] + [0.1, 0, 0])
    # world-space rotation about the origin moves the box's centre (-0.5, ., -0.2) to (-0.2, ., 0.5)
    assert np.allclose(posed["box"].to_world[[0, 2], 3], [-0.2, 0.5])
    assert np.array_equal(posed["floor"].to_world, rest["floor"].to_world)
    # the world keeps the rest pose; the view carries the motion; composing poses again
    view = parse_view(d, base_dir=tmp_path)
    assert set(view.object_transforms) == {"ball", "box"}
    world = parse_scene(area_light_scene()).world
    again = ARScene.compose(world, view)
    assert all(np.array_equal(a.to_world, b.to_world) for a, b in zip(again.shapes, scene.shapes,
                                                                      strict=True))


def test_one_world_many_views(tmp_path):
    """A sequence is one world and many views: views differ only in camera and poses."""
    world = parse_scene(area_light_scene()).world
    cam = parse_scene(area_light_scene()).camera
    def shift(t: float) -> np.ndarray:
        m = np.eye(4)
        m[0, 3] = t
        return m

    views = [FrameView(camera=cam, object_transforms={"ball": shift(t)}, timestamp=t)
             for t in (0.0, 0.5)]
    scenes = [ARScene.compose(world, v) for v in views]
    assert [s.timestamp for s in scenes] == [0.0, 0.5]
    assert all(s.shapes[0] is world.shapes[0] for s in scenes)  # static shapes are shared
    ball = [next(x for x in s.shapes if x.name == "ball") for s in scenes]
    assert ball[1].to_world[0, 3] - ball[0].to_world[0, 3] == pytest.approx(0.5)


@pytest.mark.parametrize(("frame", "field", "match"), [
    ({"object_transforms": {"nope": {"translate": [0, 0, 0]}}}, "frame.object_transforms",
     "unknown shape 'nope'"),
    ({"object_transforms": {"ball": {"scale": 0}}}, "frame.object_transforms.ball.scale", "zero"),
    ({"timestamp": "noon"}, "frame.timestamp", "number"),
    ({"depth": "missing.exr"}, "frame.depth", "not found"),
    ({"colour": 1}, "frame.colour", "unknown field"),
])
def test_bad_view_fields_name_the_field(tmp_path, frame, field, match):
    d = area_light_scene()
    d["frame"] = frame
    with pytest.raises(InputError, match=match) as err:
        parse_scene(d, base_dir=tmp_path)
    assert err.value.field == field


def test_depth_of_wrong_size_is_rejected(tmp_path):
    write_exr(tmp_path / "d.exr", np.ones((3, 4), np.float32))
    d = area_light_scene()
    d["frame"] = {"depth": "d.exr"}
    with pytest.raises(InputError, match="depth is 4×3") as err:
        parse_scene(d, base_dir=tmp_path)
    assert err.value.field == "frame.depth"


def test_load_world_needs_no_camera_and_load_view_no_shapes(tmp_path):
    d = area_light_scene()
    cam = d.pop("camera")
    (tmp_path / "w.json").write_text(__import__("json").dumps(d))
    world = load_world(tmp_path / "w.json")
    assert [s.name for s in world.shapes] == ["floor", "wall", "box", "ball"]
    (tmp_path / "v.json").write_text(__import__("json").dumps({"camera": cam}))
    assert load_view(tmp_path / "v.json").camera.width == 40


def test_resized_box_filters_depth_over_known_values():
    scene = parse_scene(area_light_scene(4, 2))
    depth = np.array([[1, 3, np.nan, 0], [1, 3, np.nan, 0]], np.float32)
    small = ARScene.compose(scene.world, FrameView(camera=scene.camera, depth=depth)).resized(2, 1)
    assert small.depth[0, 0] == 2.0 and np.isnan(small.depth[0, 1])


@pytest.mark.parametrize("path", DATA_SCENES)
def test_saved_scene_loads_back_equal(path, tmp_path):
    """Catches: a field not written (or written in another unit/axis convention), a path
    written relative to the wrong folder, the normal rotation applied twice."""
    a = load_scene(path)
    b = load_scene(save_scene(a, tmp_path / "out" / "scene.toml"))
    ca, cb = a.camera, b.camera
    assert (ca.width, ca.height, ca.fx, ca.fy, ca.cx, ca.cy) == (cb.width, cb.height, cb.fx,
                                                                 cb.fy, cb.cx, cb.cy)
    assert np.array_equal(ca.world_from_camera, cb.world_from_camera)
    assert (ca.aperture_radius, ca.focus_distance, ca.aperture_shape, ca.transfer) == (
        cb.aperture_radius, cb.focus_distance, cb.aperture_shape, cb.transfer)
    for x, y in zip(a.shapes, b.shapes, strict=True):
        assert (x.name, x.role, x.type, x.material.type) == (y.name, y.role, y.type,
                                                              y.material.type)
        assert x.material.params == y.material.params
        assert np.array_equal(x.to_world, y.to_world)
        if x.mesh is not None:
            assert np.array_equal(x.mesh.vertices, y.mesh.vertices)
    for x, y in zip(a.lights, b.lights, strict=True):
        assert (x.name, x.type) == (y.name, y.type)
        px = {k: v for k, v in x.params.items() if k not in ("normal", "transform", "to_world")}
        py = {k: v for k, v in y.params.items() if k not in ("normal", "transform", "to_world")}
        assert px == py
        if "to_world" in x.params:
            assert np.array_equal(x.params["to_world"], y.params["to_world"])
        if x.radiance_map is not None:
            assert np.array_equal(x.radiance_map, y.radiance_map)
    if a.frame is not None:
        assert np.array_equal(a.frame, b.frame) and np.array_equal(a.frame_codes,
                                                                   b.frame_codes)


def test_saved_hdr_frame_depth_and_timestamp_round_trip(tmp_path):
    scene = parse_scene(area_light_scene())
    rng = np.random.default_rng(2)
    frame = rng.uniform(0, 5, (30, 40, 3)).astype(np.float32)
    depth = rng.uniform(0, 5, (30, 40)).astype(np.float32)
    view = FrameView(camera=scene.camera, frame=frame, depth=depth, timestamp=3.5)
    b = load_scene(save_scene(ARScene.compose(scene.world, view), tmp_path / "s.toml"))
    assert np.array_equal(b.frame, frame) and np.array_equal(b.depth, depth)
    assert b.timestamp == 3.5 and b.frame_codes is None


def test_saved_scene_renders_identically(tmp_path):
    """The saved file is the same scene to a renderer, bit for bit."""
    from arlight.methods import RenderSettings, get_method
    from tests.conftest import with_constant_frame

    a = with_constant_frame(parse_scene(area_light_scene(12, 9)))
    b = load_scene(save_scene(a, tmp_path / "s.toml"))
    ref = get_method("reference")
    la, lb = ref(a, RenderSettings(spp=4, seed=1)), ref(b, RenderSettings(spp=4, seed=1))
    assert np.array_equal(la.composite, lb.composite)


def test_to_toml_quotes_keys_and_refuses_non_finite():
    import tomllib

    d = {"a": 1, "t": {"x y": "é\"q", "v": [1.5, True]}, "arr": [{"k": {"m": [[1.0]]}}]}
    assert tomllib.loads(to_toml(d)) == d
    with pytest.raises(ValueError, match="non-finite"):
        to_toml({"x": float("nan")})
