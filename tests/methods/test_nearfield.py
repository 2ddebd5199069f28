"""The nearfield method (Rohmer 2015): Eq. 14 identities (checklist 13), materials (18),
the budget harness (19), bad input and the untouched frame without virtual objects."""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from arlight.errors import InputError
from arlight.methods import RenderSettings, get_method
from arlight.methods.nearfield import NearFieldClient, empty_light, prepare
from arlight.nearfield.cameras import auto_rig
from arlight.nearfield.lightfile import load_light, save_light
from arlight.nearfield.materials import (
    beer_lambert,
    eta_for_f0,
    glass_composite,
    schlick_complex,
)
from arlight.nearfield.pipeline import NearFieldServer, NearFieldSettings, payload_bytes
from arlight.nearfield.shading import direct_light, shadow_maps, tile_lanes
from arlight.nearfield.state import NearFieldLight
from tests.nearfield.conftest import room, scene, vbox, world

SLAB = [{"name": "slab", "role": "real", "type": "box", "size": [0.6, 0.1, 0.6],
         "transform": {"translate": [0.0, 0.5, 0.0]},
         "material": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}}]
FLOATING = vbox("cube", at=(0.0, 1.0, 0.0), size=(0.2, 0.2, 0.2))


def _light(n_obj=1, sh0=0.0):
    sh = np.zeros((n_obj, 9, 3))
    sh[:, 0] = sh0
    return NearFieldLight(np.array([[0.0, 1.99, 0.0]]), np.array([[0.0, -1.0, 0.0]]),
                          np.array([[2.0, 1.0, 0.5]]), np.array([0.01]), sh)


def _pts(a):
    a = np.asarray(a, np.float32)
    return mi.Point3f(a[:, 0], a[:, 1], a[:, 2])


@pytest.mark.parametrize("shadows", ["rays", "maps"])
def test_eq14_real_occluders_win_and_virtual_shadow_removes_the_val(shadows):
    w = world(room(virtual=[FLOATING], extra=SLAB))
    opts = get_method("nearfield").spec.parse_options({"light": "x.json"})
    data = prepare(w, opts, _light())
    light = _light()
    # floor under slab and cube; slab top under the cube; floor in the open
    p = np.array([[0.0, 0.0, 0.0], [0.0, 0.55, 0.0], [0.7, 0.0, 0.7]])
    n = np.array([[0, 1, 0]] * 3, np.float64)
    maps = (shadow_maps(light, data.proxy, data.occluder, data.sphere)
            if shadows == "maps" else None)
    shape = mi.Int32([0, 0, 0])
    lit, lost = direct_light(light, _pts(p), mi.Vector3f(*[mi.Float(n[:, i].astype(
        np.float32)) for i in range(3)]), mi.Color3f(0.5, 0.5, 0.5),
        mi.Vector3f(0, 1, 0), mi.Bool(False), mi.Bool(True), shape, data.materials,
        data.proxy, data.occluder, maps)
    lost = np.array(lost).T if np.array(lost).shape[0] == 3 else np.array(lost)
    lit = np.array(lit).T if np.array(lit).shape[0] == 3 else np.array(lit)
    P = light.positions[0] + 1e-3 * light.normals[0]
    d = P - p[1]
    r2 = d @ d
    cos = d[1] / math.sqrt(r2)
    expect = 0.5 / math.pi * light.intensity[0] * cos * cos / (r2 + 0.01 / math.pi)
    assert np.all(lost[0] == 0)                       # real slab already blocks: unchanged
    assert np.allclose(lost[1], expect, rtol=1e-4)    # only the virtual cube: loses L_VAL
    assert np.all(lost[2] == 0) and np.all(lit[2] > 0)  # open floor: nothing lost
    assert np.all(lit[0] == 0) and np.all(lit[1] == 0)


def test_no_virtual_object_gives_the_frame_bitwise(tmp_path):
    sc = scene(room())
    path = save_light(_light(0), tmp_path / "vals.json")
    assert load_light(path).count == 1
    layers = get_method("nearfield")(sc, RenderSettings(options={"light": str(path)}))
    assert np.array_equal(layers.composite, sc.view.frame)
    client = NearFieldClient(sc.world)
    assert np.array_equal(client.render(sc.view, _light(0)).composite, sc.view.frame)


def test_render_is_deterministic_and_casts_a_shadow():
    """Same light, same frame; the cube darkens some real pixels. (``delta <= 0`` is not
    asserted: ``delta = −V(1 − V̂)L_VAL`` is non-positive by construction, so the assert
    could not fail; the size of the loss is checked analytically by the Eq. 14 test.)"""
    sc = scene(room(virtual=[vbox(at=(0.0, 0.3, 0.3))]))
    client = NearFieldClient(sc.world, {"shadows": "rays"})
    a = client.render(sc.view, _light(1, 0.5))
    b = client.render(sc.view, _light(1, 0.5))
    assert np.array_equal(a.composite, b.composite)
    assert np.any(a.delta < 0) and a.mask.sum() > 10
    none = client.render(sc.view, empty_light(1))
    assert np.all(none.delta == 0)
    # Eq. 8: constant radiance L = 1 (C_0 = 2 sqrt(pi)) on a convex object gives rho
    ind = NearFieldClient(sc.world, {"direct": False}).render(
        sc.view, _light(1, 2 * math.sqrt(math.pi)))
    m = ind.mask == 1
    assert np.allclose(ind.mixed[m], 0.8, rtol=0.01)


def test_metals_get_no_prt_and_the_fresnel_identities():
    metal = {"type": "roughconductor", "alpha": 0.2, "reflectance": [0.9, 0.6, 0.3]}
    sc = scene(room(virtual=[vbox(at=(0.0, 0.3, 0.3), material=metal)]))
    layers = NearFieldClient(sc.world, {"direct": False}).render(sc.view, _light(1, 1.0))
    assert np.all(layers.mixed[layers.mask == 1] == 0)
    n, k = np.array([0.2, 1.5, 3.0]), np.array([3.0, 0.5, 0.0])
    assert np.allclose(schlick_complex(1.0, n, k), ((n - 1)**2 + k**2) / ((n + 1)**2 + k**2))
    f0 = np.array([0.9, 0.6, 0.04])
    assert np.allclose(schlick_complex(1.0, eta_for_f0(f0, k), k), f0)
    assert np.allclose(glass_composite(0.0, 5.0, 1.0, 1.0, 2.0), 3.0)
    assert np.isclose(beer_lambert(0.0, 1.0), 1.0)


def test_bad_options_are_input_errors():
    sc = scene(room(virtual=[FLOATING]))
    m = get_method("nearfield")
    for bad in ({"tau": 1.5}, {"tau": -0.1}, {"vals": 0}):
        with pytest.raises(InputError):
            m(sc, RenderSettings(options=bad))
    with pytest.raises(InputError, match="M"):
        NearFieldSettings(vals=0).check()
    with pytest.raises(InputError, match="τ"):
        NearFieldSettings(tau=2.0).check()


def test_server_stages_payload_and_the_full_method():
    sc = scene(room(virtual=[FLOATING]))
    lo, hi = np.array([-1, 0, -1.0]), np.array([1, 2, 1.0])
    rig = auto_rig(lo, hi, 24)[:4]
    srv = NearFieldServer(sc.world, rig, NearFieldSettings(atlas_resolution=48, vals=4))
    imgs = [np.full((24, 24, 3), 0.5, np.float32) for _ in rig]
    light = srv.update(imgs)
    for stage in ("combine", "threshold", "split", "dilate", "sampling", "kmeans",
                  "integrate", "sh") + tuple(f"project_{c.name}" for c in rig):
        assert srv.stats[stage] >= 0
    assert payload_bytes(light) == 32 * light.count + 108 * light.n_objects
    assert light.count == 4 and light.sequence == 1
    layers = get_method("nearfield")(sc, RenderSettings(options={
        "capture_size": 16, "capture_spp": 1, "atlas_resolution": 32, "vals": 4}))
    assert 1 <= layers.stats["vals"] <= 4 and "time_direct" in layers.stats
    dr.sync_thread()


@pytest.mark.parametrize("shadows,gspp", [("rays", 1), ("maps", 1), ("maps", 4)])
def test_lane_culling_changes_nothing(shadows, gspp):
    """Checklist 14 (culling): with and without the per-VAL lane culling the direct light
    is the same to 1e-6."""
    from arlight.realtime.gbuffer import render_gbuffer

    sc = scene(room(virtual=[vbox(at=(0.0, 0.3, 0.3))], extra=SLAB))
    data = NearFieldClient(sc.world).state.data
    rng = np.random.default_rng(4)
    pos = np.column_stack([rng.uniform(-0.9, 0.9, 6), rng.uniform(0.0, 1.99, 6),
                           rng.uniform(-0.9, 0.9, 6)])
    nrm = rng.normal(size=(6, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    light = NearFieldLight(pos, nrm, rng.uniform(0.1, 1.0, (6, 3)), rng.uniform(0, 0.05, 6),
                           np.zeros((1, 9, 3)))
    gb = render_gbuffer(data.views.mixed, sc.view.camera, gspp)
    maps = (shadow_maps(light, data.proxy, data.occluder, data.sphere)
            if shadows == "maps" else None)
    args = (light, gb.position, gb.normal, gb.albedo, gb.to_camera, gb.virtual, gb.valid,
            gb.shape, data.materials, data.proxy, data.occluder, maps)
    a = [np.array(x) for x in direct_light(*args)]
    lanes = tile_lanes(light, np.array(gb.position, np.float64).T, np.array(gb.valid),
                       np.array(gb.virtual), gb.width, gb.height, gb.spp, data.sphere)
    assert sum(len(x) for x in lanes) < 0.9 * light.count * int(np.sum(np.array(gb.valid)))
    b = [np.array(x) for x in direct_light(*args, lanes_per_val=lanes)]
    virt = np.array(gb.virtual)
    assert np.allclose(a[0][:, virt], b[0][:, virt], atol=1e-6, rtol=0)
    assert np.allclose(a[1][:, ~virt], b[1][:, ~virt], atol=1e-6, rtol=0)
    assert np.any(a[1] > 0)


def test_glossy_adds_a_highlight_from_the_val_centre():
    """Blinn-Phong sampled at the VAL centre: a phong object is the diffuse one (kd) plus a
    non-negative specular term that is positive somewhere. Bug caught: the specular lobe
    ignored, or replacing the diffuse part."""
    phong = {"type": "phong", "kd": [0.5, 0.5, 0.5], "ks": [0.4, 0.4, 0.4], "exponent": 20.0}
    light = NearFieldLight(np.array([[0.0, 1.99, 1.0]]), np.array([[0.0, -1.0, 0.0]]),
                           np.array([[2.0, 2.0, 2.0]]), np.array([0.01]), np.zeros((1, 9, 3)))
    out = []
    for mat in (phong, {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}):
        sc = scene(room(virtual=[vbox(at=(0.0, 0.3, 0.3), material=mat)]))
        out.append(NearFieldClient(sc.world, {"shadows": "rays"}).render(sc.view, light))
    m = out[0].mask == 1
    spec = out[0].mixed[m] - out[1].mixed[m]
    assert np.all(spec >= -1e-6) and spec.max() > 1e-4
