"""Aimed reflective shadow maps and VPL selection by importance (issue #33).

Each test compares with an independent computation and names the wrong implementation it
rejects."""

from __future__ import annotations

import math

import numpy as np
import pytest

from arlight.backend.mitsuba_scene import build_views
from arlight.jit import ensure_variant
from arlight.methods.dir import pick_by_importance
from arlight.realtime.light_reduction import ReducedLight
from arlight.realtime.rsm import Aim, light_rays, render_rsm
from arlight.scene.load import parse_scene
from tests.conftest import LOOK

ensure_variant()

SIDE = 4.0
LIGHT = np.array([0.3, 1.2, -0.2])
AXIS = np.array([0.2, -1.0, 0.1]) / np.linalg.norm([0.2, -1.0, 0.1])
AIMS = [Aim(np.array([0.8, 0.2, 0.5]), 0.3, 1.0), Aim(np.zeros(3), 1.5, 0.25)]


def _plane():
    """A real, diffuse (ρ 0.5) square floor of side 4 m at y = 0, normal +y."""
    return build_views(parse_scene({
        "camera": {"resolution": [8, 6], "fov_y_deg": 45, "look_at": LOOK},
        "shapes": [{"name": "floor", "role": "real", "type": "rectangle",
                    "size": [SIDE, SIDE], "normal": [0, 1, 0],
                    "material": {"type": "diffuse", "albedo": 0.5}}],
        "lights": [{"type": "point", "position": [0, 1, 0], "intensity": 1.0}]}).world)


def _plane_flux(light: ReducedLight) -> float:
    """Flux (W, red channel) onto the floor by midpoint quadrature over the plane (2000²
    cells), from the light's definition: ``∫ I(ω(x)) cos θ_x / d² dA`` (point, cosine, spot:
    Mitsuba's spot falloff written out: 1 inside the beam, linear in angle to 0 at the
    cutoff) and ``E |cos| A`` (directional)."""
    i0 = float(light.intensity[0])
    if light.kind == "directional":
        return i0 * abs(light.axis[1]) * SIDE * SIDE
    n = 2000
    g = (np.arange(n) + 0.5) / n * SIDE - SIDE / 2
    x, z = np.meshgrid(g, g)
    to = np.stack([x - LIGHT[0], np.full_like(x, -LIGHT[1]), z - LIGHT[2]], -1)
    d = np.linalg.norm(to, axis=-1)
    ca = (to / d[..., None]) @ light.axis
    if light.kind == "point":
        i = np.ones_like(d)
    elif light.kind == "cosine":
        i = np.maximum(ca, 0.0)
    else:
        theta = np.arccos(np.clip(ca, -1.0, 1.0))
        cut, beam = math.acos(light.cos_cutoff), math.acos(light.cos_beam)
        i = np.clip((cut - theta) / (cut - beam), 0.0, 1.0)
    return i0 * float((i * LIGHT[1] / d**3).sum()) * (SIDE / n) ** 2


@pytest.mark.parametrize("kind", ["point", "cosine", "spot", "directional"])
def test_aimed_rsm_flux_is_the_plane_integral(kind):
    """The texels of an RSM — the light's own map alone, and with two aims (a small sphere
    off-centre on the floor, ×1 texels; a large one, ×0.25) — carry the flux the floor
    receives, within 1 % of a quadrature over the plane, and the VPL flux is ρ times it;
    the aimed map puts ≥ 3× as many texels in the small sphere. Rejects aimed texels weighted
    as the light's own (the weights not renormalised: +25 to +100 %), a mixture that leaves
    out the base map's density or an aim's, and a wrong cone/square density."""
    views = _plane()
    light = ReducedLight(kind, LIGHT, AXIS, np.full(3, 2.0),
                         cos_cutoff=math.cos(math.radians(50)),
                         cos_beam=math.cos(math.radians(30)))
    want = _plane_flux(light)
    inside = []
    for aims in ([], AIMS):
        rsm = render_rsm(views.real, light_rays(light, 256, (np.zeros(3), 0.75 * SIDE), aims))
        flux_in = np.array(rsm.flux_in, np.float64).reshape(3, -1)
        assert flux_in[0].sum() == pytest.approx(want, rel=0.01), aims
        assert np.array(rsm.flux_out, np.float64).reshape(3, -1)[0].sum() == pytest.approx(
            0.5 * flux_in[0].sum(), rel=1e-5)
        p = np.array(rsm.position, np.float64).reshape(3, -1).T
        hit = np.array(rsm.valid, bool)
        inside.append(int((hit & (np.linalg.norm(p - AIMS[0].centre, axis=1) < 0.3)).sum()))
    assert inside[1] >= 3 * max(inside[0], 1), inside


def test_aim_holding_the_light_adds_nothing():
    """An aim whose sphere holds a point light adds no texels (its cone would be the whole
    sphere, already the light's own map): rejects a cone of NaN angle."""
    light = ReducedLight("point", LIGHT, AXIS, np.full(3, 1.0))
    rays = light_rays(light, 16, (np.zeros(3), 1.0), [Aim(LIGHT + 0.1, 1.0, 1.0)])
    flux = np.array(rays.flux, np.float64).reshape(3, -1)
    assert flux.shape[1] == 256
    assert flux[0].sum() == pytest.approx(4 * math.pi, rel=1e-5)
    assert np.isfinite(np.array(rays.direction)).all()


def _inclusion(q: np.ndarray, n: int) -> np.ndarray:
    """Reference inclusion probabilities ``π_i = min(1, c q_i)`` with ``Σ π = n``, ``c`` by
    bisection (an independent way to the capped proportional allocation)."""
    lo, hi = 0.0, 1e9
    for _ in range(200):
        c = 0.5 * (lo + hi)
        if np.minimum(1.0, c * q).sum() < n:
            lo = c
        else:
            hi = c
    return np.minimum(1.0, hi * q)


def test_pick_by_importance_is_horvitz_thompson():
    """Over ξ on a fine grid, each index is picked with frequency ``π_i = min(1, c q_i)``
    (bisection reference), never twice, ``n`` indices per draw, and the mean of
    ``Σ f_i / π_i`` is ``Σ f_i``; zero-importance indices are never picked. Rejects picking
    with replacement (``1/(n p)`` weights, duplicates), forgetting the cap at 1, and
    systematic points that skip the last stratum."""
    rng = np.random.default_rng(3)
    q = 0.05 + rng.random(200)
    q[:5] = 50.0  # certain picks
    q[10:20] = 0.0
    f = rng.random(200)
    n = 40
    want = _inclusion(q, n)
    hits = np.zeros(q.size)
    est = []
    grid = (np.arange(2000) + 0.5) / 2000
    for xi in grid:
        idx, pi = pick_by_importance(q, n, xi)
        assert idx.size == n and np.unique(idx).size == n
        assert np.allclose(pi, want[idx], rtol=1e-6)
        hits[idx] += 1
        est.append(float((f[idx] / pi).sum()))
    assert np.allclose(hits / grid.size, want, atol=2e-3)
    assert not hits[10:20].any()
    assert np.mean(est) == pytest.approx(f[q > 0].sum(), rel=2e-3)


def test_pick_takes_every_texel_when_few():
    """Fewer positive importances than asked: every one, with π = 1 (rejects a division by
    a zero sum or picking zero-flux misses)."""
    idx, pi = pick_by_importance(np.array([0.0, 2.0, 0.0, 1.0]), 8, 0.5)
    assert list(idx) == [1, 3] and np.all(pi == 1.0)


def test_mixture_density_of_an_aimed_cone_is_normalised():
    """The aimed cone's texel directions fall inside the cone the sphere subtends, and with
    only an aim (``rsm`` 1, aim share large) the cone's flux sum approaches ``I · Ω_cone``
    for a point light whose own map puts almost nothing there (independent: solid angle
    ``2π(1 − cos α)``). Rejects a cone half-angle of ``asin`` vs ``acos`` mixed up."""
    light = ReducedLight("point", np.zeros(3), np.zeros(3), np.full(3, 1.0))
    c, r = np.array([0.0, 0.0, 5.0]), 1.0
    rays = light_rays(light, 4, (np.zeros(3), 1.0), [Aim(c, r, 64.0)])
    d = np.array(rays.direction, np.float64).reshape(3, -1).T
    cos_a = math.sqrt(1 - (r / 5.0) ** 2)
    aimed = d[16:]
    assert (aimed[:, 2] >= cos_a - 1e-6).all()
    flux = np.array(rays.flux, np.float64).reshape(3, -1)[0]
    in_cone = d[:, 2] >= cos_a
    assert flux[in_cone].sum() == pytest.approx(2 * math.pi * (1 - cos_a), rel=0.02)
