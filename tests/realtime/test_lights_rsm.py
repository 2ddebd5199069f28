"""Light reduction, reflective shadow maps and the G-buffer (Franke checklist 12).

Each test names the wrong implementation it rejects."""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from arlight.backend.mitsuba_scene import build_views
from arlight.errors import InputError
from arlight.jit import ensure_variant
from arlight.realtime.gbuffer import render_gbuffer, resolve
from arlight.realtime.light_reduction import ReducedLight, reduce_lights
from arlight.realtime.rsm import (
    light_rays,
    render_rsm,
    render_rsm_pair,
    render_rsm_pair_reusing,
    shared_texels,
)
from arlight.realtime.shading import virtual_bounds
from arlight.scene.load import parse_scene
from tests.conftest import LOOK, area_light_scene

ensure_variant()


def _sum(c) -> np.ndarray:
    return np.array(c, np.float64).reshape(3, -1).sum(axis=1)


def test_area_light_becomes_cosine_points_of_equal_power():
    """An area light of radiance L and area A becomes g² cosine points emitting π L A in all;
    rejects I = L A (isotropic, 4× too much power) and a lost grid factor."""
    world = parse_scene(area_light_scene()).world
    for g in (1, 3):
        ls = reduce_lights(world, area_grid=g)
        assert len(ls.lights) == g * g and all(x.kind == "cosine" for x in ls.lights)
        power = sum(x.power for x in ls.lights)
        assert power == pytest.approx(math.pi * 12.0 * 0.36, rel=1e-9)
        assert np.allclose(ls.lights[0].axis, [0, -1, 0])


def test_constant_environment_is_ambient():
    """A constant sky of radiance L is all SH ambient with irradiance π L; rejects dropping
    the remainder or a missing √(4π)."""
    from arlight.realtime.shading import ambient_irradiance

    d = area_light_scene()
    d["lights"] = [{"type": "constant", "radiance": 0.5}]
    ls = reduce_lights(parse_scene(d).world)
    assert ls.lights == []
    e = ambient_irradiance(ls, np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]))
    assert np.allclose(e, math.pi * 0.5, rtol=1e-6)


def test_no_light_is_an_input_error():
    d = area_light_scene()
    d["lights"] = []
    with pytest.raises(InputError) as e:
        reduce_lights(parse_scene(d).world)
    assert e.value.field == "lights"


def _closed_box(light: dict) -> dict:
    return {"camera": {"resolution": [8, 6], "fov_y_deg": 45, "look_at": LOOK},
            "shapes": [{"name": "room", "role": "real", "type": "box", "size": [4, 4, 4],
                        "transform": {"translate": [0, 1, 0]},
                        "material": {"type": "diffuse", "albedo": 0.5}}],
            "lights": [light]}


@pytest.mark.parametrize("kind", ["point", "cosine", "spot"])
def test_rsm_carries_the_lights_power(kind):
    """Inside a closed room every texel hits, so the RSM's incident flux is the light's
    power (4πI, πI0, spot cone) and the VPL flux is ρ times it; rejects a wrong texel solid
    angle in any of the three texel maps."""
    world = parse_scene(_closed_box({"type": "point", "position": [0, 1, 0],
                                     "intensity": 2.0})).world
    views = build_views(world)
    light = ReducedLight(kind, np.array([0.0, 1.0, 0.0]), np.array([0.0, -1.0, 0.0]),
                         np.full(3, 2.0), cos_cutoff=math.cos(math.radians(40)),
                         cos_beam=math.cos(math.radians(40)))
    rsm = render_rsm(views.real, light_rays(light, 128, (np.zeros(3), 1.0)))
    assert bool(dr.all(rsm.valid))
    want = {"point": 4 * math.pi * 2.0, "cosine": math.pi * 2.0,
            "spot": 2 * math.pi * (1 - math.cos(math.radians(40))) * 2.0}[kind]
    assert np.allclose(_sum(rsm.flux_in), want, rtol=1e-4)
    assert np.allclose(_sum(rsm.flux_out), 0.5 * want, rtol=1e-4)
    # normals face the light
    assert np.array(dr.dot(rsm.normal, -rsm.direction)).min() >= 0.0


def test_rsms_equal_without_virtual_object():
    """Without a virtual object R_ρ == R_µ bit for bit and every texel is shared; with one,
    the texels that see it differ (checklist 12). Rejects RSMs built from different rays."""
    for virtual in (False, True):
        world = parse_scene(area_light_scene(virtual=virtual)).world
        views = build_views(world)
        lt = reduce_lights(world).lights[0]
        rays = light_rays(lt, 64, (np.zeros(3), 2.0))
        a, b = render_rsm(views.mixed, rays), render_rsm(views.real, rays)
        shared = np.array(shared_texels(a, b))
        if not virtual:
            assert shared.all()
            assert np.array_equal(np.array(a.flux_out), np.array(b.flux_out))
        else:
            assert 0 < (~shared).sum() < shared.size
            assert np.all(np.array(a.role)[~shared] == 1)


@pytest.mark.parametrize("reusing", [False, True])
def test_rsm_pair_equals_two_casts(reusing):
    """``render_rsm_pair`` (R_µ cast on the virtual texels only) and
    ``render_rsm_pair_reusing`` (R_µ cast before, only rays crossing the virtual objects'
    box cast into the mixed view) equal casting every ray into both views, field by field,
    with and without a virtual object, and their changed texels are exactly those that
    differ. Rejects copying the virtual hits into R_µ, casting them into the mixed view,
    putting them back at the wrong texels, or a box test that drops rays that reach the
    object."""
    for virtual in (False, True):
        world = parse_scene(area_light_scene(virtual=virtual)).world
        views = build_views(world)
        rays = light_rays(reduce_lights(world).lights[0], 64, (np.zeros(3), 2.0))
        full = (render_rsm(views.mixed, rays), render_rsm(views.real, rays))
        if reusing:
            box = virtual_bounds(world, views.mixed) or (np.full(3, 9.0), np.full(3, 9.5))
            pair = render_rsm_pair_reusing(views, rays, full[1], box)
        else:
            pair = render_rsm_pair(views, rays)
        for got, want in zip((pair.rho, pair.mu()), full, strict=True):
            for name in ("position", "normal", "albedo", "role", "shape", "t", "direction",
                         "flux_in", "flux_out"):
                assert np.array_equal(np.array(getattr(got, name)),
                                      np.array(getattr(want, name))), name
        differ = ~np.array(shared_texels(*full))
        assert np.array_equal(np.flatnonzero(differ), np.array(pair.changed))
        assert differ.any() == virtual


@pytest.mark.parametrize("material,albedo", [
    ({"type": "diffuse", "albedo": 0.4}, 0.4),
    ({"type": "phong", "kd": 0.5, "ks": 0.3, "exponent": 20}, 0.5),
    ({"type": "roughconductor", "alpha": 0.3, "reflectance": [0.9, 0.6, 0.3]}, 0.0),
    ({"type": "glass", "ior": 1.5}, 0.0),
])
def test_gbuffer_albedo_is_the_diffuse_lobe(material, albedo):
    """The G-buffer (and RSM) albedo is the diffuse lobe's reflectance only. Rejects Mitsuba's
    default ``eval_diffuse_reflectance`` (the whole BRDF at normal incidence: 3.5 for this
    Phong, 2.4 for the rough conductor), which made every real-time method treat glossy
    surfaces as brighter-than-white diffuse ones."""
    d = {"camera": {"resolution": [8, 6], "fov_y_deg": 30,
                    "look_at": {"origin": [0, 0, 3], "target": [0, 0, 0]}},
         "shapes": [{"name": "p", "role": "real", "type": "rectangle", "size": [5, 5],
                     "normal": [0, 0, 1], "material": material}],
         "lights": [{"type": "point", "position": [0, 0, 2], "intensity": 1.0}]}
    scene = parse_scene(d)
    gb = render_gbuffer(build_views(scene.world).mixed, scene.camera)
    np.testing.assert_allclose(resolve(gb, gb.albedo), albedo, atol=1e-6)


def test_gbuffer_roles_and_albedo():
    """The G-buffer's albedo is the hit material's reflectance and its roles match the
    mask of virtual coverage; rejects reading the albedo of the wrong shape."""
    scene = parse_scene(area_light_scene(40, 30))
    views = build_views(scene.world)
    gb = render_gbuffer(views.mixed, scene.camera)
    role = np.array(gb.role).reshape(30, 40)
    alb = resolve(gb, gb.albedo)
    assert (role == 1).any() and (role == 0).any()
    floorish = (role == 0) & np.isclose(alb[..., 2], 0.6)
    assert np.allclose(alb[floorish], [0.7, 0.7, 0.6], atol=1e-6) and floorish.sum() > 50
    n = np.array(gb.normal).reshape(3, -1).T
    to_cam = np.array(gb.to_camera).reshape(3, -1).T
    assert np.all((n * to_cam).sum(1)[role.ravel() >= 0] >= -1e-6)


def test_ambient_polynomial_equals_sh_irradiance():
    """The Dr.Jit quadratic form of the 9-coefficient irradiance equals
    arlight.sphere.sh.irradiance for random normals and a random SH; rejects a basis
    convention mismatch (e.g. a sign flip of the band-1 terms)."""
    from arlight.realtime.light_reduction import LightSet
    from arlight.realtime.shading import ambient_irradiance, ambient_irradiance_dr

    rng = np.random.default_rng(0)
    ls = LightSet([], rng.normal(size=(9, 3)))
    n = rng.normal(size=(50, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    ref = ambient_irradiance(ls, n)
    got = ambient_irradiance_dr(ls, mi.Vector3f(*(np.ascontiguousarray(n[:, i], np.float32)
                                                 for i in range(3))))
    assert np.allclose(np.array(got).reshape(3, -1).T, ref, atol=1e-4 * np.abs(ref).max())


@pytest.mark.parametrize("rotation", [0.0, 70.0])
def test_environment_map_splits_into_lights_and_ambient(rotation):
    """An environment map becomes directional lights (its highlights) plus SH ambient; the
    irradiance on an upward and a sideways surface matches the map's cosine integral (3 %;
    the 9-coefficient SH of the remainder is the only approximation), also with the map
    rotated. Rejects a dropped remainder, lights pointing the wrong way (direction of travel
    vs towards the light) or an unrotated SH."""
    from arlight.demo import DEMO_DIR
    from arlight.realtime.shading import ambient_irradiance
    from arlight.sphere.envmap import equirect_directions, equirect_solid_angle

    d = area_light_scene()
    d["lights"] = [{"type": "envmap", "file": str(DEMO_DIR / "lebombo_512x256.hdr"),
                    "rotation_deg": rotation}]
    world = parse_scene(d).world
    light = world.lights[0]
    ls = reduce_lights(world, env_lights=4)
    assert 1 <= len(ls.lights) <= 4 and all(x.kind == "directional" for x in ls.lights)
    img = np.asarray(light.radiance_map, np.float64) * light.params.get("scale", 1.0)
    h = img.shape[0]
    dirs = equirect_directions(h, img.shape[1])
    a = math.radians(rotation)
    rot = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    dirs = dirs @ rot.T
    omega = equirect_solid_angle(h, img.shape[1])
    for n in (np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0])):
        want = (img * (np.maximum(dirs @ n, 0) * omega)[..., None]).sum(axis=(0, 1))
        got = ambient_irradiance(ls, n[None])[0]
        for x in ls.lights:
            got = got + x.intensity * max(0.0, float(-x.axis @ n))
        assert np.allclose(got, want, rtol=0.03), (n, got, want)
