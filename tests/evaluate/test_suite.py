"""The scene suite: every scene loads with its documentation, and its proxy is the world minus
detail (same camera, virtual objects and lights). Agreement with ground truth:
``test_ground_truth.py``."""

from __future__ import annotations

import numpy as np
import pytest

from arlight.errors import InputError
from arlight.evaluate.suite import get_scene, list_scenes, scenes_dir
from arlight.io.images import read_linear

EXPECTED = {"bunny-box", "glass-ring", "glass-ring-point", "mirror-dragon", "red-paper",
            "cornell-near-field", "outdoor-env"}
FULL = {"cornell-near-field": (960, 540)}


def test_suite_lists_the_papers_scenes():
    assert EXPECTED <= set(list_scenes())


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_scene_loads_with_documentation(name):
    quick, full = get_scene(name, quick=True), get_scene(name, quick=False)
    assert quick.resolution[0] == 80
    assert full.resolution == FULL.get(name, (640, 480))
    # quick keeps the aspect ratio and the field of view
    assert quick.resolution[1] == round(80 * full.resolution[1] / full.resolution[0])
    assert quick.world.camera.fy / quick.resolution[1] == pytest.approx(
        full.world.camera.fy / full.resolution[1])
    assert quick.paper_figure and quick.description
    assert quick.world.has_virtual and quick.world.real_shapes
    assert quick.proxy.frame is None


def test_unknown_scene_names_the_known_ones():
    with pytest.raises(InputError, match="bunny-box"):
        get_scene("no-such-scene")


def test_cornell_lights_are_rohmers():
    lights = {x.name: x for x in get_scene("cornell-near-field").world.lights}
    assert lights["ceiling_light"].params["radiance"] == [15.0] * 3
    assert lights["window"].params["radiance"] == [3.0] * 3


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_proxy_differs_from_the_world_only_in_real_detail(name):
    """Every scene has a proxy.toml; it keeps the world's camera, virtual objects and lights
    (a method must be graded on the same insertion under the same light; a bulb of the
    world, ``type = "sphere"``, is the point light of the same position and intensity that a
    light estimate gives), and its real part is a different, coarser reconstruction."""
    assert (scenes_dir() / name / "proxy.toml").is_file()
    s = get_scene(name, quick=False)
    w, p = s.world, s.proxy
    assert p is not w
    for attr in ("width", "height", "fx", "fy", "cx", "cy", "aperture_radius"):
        assert getattr(p.camera, attr) == getattr(w.camera, attr), attr
    np.testing.assert_array_equal(p.camera.world_from_camera, w.camera.world_from_camera)
    virtual = [(x.name, x.type, x.params, x.material) for x in w.shapes if x.role == "virtual"]
    assert [(x.name, x.type, x.params, x.material) for x in p.shapes
            if x.role == "virtual"] == virtual
    for a, b in zip((x for x in w.shapes if x.role == "virtual"),
                    (x for x in p.shapes if x.role == "virtual"), strict=True):
        np.testing.assert_array_equal(a.to_world, b.to_world)
    as_estimated = [{"type": "point", "position": lt["position"], "intensity": lt["intensity"]}
                    if lt["type"] == "sphere" else lt for lt in w.raw["lights"]]
    assert p.raw["lights"] == as_estimated
    assert p.raw["shapes"] != w.raw["shapes"] or p.raw.get("materials") != w.raw.get("materials")


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_world_textures_average_to_the_proxy_albedo(name):
    """A textured world material and the proxy's flat material of the same name reflect the
    same light on average (the textures are made by make_assets.py, which prints their mean),
    so bounce light onto the virtual objects is the same in world and proxy."""
    s = get_scene(name, quick=True)
    proxy = {sh.material.name: sh.material for sh in s.proxy.shapes}
    for mat in {sh.material.name: sh.material for sh in s.world.shapes}.values():
        if mat.params.get("texture"):
            mean = read_linear(mat.params["texture"]).reshape(-1, 3).mean(axis=0)
            flat = proxy[mat.name].params
            assert not flat.get("texture")
            np.testing.assert_allclose(flat["albedo"], mean, atol=1e-4)
