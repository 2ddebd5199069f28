"""The culling of real lanes' mirror rays (:func:`arlight.realtime.mirror_rays.mirror_rays`
with ``change_only`` and ``ball``) against the same rays shaded on every lane: a lane is
skipped only where its change is exactly zero, so the change and the virtual hits must
come out bit for bit as without culling, while lanes are in fact skipped."""

from __future__ import annotations

import drjit as dr
import numpy as np
import pytest

from arlight.backend.mitsuba_scene import ROLE_REAL, ROLE_VIRTUAL
from arlight.backend.reproject import Reprojector
from arlight.methods import RenderSettings, get_method
from arlight.realtime.gbuffer import render_gbuffer
from arlight.realtime.mirror_rays import MirrorLight, mirror_rays
from arlight.realtime.shading import virtual_bounds
from arlight.realtime.shadow_reach import bounding_ball
from arlight.scene.load import parse_scene

FLOORS = {"mirror": {"type": "mirror", "reflectance": 0.8},
          "rough": {"type": "roughconductor", "alpha": 0.1, "reflectance": 0.8}}


@pytest.fixture(scope="module", params=sorted(FLOORS))
def floor_mirror_and_shadowed_wall(request):
    """A real mirror (or rough metal, GGX α 0.1) floor that shows a real white wall, and on
    the wall the shadow of a virtual sphere standing between it and a low sun behind the
    camera: floor lanes far from the sphere reflect the shadow (their own shadow rays cannot
    meet the sphere), others reflect the sphere, others lit wall or sky; the floor under the
    sphere lies in its shadow (a rough lobe's highlight of the sun is blocked there)."""
    world = parse_scene({
        "camera": {"resolution": [48, 36], "fov_y_deg": 40,
                   "look_at": {"origin": [0.0, 0.9, 2.2], "target": [0.0, 0.2, -0.4]}},
        "shapes": [
            {"name": "floor", "role": "real", "type": "rectangle", "size": [4, 4],
             "normal": [0, 1, 0], "material": FLOORS[request.param]},
            {"name": "wall", "role": "real", "type": "rectangle", "size": [4, 2],
             "normal": [0, 0, 1], "transform": {"translate": [0.0, 1.0, -1.2]},
             "material": {"type": "diffuse", "albedo": 0.8}},
            {"name": "ball", "role": "virtual", "type": "sphere", "radius": 0.2,
             "transform": {"translate": [0.0, 0.45, -0.6]},
             "material": {"type": "diffuse", "albedo": [0.7, 0.3, 0.2]}}],
        "lights": [{"type": "constant", "radiance": 0.2},
                   {"type": "directional", "direction": [0.0, -0.25, -1.0],
                    "irradiance": 3.0}]})
    frame = np.full((36, 48, 3), 0.5, np.float32)
    world = world.with_frame(frame)
    state = get_method("dvct").prepare(world, RenderSettings(options={"volume_size": 32,
                                                                      "rsm_size": 32}))
    return world, state.data, frame


def test_culled_lanes_change_nothing(floor_mirror_and_shadowed_wall):
    """Rejects: a cull that tests the lane's own point instead of its ray's hit (it drops
    the floor lanes that show the sphere's shadow on the wall from afar: their change
    differs); one that drops lanes whose ray meets the virtual sphere (their role and
    radiance differ); and no cull at all (no lane skipped)."""
    world, data, frame = floor_mirror_and_shadowed_wall
    gb = render_gbuffer(data.views.mixed, world.camera, 1, 0)
    real = gb.valid & (gb.role == ROLE_REAL)
    light = MirrorLight.of(data.views, data.lights, data.world, data.distant)
    seen = Reprojector(world.camera, frame, data.views.real)
    ball = bounding_ball(virtual_bounds(data.world, data.views.mixed))
    args = (light, gb.position, gb.normal, gb.to_camera, gb.shape, real, seen)
    rad0, change0, role0 = (np.array(x) for x in mirror_rays(*args))
    rad1, change1, role1 = (np.array(x) for x in mirror_rays(*args, real, ball))
    np.testing.assert_array_equal(change1, change0)
    virt = role0 == ROLE_VIRTUAL
    assert virt.sum() > 10  # the sphere's reflection
    np.testing.assert_array_equal(role1[virt], role0[virt])
    np.testing.assert_array_equal(rad1[:, virt], rad0[:, virt])
    shadowed = np.abs(change0).max(0) > 0
    assert shadowed.sum() > 10  # the wall's shadow seen in the floor
    skipped = (role0 == ROLE_REAL) & (role1 == -1)
    assert skipped.sum() > 0.3 * (role0 == ROLE_REAL).sum()
    assert dr.width(gb.role) == role1.size
