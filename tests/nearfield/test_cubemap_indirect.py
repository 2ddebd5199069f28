"""Checklist items 11 (SH projection), 12 (transfer and PRT) and 17 (inter-object light)."""

from __future__ import annotations

import numpy as np

from arlight.nearfield import cubemap
from arlight.nearfield.atlas import layout_charts, proxy_mesh
from arlight.nearfield.indirect import IndirectProbes
from arlight.nearfield.pipeline import virtual_objects
from arlight.sphere.sh import sh_basis
from tests.nearfield.conftest import room, vbox, world


def test_solid_angles_and_constant_projection():
    w = cubemap.texel_solid_angles(32)
    assert abs(w.sum() - 4 * np.pi) < 1e-6
    c = cubemap.project(np.ones((6 * 32 * 32, 3)), 32)
    assert np.allclose(c[0], 2 * np.sqrt(np.pi), atol=1e-6)  # 3.5449
    assert np.max(np.abs(c[1:])) < 1e-6
    # a direction-dependent function: L = Y_2 (linear band) projects to the unit vector
    y = sh_basis(cubemap.cube_directions(32), 2)
    c = cubemap.project(np.repeat(y[:, 2:3], 3, 1), 32)
    assert abs(c[2, 0] - 1) < 2e-3 and np.max(np.abs(np.delete(c[:, 0], 2))) < 2e-3


def test_unoccluded_transfer_is_the_clamped_cosine_and_prt_gives_albedo():
    rng = np.random.default_rng(0)
    n = rng.normal(size=(20, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    t = cubemap.transfer(np.ones((20, 6 * 32 * 32)), n, 32)
    a_hat = np.array([np.pi] + [2 * np.pi / 3] * 3 + [np.pi / 4] * 5)
    expect = a_hat * sh_basis(n, 2)
    assert np.max(np.abs(t - expect)) < 1e-3 * np.pi
    # constant L = 1: rho/pi sum_k C_k C_vk = rho
    c = cubemap.project(np.ones((6 * 32 * 32, 3)), 32)
    rho = np.array([0.2, 0.5, 0.9])
    L = rho / np.pi * (t @ c)
    assert np.allclose(L, rho, rtol=1e-3)
    # fully enclosed vertex: 0
    assert np.all(cubemap.transfer(np.zeros((1, 6 * 32 * 32)), n[:1], 32) == 0)


def test_mesh_transfer_self_occlusion():
    w = world(room(virtual=[vbox()]))
    obj = virtual_objects(w)[0]
    t = cubemap.vertex_transfer(obj.vertices, obj.normals, obj.faces, res=8)
    # a convex box never occludes itself from its (smooth, outward) vertex normals' side:
    # C_v0 equals the unoccluded pi * Y_0 up to the cube map's accuracy at 8^2
    assert np.all(t[:, 0] > 0) and np.all(t[:, 0] <= np.pi * 0.2821 * 1.01)


def _probes(objs):
    w = world(room(virtual=objs))
    m = proxy_mesh(w)
    lay = layout_charts(m, 32)
    return IndirectProbes(m.vertices, m.faces, lay, virtual_objects(w), res=8)


def test_inter_object_light():
    assert _probes([vbox()]).cube_maps == 1
    white = vbox("white", at=(-0.25, 0.3, 0.0), albedo=(0.8, 0.8, 0.8))
    blue = vbox("blue", at=(0.25, 0.3, 0.0), albedo=(0.05, 0.05, 0.9))
    p = _probes([white, blue])
    assert p.cube_maps == 4
    atlas = np.full((32, 32, 3), 0.5)
    first = p.coefficients(atlas)
    # blue lit by its SH: the white object's cube map now sees blue light
    second = p.coefficients(atlas, previous=first)
    assert second[0, 0, 2] > first[0, 0, 2]
    assert second[0, 0, 0] < second[0, 0, 2]
    # direct light from a VAL on the other object adds more
    vals = (np.array([[0.0, 0.3, 0.3]]), np.array([[0.6, 0.0, -0.8]]),
            np.array([[5.0, 5.0, 5.0]]), np.array([0.1]))
    third = p.coefficients(atlas, previous=first, vals=vals)
    assert third[0, 0, 2] > second[0, 0, 2]
