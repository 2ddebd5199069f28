"""`--light FILE`: a light estimate replaces the scene's lights, nothing else changes.

Rejects: an estimate added to the scene's lights (counting the light twice), one that
drops the SH remainder, and a rebuilt scene that loses the camera's intrinsics, pose or
transfer function, or the shapes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

import arlight
from arlight.io.images import read_linear
from arlight.light.estimate import LightEstimate
from arlight.live.setup import with_light_estimate
from arlight.scene.load import load_scene, parse_scene


def test_the_estimate_replaces_the_lights_only(clip, tmp_path):
    hdr = read_linear(Path(arlight.__file__).parent / "data/light/grace_latlong_256x128.hdr")
    est = LightEstimate.from_envmap(hdr, n_lights=4, sh_order=2)
    path = est.save(tmp_path / "light.json")
    sc = load_scene(clip.scene)
    lit = with_light_estimate(sc, path)
    # independently: the same light tables parsed on their own
    alone = parse_scene({"camera": {"resolution": [8, 6], "fov_y_deg": 40, "look_at": {
                                        "origin": [0, 1, 1], "target": [0, 0, 0]}},
                         "lights": LightEstimate.load(path).to_scene_lights("directional")})
    assert [(x.type, sorted(x.params)) for x in lit.world.lights] == \
        [(x.type, sorted(x.params)) for x in alone.world.lights]
    for a, b in zip(lit.world.lights, alone.world.lights, strict=True):
        for k, v in a.params.items():
            assert np.allclose(np.asarray(v, float), np.asarray(b.params[k], float)), k
    assert "sh" in {x.type for x in lit.world.lights}
    assert {x.type for x in sc.world.lights} == {"directional", "constant"}
    assert "constant" not in {x.type for x in lit.world.lights}
    cam, cam0 = lit.camera, sc.camera
    assert (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy) == \
        (cam0.width, cam0.height, cam0.fx, cam0.fy, cam0.cx, cam0.cy)
    assert np.array_equal(cam.world_from_camera, cam0.world_from_camera)
    assert repr(cam.transfer) == repr(cam0.transfer)
    assert [s.name for s in lit.world.shapes] == [s.name for s in sc.world.shapes]
