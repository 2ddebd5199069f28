"""``dvct``'s one-bounce light against Mitsuba's path tracer (issue #33), as
``tests/methods/test_dir_reference.py`` does for ``dir``: on the box scene (red cube on a
white floor, point light) the cube's own bounce light, the floor ring's loss of bounce light
and the cube's red bounce on the floor, from dvct's nine diffuse cones (``ρ/π Σ w_k C_k``,
full-resolution cones, no shadow or ambient term), against ``path`` (max_depth 3) minus
``path`` (max_depth 2) — independent code, one bounce exactly.

Measured ratios dvct / Mitsuba (cube's own, ring's loss, cube's red bounce on the floor):

* isotropic cells (Franke; the default before issue #33's fix): 1.43, 1.07, **4.1** — the
  cube's lit top face radiates its Φ/π in every direction, so the floor beside the cube
  gathers it (removing the top face's texels: 0.99, 1.16, 1.21); the ring's loss and the
  cube's own light came out near 1 only through gathers a path tracer does not make (the
  floor's shadowed texels gathered by the coplanar floor, the cube's top by its front face);
* anisotropic cells (6 directions) with the occluded real bounce: 0.20, 0.29, 0.67.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.ndimage import binary_dilation, binary_erosion

from arlight.methods.dvct import (
    DELTA_VISIBILITY,
    SPEC,
    Lanes,
    build_volumes,
    diffuse_cones,
    prepare,
)
from arlight.realtime.gbuffer import render_gbuffer
from arlight.realtime.voxels import ConeVolumes
from tests.methods.test_dir_reference import one_bounce
from tests.methods.test_dlpv import box_scene, make

W, H = 40, 30
PASSES = 8


@pytest.fixture(scope="module")
def reference():
    """The box scene, its G-buffer, the regions (the cube eroded by one pixel, the floor
    ring 2–6 px around it) and Mitsuba's one-bounce images of the mixed scene and of the
    difference mixed − real (``PASSES`` independent estimates each)."""
    scene = make(box_scene(w=W, h=H))
    data = prepare(scene.world, SPEC.parse_options({}))
    gb = render_gbuffer(data.views.mixed, scene.camera, 1, 0)
    role = np.array(gb.role).reshape(H, W)
    virt = binary_erosion(role == 1, iterations=1)
    ring = (binary_dilation(role == 1, iterations=6) & ~binary_dilation(role == 1, iterations=1)
            & (role == 0))
    mixed = one_bounce(data.views.mixed, scene.camera)
    real = one_bounce(data.views.real, scene.camera)
    return scene, gb, virt, ring, mixed, mixed - real


def ratios(ref, **opts) -> np.ndarray:
    """dvct / Mitsuba for (the cube's one-bounce light, red; the floor ring's delta, green —
    the cube's shadow on bounce light; ring red − green — the cube's red bounce), from the
    diffuse cones of every G-buffer lane (``V_ρ`` on the cube, ``V_Δ`` on the floor)."""
    scene, gb, virt, ring, mixed, delta = ref
    o = SPEC.parse_options({"cone_scale": 1, **opts})
    data = prepare(scene.world, o)
    vols = build_volumes(data, o)
    lanes = Lanes(gb.position, gb.normal, gb.to_camera, gb.role, gb.shape)
    knobs = (float(o.shells), float(o.level_bias))
    e_delta, _, _ = diffuse_cones(
        ConeVolumes(vols.alpha, vols.normal, vols.delta,
                    vols.rho if o.occluded_bounce else None),
        lanes, o.diffuse_aperture_deg, DELTA_VISIBILITY, *knobs)
    e_rho, _, _ = diffuse_cones(ConeVolumes(vols.alpha, vols.normal, vols.rho), lanes,
                                o.diffuse_aperture_deg, 0, *knobs)
    alb = np.array(gb.albedo, np.float64).T.reshape(H, W, 3) / math.pi
    gv = (np.array(e_rho, np.float64).T.reshape(H, W, 3) * alb)[virt].mean(axis=0)
    gr = (np.array(e_delta, np.float64).T.reshape(H, W, 3) * alb)[ring].mean(axis=0)
    rv = mixed[:, virt].mean(axis=1).mean(axis=0)
    rr = delta[:, ring].mean(axis=1).mean(axis=0)
    return np.array([gv[0] / rv[0], gr[1] / rr[1], (gr[0] - gr[1]) / (rr[0] - rr[1])])


def test_reference_standard_errors_are_small(reference):
    """The reference's standard errors (over its passes) are ≤ 3 % of the three means, so
    the tolerances below are dvct's error, not the reference's."""
    _, _, virt, ring, mixed, delta = reference
    for img, reg, ch in ((mixed, virt, [0]), (delta, ring, [1]), (delta, ring, [0, 1])):
        per = img[:, reg].mean(axis=1)
        x = per[:, ch[0]] - (per[:, ch[1]] if len(ch) == 2 else 0.0)
        assert x.std(ddof=1) / math.sqrt(PASSES) <= 0.03 * abs(x.mean())


def test_anisotropic_cells_keep_the_lit_top_off_the_floor(reference):
    """With anisotropic cells the cube's red bounce on the floor is within 0.5–1.5× the path
    tracer's (measured 0.67: the cone gather of a plane is low, see the module docstring),
    where isotropic cells — today's default, Franke's — give more than 3× (measured 4.1:
    the lit top face radiating downwards). Rejects isotropic cells. (The slots of the
    travel direction instead of the direction towards the receiver are rejected in
    ``tests/realtime/test_voxels.py``; here they read the top face again, 0.5–1.5 by
    chance.)"""
    aniso = ratios(reference, anisotropic=True)
    iso = ratios(reference, anisotropic=False)
    assert 0.5 <= aniso[2] <= 1.5, aniso
    assert iso[2] > 3.0, iso


@pytest.mark.xfail(strict=True, reason="issue #33 open: dvct's one-bounce magnitude is not "
                   "yet right (defaults 1.43, 1.07, 4.1; anisotropic 0.20, 0.29, 0.67)")
@pytest.mark.parametrize("anisotropic", [False, True])
def test_one_bounce_magnitude_matches_path_traced_reference(reference, anisotropic):
    """The target: the cube's own bounce, the ring's loss of bounce light and the cube's red
    bounce each within 25 % of Mitsuba's (dir reaches 5 %, 4 %, 20 % rms). Strict xfail: it
    turns into a failure when a fix makes it pass, so the marker has to go."""
    r = ratios(reference, anisotropic=anisotropic, occluded_bounce=anisotropic)
    assert np.all(np.abs(r - 1.0) <= 0.25), r
