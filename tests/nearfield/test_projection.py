"""Checklist items 1 (fisheye model of the rig) and 3 (projection and merge)."""

from __future__ import annotations

import numpy as np
import pytest

from arlight.errors import InputError
from arlight.nearfield.atlas import layout_charts, proxy_mesh, rasterize
from arlight.nearfield.cameras import RigCamera, auto_rig, load_rig, look_rotation
from arlight.nearfield.projection import camera_weights, merge, project_camera
from arlight.nearfield.raytrace import mesh_scene
from arlight.sphere.fisheye import FisheyeCamera
from tests.nearfield.conftest import room, world

BOX = [{"name": "crate", "role": "real", "type": "box", "size": [0.5, 0.5, 0.5],
        "transform": {"translate": [0.0, 0.25, -0.4]},
        "material": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}}]


def _setup(res=64):
    m = proxy_mesh(world(room(extra=BOX)))
    g = rasterize(m, layout_charts(m, res), 2)
    return m, g, mesh_scene([(m.vertices, m.faces)])


def _cam(pos, look, up=(0, 1, 0), size=96):
    model = FisheyeCamera.equidistant((size, size), 180.0,
                                      world_from_camera=look_rotation(look, up))
    return RigCamera("c", model, np.asarray(pos, float))


def test_fisheye_round_trip_and_border_angle():
    cam = _cam([0, 1, 0], [0.3, -0.2, -1.0], size=200)
    rng = np.random.default_rng(1)
    px = rng.uniform(20, 180, (500, 2))
    d, ok = cam.model.unproject(px)
    back, ok2 = cam.model.project(d[ok])
    assert np.max(np.abs(back - px[ok])) < 0.01
    # r_max (the image circle's radius) <-> theta = 90 deg
    r_max = cam.model.K[0, 0] * np.pi / 2
    d, _ = cam.model.unproject(np.array([[100 + r_max, 100.0]]))
    assert abs(float(d[0] @ cam.axis)) < 1e-9


def test_constant_radiance_merges_exactly_and_weights_are_clamped_cosines():
    m, g, scene = _setup()
    cams = [_cam([0, 0.25, 0.5], [0, 0, -1]), _cam([0.5, 1, 0], [-1, 0, 0]),
            _cam([0, 1.5, 0], [0, -1, 0], up=(0, 0, -1))]
    L = np.array([0.25, 0.5, 2.0], np.float32)
    projs = [project_camera(g, c, np.broadcast_to(L, (96, 96, 3)).copy(), scene) for c in cams]
    rad, ws = merge(projs)
    seen = ws > 0
    assert seen.mean() > 0.5
    assert np.max(np.abs(rad[seen] - L)) < 1e-4
    # weights: cos(alpha) cos(beta) where seen, 0 on back faces and occluded texels
    c = cams[0]
    w, _ = camera_weights(g, c, scene)
    x, n = g.position[g.covered], g.normal[g.covered]
    u = x - c.position
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    expect = np.clip(u @ c.axis, 0, 1) * np.clip(-(u * n).sum(1), 0, 1)
    pos = w > 0
    assert np.allclose(w[pos], expect[pos])
    assert np.all(w[(u * n).sum(1) > 0] == 0)  # back-facing
    # texels on the back wall hidden behind the crate are occluded
    behind = (np.abs(x[:, 2] + 1) < 1e-6) & (np.abs(x[:, 0]) < 0.2) & (x[:, 1] < 0.45)
    assert behind.sum() > 3 and np.all(w[behind] == 0)
    assert np.all(expect[behind] > 0)


def test_a_camera_that_sees_nothing_is_an_error():
    m, g, scene = _setup()
    outside = _cam([0, 1, 3.0], [0, 0, 1])  # outside the open room, looking away
    with pytest.raises(InputError, match="sees nothing"):
        project_camera(g, outside, np.ones((96, 96, 3), np.float32), scene)


def test_rig_file_errors_and_auto_rig(tmp_path):
    bad = tmp_path / "cams.toml"
    bad.write_text('[[cameras]]\nname = "a"\nposition = [0, 1, 0]\nlook = [0, 0, -1]\n')
    with pytest.raises(InputError, match="uncalibrated"):
        load_rig(bad)
    good = tmp_path / "ok.toml"
    good.write_text('[[cameras]]\nname = "a"\nposition = [0, 1, 0]\nlook = [0, 0, -1]\n'
                    'equidistant = { size = [32, 32], fov_deg = 180.0 }\n')
    rig = load_rig(good)
    assert np.allclose(rig[0].axis, [0, 0, -1]) and rig[0].size == (32, 32)
    assert len(auto_rig(np.zeros(3), np.ones(3), 16)) == 6


def test_auto_rig_sees_a_flat_proxy_from_above():
    from arlight.errors import InputError
    from arlight.nearfield.cameras import seeing_cameras

    d = room()
    d["shapes"] = d["shapes"][:1]  # the floor alone
    m = proxy_mesh(world(d))
    g = rasterize(m, layout_charts(m, 32), 1)
    scene = mesh_scene([(m.vertices, m.faces)])
    keep = seeing_cameras(auto_rig(m.vertices.min(0), m.vertices.max(0), 16), g, scene)
    names = [c.name for c in keep]
    assert "-y" in names and "+y" not in names
    with pytest.raises(InputError, match="no camera"):
        seeing_cameras([_cam([0, -1, 0], [0, -1, 0], up=(0, 0, 1))], g, scene)
