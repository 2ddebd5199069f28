"""``dlpv``'s one-bounce light against Mitsuba's path tracer (issue #33): the light the
floor and wall throw on the virtual cube (``V_ρ``), the cube's red bounce on the floor and
the floor ring's loss of bounce light (``V_Δ``'s VPLs), against ``path`` (max_depth 3)
minus ``path`` (max_depth 2) — independent code, one bounce exactly. Same box scene and
regions as ``tests/methods/test_dir_reference.py``.

The volume is ``VOLUME_SCALE`` (4) × the cube's edge so that the floor ring lies inside it:
at Franke's 2 only 25 of the ring's 210 pixels do, and the LPV is zero outside its volume —
a cut-off by design, not a radiometric error (docs/methods/dlpv.md)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from arlight.methods.dlpv import SPEC, build_volumes, prepare, shade
from arlight.realtime.sh_volume import query_irradiance
from tests.methods.one_bounce import OneBounce
from tests.methods.test_dlpv import box_scene, make

W, H = 40, 30
VOLUME_SCALE = 4.0
RSM_SIZE = 512
"""The maps' resolution of the checks (the default was 512 when they were written; 256 since
issue #33): the cube covers a few texels of this small scene's maps and its bleed on the
ring swings with the resolution, an aliasing of the maps, not a radiometric error (128:
1.36×, 256: 0.63×, 512: 0.92×, 1024: 0.79× of Mitsuba's)."""
BAND = 0.3
"""Tolerance on each region mean's ratio: an LPV blurs the bounce over 2–3 cells and its
response to one VPL varies by ±25 % with direction and distance (``point_response``)."""


def _image(c) -> np.ndarray:
    """A Dr.Jit colour array of the G-buffer's lanes as ``(H, W, 3)`` float64."""
    return np.array(c, np.float64).reshape(3, -1).T.reshape(H, W, 3)


@pytest.fixture(scope="module")
def reference():
    """The box scene and Mitsuba's one-bounce reference
    (:class:`~tests.methods.one_bounce.OneBounce`) of dlpv's views at ``VOLUME_SCALE``."""
    scene = make(box_scene(w=W, h=H))
    data = prepare(scene.world, SPEC.parse_options({"volume_scale": VOLUME_SCALE,
                                                    "rsm_size": RSM_SIZE}))
    return scene, OneBounce.of(data.views, scene.camera)


def _ratios(ref, opts: dict) -> dict[str, float]:
    """dlpv / Mitsuba for: ``cube_red``, ``cube_green`` — ``V_ρ``'s indirect light on the
    cube (green: the white floor's and wall's bounce alone, red also the cube's own VPLs);
    ``bleed`` — the ring's red − green change at the given options (the light is white, so
    the direct lobes cancel in red − green: the cube's red bounce); ``loss`` — the ring's
    green change of ``V_Δ``'s VPLs alone (``direct = none``).

    ``loss`` is measured, not held to the band: its reference is the bounce of the wall
    that the cube occludes (the floor does not light itself), which ``V_Δ`` cannot carry —
    it holds only the texels the insertion changes, the occluded wall light is unchanged
    light. dlpv's ``loss`` (0.45×) is the floor's own subtracted ``R_µ`` VPLs lighting the
    floor, an LPV artefact (without the floor's VPLs it is −0.03×)."""
    scene, one = ref
    gb, virt, ring = one.gb, one.virt, one.ring
    rv, rr = one.means()
    alb = _image(gb.albedo) / math.pi
    out = {}
    for direct in (True, False):
        # probe off: V_ρ is what is measured (with the bounce probe the objects take their
        # real-surface bounce from the probe and V_ρ is not built)
        o = SPEC.parse_options({"volume_scale": VOLUME_SCALE, "rsm_size": RSM_SIZE, **opts,
                                "probe": False,
                                "direct": "volume" if direct else "none"})
        data = prepare(scene.world, o)
        pos = _image(gb.position)
        assert np.all((pos[ring] > data.grid.origin)
                      & (pos[ring] < data.grid.origin + data.grid.size))
        vols = build_volumes(data, o)
        gr = _image(shade(data, gb, vols)[1])[ring].mean(axis=0)
        if direct:
            out["bleed"] = (gr[0] - gr[1]) / (rr[0] - rr[1])
            half = 0.5 * data.grid.cell
            e = _image(query_irradiance(vols.rho, gb.position + gb.normal * half, gb.normal))
            gv = (e * alb * data.rho_scale)[virt].mean(axis=0)
            out["cube_red"], out["cube_green"] = gv[0] / rv[0], gv[1] / rv[1]
        else:
            out["loss"] = gr[1] / rr[1]
    return out


def _within(r: dict[str, float]) -> bool:
    """Whether the ratios dlpv models (all but ``loss``) lie within ``BAND`` of 1."""
    return all(abs(v - 1.0) <= BAND for k, v in r.items() if k != "loss")


def test_reference_standard_errors_are_small(reference):
    """The reference's standard errors are ≤ 3 % of the four means the checks read."""
    reference[1].assert_precise(cube_channels=(0, 1))


def test_one_bounce_matches_path_traced_reference(reference):
    """dlpv at its defaults but 512² maps (32³, 32 steps, the cube's own VPLs undamped): each of the
    cube's indirect light (red 1.27×, green 0.75× measured) and the cube's red bounce on the
    floor ring (0.92×) within 30 % of Mitsuba's (the ring's loss of bounce light, 0.45×, is
    not modelled: see :func:`_ratios`).

    Rejects the code before issue #33's fix, which damped the cube's VPLs together with the
    antiradiance (``dampen_bounce``: red bounce 0.26×), VPLs at Φ instead of Φ/π
    (3.1×) or without the point-response normalisation (cube's green 0.66×, mutation-checked).
    A missing albedo at the (0.8 white) floor (1.25×) is within the band: not rejected."""
    r = _ratios(reference, {})
    assert _within(r), r


def test_damped_bounce_is_rejected(reference):
    """The check above is able to fail: with the VPLs damped together with the direct lobes
    (today's code before the fix) the bounce misses the band."""
    r = _ratios(reference, {"dampen_bounce": True})
    assert not _within(r), r
    assert r["bleed"] < 1.0 - BAND, r


def _ring_distance_cells(reference) -> np.ndarray:
    """The ring pixels' horizontal distance (cells of the checks' volume) from the cube's
    nearest side face (the cube spans ±0.2 m in x and z)."""
    scene, one = reference
    data = prepare(scene.world, SPEC.parse_options({"volume_scale": VOLUME_SCALE,
                                                    "rsm_size": RSM_SIZE}))
    pos = _image(one.gb.position)[one.ring]
    return (np.max(np.abs(pos[:, [0, 2]]), axis=1) - 0.2) / data.grid.cell


def test_rsm_texels_carry_the_bleed_so_the_lpv_is_what_loses_it(reference):
    """Where the error of the ring's red bleed lies (issue #33, helper-48): the cube's
    ``R_ρ`` texels summed in NumPy as Lambertian emitters, ``Σ ρ/π · Φ_p/π <n_p, ω>+
    <n_x, −ω>+ / r²`` at each ring pixel (no volume), match Mitsuba's red − green within
    10 % (measured 0.99): the maps' flux and positions are right. With the VPLs divided by
    the one-VPL response derived with dlpv's half-cell offsets (1.71, right at 2.5–4
    cells, tests/realtime/test_lpv_reference.py) the bleed falls to 0.47× (dlpv / these
    texels 0.48) — the ring lies 0.7–12 cells from the cube's side faces (median 7.6, 90 %
    beyond 4), past the range where the LPV carries a VPL's light (docs/methods/dlpv.md
    "One VPL and the far field"); dlpv's cell-centre divisor (0.88) keeps it at 0.92×
    (:func:`test_one_bounce_matches_path_traced_reference`, which rejects the derived
    divisor as dlpv's default).

    Rejects maps whose texel flux is not ``ρ Φ_r`` (without the albedo the red − green
    bleed of the white light is 0; reasoned, not mutation-checked: rsm.py is shared with
    dir) and a ring moved into the near field, where this test would no longer say where
    the LPV loses light."""
    from arlight.realtime.rsm import rsm_pair

    scene, one = reference
    o = SPEC.parse_options({"volume_scale": VOLUME_SCALE, "rsm_size": RSM_SIZE,
                            "probe": False})
    data = prepare(scene.world, o)
    _, rr = one.means()
    pos = _image(one.gb.position)[one.ring]
    nrm = _image(one.gb.normal)[one.ring]
    alb = _image(one.gb.albedo)[one.ring] / math.pi
    e = np.zeros((len(pos), 3))
    for pair in rsm_pair(data):
        r = pair.rho_changed()
        ok = np.array(r.valid, bool)
        if not ok.any():
            continue
        p, n, f = (np.stack([np.array(getattr(v, c), np.float64) for c in "xyz"], 1)[ok]
                   for v in (r.position, r.normal, r.flux_out))
        v = pos[:, None, :] - p[None]
        d2 = np.einsum("xmk,xmk->xm", v, v)
        w = v / np.sqrt(d2)[..., None]
        g = (np.maximum(np.einsum("mk,xmk->xm", n, w), 0.0)
             * np.maximum(-np.einsum("xk,xmk->xm", nrm, w), 0.0) / (math.pi * d2))
        e += g @ f
    lit = (alb * e).mean(axis=0)
    texels = (lit[0] - lit[1]) / (rr[0] - rr[1])
    assert 0.9 < texels < 1.1, texels
    dist = _ring_distance_cells(reference)
    assert np.median(dist) > 4.0, np.percentile(dist, [10, 50, 90])
