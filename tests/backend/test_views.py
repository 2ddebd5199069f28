"""The µ/ρ views: role filtering, batched ray queries and the envmap convention."""

import numpy as np

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

    from arlight.backend.mitsuba_scene import light_object
    from arlight.scene.model import Light

    h, w = 32, 64
    img = np.zeros((h, w, 3), np.float32)
    row, col = 9, 40
    img[row, col] = 1000.0
    light = Light("env", "envmap", {"scale": 1.0, "rotation_deg": 0.0}, radiance_map=img)
    scene = mi.load_dict({"type": "scene", "env": light_object(light, 0)})
    u, v = (col + 0.5) / w, (row + 0.5) / h
    phi, theta = 2 * np.pi * u, np.pi * v
    d = [np.sin(theta) * np.sin(phi), np.cos(theta), -np.sin(theta) * np.cos(phi)]
    si = dr.zeros(mi.SurfaceInteraction3f)
    si.wi = mi.Vector3f(*[-float(x) for x in d])
    hot = float(np.array(scene.environment().eval(si))[0, 0])
    si.wi = mi.Vector3f(*[float(x) for x in d])  # the opposite direction is dark
    cold = float(np.array(scene.environment().eval(si))[0, 0])
    assert hot > 100.0 and cold == 0.0
