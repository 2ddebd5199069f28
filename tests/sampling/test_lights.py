"""Light sampling by power and spherical rectangles (issue #22).

Wrong implementations rejected: a spherical-rectangle warp whose density is not ``1/S``
(the irradiance estimate would be biased against Mitsuba's area sampling); a ``pdf`` that
disagrees with the sampled ``pdf`` (MIS weights would not sum to one); selection
probabilities missing from either; the wrong emitting side of a rectangle; a solid angle
that is wrong (checked against the analytic one of a square seen from its axis).
"""

import math
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import arlight
from arlight.sampling import lights
from arlight.sampling.lights import LightSampler, rectangle_solid_angle


def _scene(flip: bool = False):
    t = mi.ScalarTransform4f().translate([0.2, 1.5, -0.1]).rotate([1, 0, 0], -90 if flip
                                                                    else 90)
    return mi.load_dict({
        "type": "scene",
        "env": {"type": "constant", "radiance": {"type": "rgb", "value": [0.2, 0.3, 0.4]}},
        "light": {"type": "rectangle", "to_world": t.scale([0.8, 0.4, 1.0]),
                  "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [5, 4, 3]}}},
        "pt": {"type": "point", "position": [0.5, 1.0, 0.3],
               "intensity": {"type": "rgb", "value": [1, 1, 1]}},
    })


def _points(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    p = rng.uniform([-1, 0, -1], [1, 1.2, 1], (n, 3)).astype(np.float32)
    it = dr.zeros(mi.Interaction3f, n)
    it.p = mi.Point3f(*p.T)
    return it


def test_solid_angle_of_a_square_on_its_axis():
    """A 2a × 2a square at distance h: Ω = 4 asin(a² / (a² + h²))."""
    a, h = 0.5, 0.7
    o = mi.Point3f(0.0, 0.0, 0.0)
    s = rectangle_solid_angle(o, mi.Point3f(-a, -a, h), mi.Vector3f(2 * a, 0, 0),
                              mi.Vector3f(0, 2 * a, 0))
    assert abs(s[0] - 4 * math.asin(a * a / (a * a + h * h))) < 1e-5


def test_pdf_agrees_with_sampled_directions():
    """pdf(it, ds) of the emitter hit along a sampled direction equals the sample's pdf."""
    scene = _scene()
    ls = LightSampler(scene, selection="power")
    assert ls.rect_np.sum() == 1
    n = 20000
    it = _points(n)
    rng = np.random.default_rng(1)
    u = mi.Point2f(*rng.random((2, n)).astype(np.float32))
    ds, w = ls.sample(it, u, mi.Bool(True))
    ray = it.spawn_ray(ds.d)
    si = scene.ray_intersect(ray)
    ds_hit = mi.DirectionSample3f(scene, si, it)  # the rectangle, or the env on a miss
    same = (dr.reinterpret_array(mi.UInt32, ds_hit.emitter)
            == dr.reinterpret_array(mi.UInt32, ds.emitter)) & ~ds.delta & (ds.pdf > 0)
    pdf_hit = ls.pdf(it, ds_hit, same)
    a, b = np.array(ds.pdf), np.array(pdf_hit)
    m = np.array(same)
    assert m.sum() > 10000
    np.testing.assert_allclose(b[m], a[m], rtol=2e-3)
    # selection probabilities ∝ power: env 4π²R²L̄ (R: the scene's bounding radius), point
    # 4πI, one-sided rectangle πAL (luminance weights)
    lum = lambda c: 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]  # noqa: E731
    radius = math.hypot(1.6, 0.8) / 2
    want = {"ConstantBackgroundEmitter": 4 * math.pi**2 * radius**2 * lum([0.2, 0.3, 0.4]),
            "PointLight": 4 * math.pi, "AreaLight": math.pi * 1.6 * 0.8 * lum([5, 4, 3])}
    w = np.array([want[e.class_name()] for e in scene.emitters()])
    np.testing.assert_allclose(ls.pmf_np, w / w.sum(), rtol=1e-4)


@pytest.mark.parametrize("flip", [False, True])
def test_irradiance_matches_mitsubas_area_sampling(flip):
    """E[w · cos θ] (rectangle only, unoccluded) equals Mitsuba's estimate (4 SE)."""
    scene = _scene(flip)
    rect_only = mi.load_dict({"type": "scene", "light": dict(
        type="rectangle", to_world=mi.ScalarTransform4f().translate([0.2, 1.5, -0.1])
        .rotate([1, 0, 0], -90 if flip else 90).scale([0.8, 0.4, 1.0]),
        emitter={"type": "area", "radiance": {"type": "rgb", "value": [5, 4, 3]}})})
    ls = LightSampler(rect_only)
    n_pts, n = 8, 200_000
    it = _points(n_pts, 3)
    idx = dr.arange(mi.UInt32, n_pts * n) // n
    it = dr.gather(mi.Interaction3f, it, idx)
    up = mi.Vector3f(0, 1, 0)
    rng = np.random.default_rng(2)
    u = mi.Point2f(*rng.random((2, n_pts * n)).astype(np.float32))
    ds, w = ls.sample(it, u, mi.Bool(True))
    ours = np.array(w[0] * dr.maximum(dr.dot(ds.d, up), 0.0)).reshape(n_pts, n)
    ds_m, w_m = rect_only.sample_emitter_direction(it, u, False, mi.Bool(True))
    theirs = np.array(w_m[0] * dr.maximum(dr.dot(ds_m.d, up), 0.0)).reshape(n_pts, n)
    for a, b in zip(ours, theirs, strict=True):
        se = math.sqrt(a.var() / n + b.var() / n) + 1e-9
        assert abs(a.mean() - b.mean()) < 4 * se, (a.mean(), b.mean(), se)
    if flip:  # the light faces away from every point: no light from either
        assert not ours.any() and not theirs.any()
    else:  # solid-angle sampling is the lower-variance estimator at these points
        assert ours.var(axis=1).sum() < 0.5 * theirs.var(axis=1).sum()
    del scene


# -- selection by importance at the shading point (issue #35) ---------------------------------

ENVMAP = str(Path(arlight.__file__).parent / "data/light/grace_latlong_256x128.hdr")


def _all_lights(env: str = "constant", ground: float = 0.0, sky_only: bool = False):
    """One emitter of every kind: rectangle, sphere, point, spot, sun, and a constant sky or
    an environment map (``sky_only``: just the sky); ``ground`` > 0 adds a square ground of
    that side (m, no emitter)."""
    look = mi.ScalarTransform4f().look_at(origin=[1.5, 2.0, 0.5], target=[0, 0, 0], up=[0, 1, 0])
    d = {
        "type": "scene",
        "rect": {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate(
            [0.2, 1.5, -0.1]).rotate([1, 0, 0], 90).scale([0.3, 0.2, 1.0]),
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [50, 40, 30]}}},
        "bulb": {"type": "sphere", "center": [-0.8, 1.2, 0.4], "radius": 0.05,
                 "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 300}}},
        "pt": {"type": "point", "position": [0.5, 1.0, 0.3],
               "intensity": {"type": "rgb", "value": [1, 1, 1]}},
        "spot": {"type": "spot", "to_world": look, "cutoff_angle": 25.0, "beam_width": 18.0,
                 "intensity": {"type": "rgb", "value": 40}},
        "sun": {"type": "directional", "direction": [0.3, -1.0, 0.2],
                "irradiance": {"type": "rgb", "value": 3.0}},
    }
    if sky_only:
        d = {"type": "scene"}
    if env == "constant":
        d["env"] = {"type": "constant", "radiance": {"type": "rgb", "value": [0.2, 0.3, 0.4]}}
    else:
        d["env"] = {"type": "envmap", "filename": ENVMAP, "scale": 0.5}
    if ground:
        d["ground"] = {"type": "rectangle", "to_world": mi.ScalarTransform4f().rotate(
            [1, 0, 0], -90).scale([ground / 2, ground / 2, 1.0])}
    return mi.load_dict(d)


def _contexts(n: int, seed: int = 0, normal=None):
    """``n`` shading contexts: points above the ground, normals up-ish (or ``normal``)."""
    rng = np.random.default_rng(seed)
    p = rng.uniform([-1, 0, -1], [1, 0.8, 1], (n, 3)).astype(np.float32)
    if normal is None:
        nr = rng.normal(size=(n, 3)) + np.array([0, 2.0, 0])
    else:
        nr = np.broadcast_to(np.asarray(normal, np.float64), (n, 3))
    nr = (nr / np.linalg.norm(nr, axis=1, keepdims=True)).astype(np.float32)
    it = dr.zeros(mi.Interaction3f, n)
    it.p, it.n = mi.Point3f(*p.T), mi.Vector3f(*nr.T)
    return it, p, nr


@pytest.mark.parametrize("env,unrolled", [("constant", True), ("envmap", True),
                                          ("envmap", False)])
def test_importance_selection_frequency_equals_its_pmf(env, unrolled, monkeypatch):
    """At each of a few shading contexts, the share of 100 000 samples choosing each emitter
    (rectangle, sphere, point, spot, sun, sky) equals ``selection_pmf`` (5 binomial SE), and the
    pmf sums to one. Rejects a sampler whose pdf is not the probability it sampled with (MIS
    weights that do not sum to one): e.g. the defensive share or the reservoir's rescaling
    done differently in ``sample`` and ``pdf``. Both the per-light code (``unrolled``) and
    the loop over the light table (``MAX_UNROLLED`` = 0) are checked."""
    if not unrolled:
        monkeypatch.setattr(lights, "MAX_UNROLLED", 0)
    scene = _all_lights(env)
    ls = LightSampler(scene)
    assert ls.unrolled == unrolled
    _, p, nr = _contexts(6, 3)
    n = 100_000
    for k in range(len(p)):
        it = dr.zeros(mi.Interaction3f, n)
        it.p = mi.Point3f(*(np.full(n, v, np.float32) for v in p[k]))
        it.n = mi.Vector3f(*(np.full(n, v, np.float32) for v in nr[k]))
        g = (np.arange(n) + 0.5) / n  # stratified: exact shares up to O(1/n)
        u = mi.Point2f(np.random.default_rng(k).permutation(g).astype(np.float32),
                       np.random.default_rng(k + 9).random(n).astype(np.float32))
        ds, _ = ls.sample(it, u, mi.Bool(True))
        idx = np.array(ls._index(ds.emitter, mi.Bool(True)))
        chosen = np.array(dr.reinterpret_array(mi.UInt32, ds.emitter)) != 0
        freq = np.bincount(idx[chosen], minlength=ls.n) / n
        ctx = dr.zeros(mi.Interaction3f, 1)
        ctx.p, ctx.n = mi.Point3f(*map(float, p[k])), mi.Vector3f(*map(float, nr[k]))
        pmf = np.array([ls.selection_pmf(ctx, mi.UInt32(i), mi.Bool(True))[0]
                        for i in range(ls.n)])
        assert abs(pmf.sum() - 1) < 1e-5, pmf
        se = np.sqrt(pmf * (1 - pmf) / n) + 1e-6
        assert np.all(np.abs(freq - pmf) < 5 * se), (k, freq, pmf)


def test_importance_is_the_irradiance_of_point_and_distant_lights():
    """Independent physics: a point light's importance is its irradiance ``I |cos| / d²``, a
    sun's ``E |cos|``, a small far rectangle's tends to ``L A cos θ_l cos θ_i / d²``
    (within 1 %), a rectangle seen from behind has none, a spot's is zero outside its cone.
    Rejects the global power weights (``4π² R² L̄`` for the sky, ``π R² E`` for the sun: they
    depend on the scene's size, not on the point)."""
    scene = _all_lights()
    t = LightSampler(scene).table
    names = [e.class_name() for e in scene.emitters()]
    it, p, nr = _contexts(64, 5)
    imp = t.importance(p, nr)
    i_pt = names.index("PointLight")
    v = np.array([0.5, 1.0, 0.3]) - p
    d2 = (v * v).sum(1)
    np.testing.assert_allclose(imp[:, i_pt], np.abs((v * nr).sum(1)) / np.sqrt(d2) / d2,
                               rtol=1e-5)
    i_sun = names.index("DirectionalEmitter")
    to_sun = -np.array([0.3, -1.0, 0.2]) / np.linalg.norm([0.3, -1.0, 0.2])
    np.testing.assert_allclose(imp[:, i_sun], 3.0 * np.abs(nr @ to_sun), rtol=1e-5)
    # a far rectangle: 0.6 × 0.4 m, radiance 50/40/30, seen from 40 m along its normal (-y)
    lum = 0.2126 * 50 + 0.7152 * 40 + 0.0722 * 30
    i_rect = next(i for i in range(len(names)) if names[i] == "AreaLight"
                  and t.one_sided[i])  # the rectangle (the sphere emits all round)
    q = np.array([[0.2, 1.5 - 40.0, -0.1]])
    up = np.array([[0.0, 1.0, 0.0]])
    np.testing.assert_allclose(t.importance(q, up)[0, i_rect], lum * 0.24 / 40.0**2, rtol=0.01)
    assert t.importance(np.array([[0.2, 1.8, -0.1]]), up)[0, i_rect] == 0.0  # behind it
    i_spot = names.index("SpotLight")
    assert t.importance(np.array([[-3.0, 0.0, 3.0]]), up)[0, i_spot] == 0.0  # outside 25°
    assert t.importance(np.array([[0.0, 0.0, 0.0]]), up)[0, i_spot] > 0.0  # on the axis


def test_selection_does_not_depend_on_the_scene_size():
    """Adding a 2 km ground far below changes no selection probability at a point (the
    power-based selection of issue #22 gave the sky ~99 % of the samples in large worlds)."""
    small, large = _all_lights(), _all_lights(ground=2000.0)
    a, b = LightSampler(small), LightSampler(large)
    _, p, nr = _contexts(32, 7)
    np.testing.assert_allclose(a.table.importance(p, nr), b.table.importance(p, nr), rtol=1e-6)
    sky = [e.class_name() for e in large.emitters()].index("ConstantBackgroundEmitter")
    assert b.table.power[sky] > 100 * a.table.power[sky]  # the old weights did depend on it


def test_drjit_importance_matches_the_numpy_one():
    """The Dr.Jit importance (used to sample) equals the float64 NumPy one (acos/asin rather
    than the cos/sin subtraction), every light: read from the table per lane and evaluated
    per light by its kind's formula (``importances``; rejects e.g. a light given another
    kind's formula, or the bounds of another row)."""
    scene = _all_lights("envmap")
    ls = LightSampler(scene)
    assert ls.unrolled
    it, p, nr = _contexts(2000, 11)
    want = ls.table.importance(p, nr)
    per_light = ls.importances(it)
    assert len(per_light) == ls.n
    for i in range(ls.n):
        tol = {"rtol": 2e-3, "atol": 1e-6 * want[:, i].max()}
        got = np.array(ls.importance(mi.UInt32(i), it.p, it.n, mi.Bool(True)))
        np.testing.assert_allclose(got, want[:, i], **tol)
        np.testing.assert_allclose(np.array(per_light[i]), want[:, i], **tol)


@pytest.mark.parametrize("env,sky_only", [("constant", False), ("envmap", False),
                                          ("constant", True), ("envmap", True)])
def test_mis_of_light_and_cosine_sampling_is_unbiased(env, sky_only):
    """Irradiance at shading points, two independent ways: our light sample and a cosine
    (BSDF) sample, each with the power-heuristic MIS weight built from ``LightSampler.pdf``,
    against Mitsuba's own light sampling without MIS (visibility tested in both; 4 SE per
    point). Rejects MIS weights that do not sum to one — a ``pdf`` that omits the selection
    probability, the cosine share of the sky (caught by the sky-only worlds: with every light
    the error drowns in the others' noise), or the zero below the horizon."""
    scene = _all_lights(env, ground=6.0, sky_only=sky_only)
    ls = LightSampler(scene)
    n_pts, n = 6, 60_000
    _, p, nr = _contexts(n_pts, 13)
    p[:, 1] = np.maximum(p[:, 1], 0.05)
    idx = np.repeat(np.arange(n_pts), n)
    it = dr.zeros(mi.Interaction3f, n_pts * n)
    it.p = mi.Point3f(*p[idx].T)
    it.n = mi.Vector3f(*nr[idx].T)
    rng = np.random.default_rng(17)
    u1 = mi.Point2f(*rng.random((2, n_pts * n)).astype(np.float32))
    u2 = mi.Point2f(*rng.random((2, n_pts * n)).astype(np.float32))

    def mis(a, b):
        return dr.select(a > 0, a * a / (a * a + b * b), 0.0)

    active = mi.Bool(True)
    ds, w = ls.sample(it, u1, active)
    cos_l = dr.maximum(dr.dot(ds.d, it.n), 0.0)
    vis = ~scene.ray_test(it.spawn_ray_to(ds.p), active)
    e_light = dr.select(vis, mi.luminance(w) * cos_l, 0.0) * dr.select(
        ds.delta, 1.0, mis(ds.pdf, cos_l * dr.inv_pi))
    d_b = mi.Frame3f(it.n).to_world(mi.warp.square_to_cosine_hemisphere(u2))
    si = scene.ray_intersect(it.spawn_ray(d_b))
    ds_b = mi.DirectionSample3f(scene, si, it)
    le = mi.luminance(ds_b.emitter.eval(si, ds_b.emitter != None))  # noqa: E711
    pdf_b = dr.maximum(dr.dot(d_b, it.n), 0.0) * dr.inv_pi
    pdf_l = ls.pdf(it, ds_b, active)
    e_bsdf = dr.select(pdf_b > 0, le * dr.dot(d_b, it.n) / pdf_b, 0.0) * mis(pdf_b, pdf_l)
    ours = np.array(e_light + e_bsdf).reshape(n_pts, n)
    ds_m, w_m = scene.sample_emitter_direction(it, u1, True, active)
    theirs = np.array(mi.luminance(w_m) * dr.maximum(dr.dot(ds_m.d, it.n), 0.0)
                      ).reshape(n_pts, n)
    for a, b in zip(ours, theirs, strict=True):
        se = math.sqrt(a.var() / n + b.var() / n)
        assert abs(a.mean() - b.mean()) < 4 * se, (a.mean(), b.mean(), se)
