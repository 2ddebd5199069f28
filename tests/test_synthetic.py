"""Synthetic photographs: content-hash cache and frame/ground-truth consistency."""

import numpy as np

from arlight.scene.load import parse_scene
from arlight.synthetic import content_key, synthesize
from tests.conftest import area_light_scene


def test_cache_round_trip_and_key(tmp_path, monkeypatch):
    world = parse_scene(area_light_scene(12, 9))
    a = synthesize(world, spp=4, seed=3, cache_dir=tmp_path)
    files = list((tmp_path / "synthetic").glob("*.npz"))
    assert len(files) == 1 and a.key in files[0].name
    # a second call must come from the cache: make rendering impossible
    import arlight.synthetic as syn

    monkeypatch.setattr(syn, "_render", lambda *a, **k: (_ for _ in ()).throw(AssertionError))
    b = synthesize(world, spp=4, seed=3, cache_dir=tmp_path)
    for name in ("frame", "frame_stderr", "ground_truth", "ground_truth_stderr", "mask"):
        assert np.array_equal(getattr(a, name), getattr(b, name))
    assert content_key(world, spp=4) != content_key(world, spp=8)
    d = area_light_scene(12, 9)
    d["lights"][0]["radiance"] = 13.0
    assert content_key(parse_scene(d), spp=4) != content_key(world, spp=4)


def test_key_follows_referenced_file_content(tmp_path):
    import trimesh

    trimesh.creation.box().export(tmp_path / "m.ply")
    d = area_light_scene(8, 6)
    d["shapes"].append({"role": "virtual", "type": "mesh", "file": "m.ply"})
    k1 = content_key(parse_scene(d, base_dir=tmp_path))
    trimesh.creation.icosphere(1).export(tmp_path / "m.ply")
    assert content_key(parse_scene(d, base_dir=tmp_path)) != k1


def test_frame_excludes_and_ground_truth_includes_virtual(tmp_path):
    world = parse_scene(area_light_scene(16, 12))
    p = synthesize(world, spp=16, seed=1, cache_dir=tmp_path)
    assert p.frame.shape == (12, 16, 3) and p.mask.max() == 1.0
    covered = p.mask == 1.0
    # the virtual ball is grey-white; where it covers, the ground truth differs from the frame
    diff = np.abs(p.ground_truth - p.frame)[covered].max(axis=1)
    se = np.hypot(p.ground_truth_stderr, p.frame_stderr)[covered].max(axis=1)
    assert np.mean(diff > 3 * se) > 0.5


def test_resized_scene_box_filters_frame_and_changes_cache_key():
    world = parse_scene(area_light_scene(16, 12))
    frame = np.arange(12 * 16 * 3, dtype=np.float32).reshape(12, 16, 3)
    small = world.with_frame(frame).resized(8, 6)
    assert small.frame.shape == (6, 8, 3)
    assert np.allclose(small.frame[0, 0], frame[:2, :2].mean(axis=(0, 1)))
    assert small.raw["camera"]["resolution"] == [8, 6]
    assert content_key(small, spp=4) != content_key(world, spp=4)
