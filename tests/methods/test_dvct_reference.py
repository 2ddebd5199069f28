"""``dvct``'s one-bounce light against Mitsuba's path tracer (issue #33), as
``tests/methods/test_dir_reference.py`` does for ``dir``: on the box scene (red cube on a
white floor, point light) the cube's own bounce light, the floor ring's loss of bounce light
and the cube's red bounce on the floor, from dvct's nine diffuse cones (``ρ/π Σ w_k C_k``,
full-resolution cones, no shadow or ambient term), against ``path`` (max_depth 3) minus
``path`` (max_depth 2) — independent code, one bounce exactly.

Measured ratios dvct / Mitsuba (cube's own, ring's loss, cube's red bounce on the floor):

* defaults (isotropic cells, Franke's): 1.41, 1.06, **4.0** — the cube's lit top face
  radiates its Φ/π in every direction, so the floor beside it gathers it (the top face's
  texels removed: 0.99, 1.16, 1.21); the ring's loss and the cube's own light came out near
  1 only through gathers a path tracer does not make (the floor's shadowed texels gathered
  by the coplanar floor, the cube's top by its front face);
* ``anisotropic`` (Lambertian intensity towards 6 directions): 0.19, 0.19, 0.66;
* all of issue #33's options (``anisotropic``, ``occluded_bounce``,
  ``directional_occupancy``, no ``virtual_self_occlusion``): 0.38, 0.29, 0.72, and with
  ``volume_scale`` 4: 0.67, 0.87, 0.68. What remains is mostly light from outside the
  volume (2× the object, Franke): the front face's horizontal cones leave the volume before
  they reach the floor, the wall behind the cube is outside it.

None of these is the default: on training worlds the bounce is not what limits dvct
(docs/methods/dvct.md, "Radiometry of the bounce")."""

from __future__ import annotations

import math

import numpy as np
import pytest

from arlight.backend.mitsuba_scene import ROLE_REAL, ROLE_VIRTUAL
from arlight.methods.dvct import (
    SPEC,
    Lanes,
    build_volumes,
    cone_volumes,
    diffuse_cones,
    diffuse_visibility,
    prepare,
)
from tests.methods.one_bounce import OneBounce
from tests.methods.test_dlpv import box_scene, make

W, H = 40, 30


def reference_data():
    """The box scene and Mitsuba's one-bounce reference
    (:class:`~tests.methods.one_bounce.OneBounce`) of dvct's views."""
    scene = make(box_scene(w=W, h=H))
    data = prepare(scene.world, SPEC.parse_options({}))
    return scene, OneBounce.of(data.views, scene.camera)


@pytest.fixture(scope="module")
def reference():
    """:func:`reference_data`, once per module."""
    return reference_data()


def ratios(ref, **opts) -> np.ndarray:
    """dvct / Mitsuba for (the cube's one-bounce light, red; the floor ring's delta, green —
    the cube's shadow on bounce light; ring red − green — the cube's red bounce), from the
    diffuse cones of every G-buffer lane (``V_ρ`` on the cube, ``V_Δ`` on the floor)."""
    scene, one = ref
    gb, virt, ring = one.gb, one.virt, one.ring
    o = SPEC.parse_options({"cone_scale": 1, **opts})
    data = prepare(scene.world, o)
    vols = build_volumes(data, o)
    lanes = Lanes(gb.position, gb.normal, gb.to_camera, gb.role, gb.shape)
    knobs = (float(o.shells), float(o.level_bias))
    cv_delta, cv_rho = cone_volumes(vols, o)
    e_delta, _, _ = diffuse_cones(cv_delta, lanes, o.diffuse_aperture_deg,
                                  diffuse_visibility(ROLE_REAL, o), *knobs)
    e_rho, _, _ = diffuse_cones(cv_rho, lanes, o.diffuse_aperture_deg,
                                diffuse_visibility(ROLE_VIRTUAL, o), *knobs)
    alb = np.array(gb.albedo, np.float64).T.reshape(H, W, 3) / math.pi
    gv = (np.array(e_rho, np.float64).T.reshape(H, W, 3) * alb)[virt].mean(axis=0)
    gr = (np.array(e_delta, np.float64).T.reshape(H, W, 3) * alb)[ring].mean(axis=0)
    rv, rr = one.means()
    return np.array([gv[0] / rv[0], gr[1] / rr[1], (gr[0] - gr[1]) / (rr[0] - rr[1])])


def test_reference_standard_errors_are_small(reference):
    """The reference's standard errors are ≤ 3 % of the three means, so the tolerances
    below are dvct's error, not the reference's."""
    reference[1].assert_precise()


def test_anisotropic_cells_keep_the_lit_top_off_the_floor(reference):
    """With anisotropic cells the cube's red bounce on the floor is within 0.5–1.5× the path
    tracer's (measured 0.66), where isotropic cells — the default, Franke's — give more
    than 3× (measured 4.0:
    the lit top face radiating downwards). Rejects isotropic cells. (The slots of the
    travel direction instead of the direction towards the receiver are rejected in
    ``tests/realtime/test_voxels.py``; here they read the top face again, 0.5–1.5 by
    chance.)"""
    aniso = ratios(reference, anisotropic=True)
    iso = ratios(reference, anisotropic=False)
    assert 0.5 <= aniso[2] <= 1.5, aniso
    assert iso[2] > 3.0, iso


FULL = {"anisotropic": True, "occluded_bounce": True, "directional_occupancy": True,
        "virtual_self_occlusion": False, "volume_scale": 4.0, "lost_bounce": True}
"""Issue #33's bounce options, with the ``−R_µ`` VPLs in ``V_Δ`` (``lost_bounce``, Franke's,
off by default since the shadows come from rays: without them the ring's loss is 0.44)."""


def test_issue_33_options_bring_the_three_terms_within_40_percent(reference):
    """With all of issue #33's options and a volume of 4× the object, each of the three
    one-bounce terms is within 0.6–1.4× Mitsuba's (measured 0.67, 0.87, 0.68): the
    anisotropic light keeps the top face off the floor, the occluded bounce gives the ring
    its loss, α_real on virtual lanes removes the cube's self-occlusion. Rejects the
    defaults (4.0× red bounce), and each of virtual self-occlusion (cube 0.53) and a volume
    of 2× the object (ring's loss 0.29) with the other options on."""
    r = ratios(reference, **FULL)
    assert np.all((r >= 0.6) & (r <= 1.4)), r
    for change in ({"anisotropic": False}, {"virtual_self_occlusion": True},
                   {"volume_scale": 2.0}):
        bad = ratios(reference, **{**FULL, **change})
        assert not np.all((bad >= 0.6) & (bad <= 1.4)), (change, bad)


@pytest.mark.xfail(strict=True, reason="issue #33 open: dvct's one-bounce magnitude is not "
                   "within 25 % (defaults 1.41, −0.14, 4.0 — the ring's loss needs "
                   "lost_bounce, off by default since the shadow rays: 1.06 with it; all "
                   "options at 4× volume 0.67, 0.87, 0.68)")
@pytest.mark.parametrize("options", [{}, FULL], ids=["defaults", "issue33"])
def test_one_bounce_magnitude_matches_path_traced_reference(reference, options):
    """The target: the cube's own bounce, the ring's loss of bounce light and the cube's red
    bounce each within 25 % of Mitsuba's (dir reaches 5 %, 4 %, 20 % rms). Strict xfail: it
    turns into a failure when a fix makes it pass, so the marker has to go."""
    r = ratios(reference, **options)
    assert np.all(np.abs(r - 1.0) <= 0.25), r
