"""Tests of differential caustic photon mapping (Kán §4.1.2; digest checklist 14–16).

Each test names the wrong implementation it rejects.
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from arlight.errors import InputError
from arlight.methods import RenderSettings, get_method
from arlight.scene.load import parse_scene
from arlight.tracing.photons import (
    REAL_ONLY,
    SHARED,
    Cone,
    PhotonMap,
    PhotonSettings,
    StoredPhotons,
    build_photon_maps,
    emit_photons,
    merge_cones,
    trace_photons,
)
from arlight.tracing.scenes import prepare_scenes

IOR = 1.5
R = 0.1
TILT = math.radians(30.0)  # light direction off the vertical
DIST = 1.2  # light to sphere centre, m
INTENSITY = 2.0  # W/sr


def focus_geometry() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sphere centre, light position and paraxial focus (on the plane y = 0, by choice of the
    sphere's height): ball lens EFL f = nR/(2(n − 1)) from the centre, 1/s_o + 1/s_i = 1/f."""
    f = IOR * R / (2 * (IOR - 1))
    s_i = f * DIST / (DIST - f)
    u = np.array([math.sin(TILT), -math.cos(TILT), 0.0])  # light -> centre
    c = np.array([0.0, s_i * math.cos(TILT), 0.0])
    return c, c - DIST * u, c + s_i * u


def sphere_scene(glass_role: str = "virtual", extra: list[dict] | None = None,
                 w: int = 48, h: int = 36, light: np.ndarray | None = None) -> dict:
    c, lp, _ = focus_geometry()
    lp = lp if light is None else light
    shapes = [{"name": "floor", "role": "real", "type": "rectangle", "size": [2, 2],
               "normal": [0, 1, 0], "material": {"type": "diffuse", "albedo": 0.6}},
              {"name": "glass", "role": glass_role, "type": "sphere", "radius": R,
               "transform": {"translate": [float(x) for x in c]},
               "material": {"type": "glass", "ior": IOR}}]
    return {"camera": {"resolution": [w, h], "fov_y_deg": 40,
                       "look_at": {"origin": [0.35, 0.55, 0.55], "target": [0.05, 0.0, 0.0]}},
            "shapes": shapes + (extra or []),
            "lights": [{"type": "point", "position": [float(x) for x in lp],
                        "intensity": INTENSITY}]}


def make(d: dict):
    sc = parse_scene(d)
    frame = np.full((sc.camera.height, sc.camera.width, 3), 0.2, np.float32)
    return sc.with_frame(frame)


def render(scene, caustics: bool, spp: int = 4, **opts):
    o = {"caustics": "photons" if caustics else "none", **opts}
    if not caustics:
        o = {k: v for k, v in o.items() if k == "caustics"}
    return get_method("onepass")(scene, RenderSettings(spp=spp, options=o))


# ------------------------------------------------------------- NumPy reference (independent)
def _fresnel(cos_i: np.ndarray, eta: np.ndarray) -> np.ndarray:
    """Unpolarised Fresnel reflectance; ``eta`` = n_t/n_i; 1 under total internal reflection."""
    sin_t2 = (1 - cos_i ** 2) / eta ** 2
    tir = sin_t2 >= 1
    cos_t = np.sqrt(np.clip(1 - sin_t2, 0, 1))
    rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    return np.where(tir, 1.0, 0.5 * (rs ** 2 + rp ** 2))


def reference_hits(c: np.ndarray, lp: np.ndarray, n: int = 800
                   ) -> tuple[np.ndarray, np.ndarray, float]:
    """(points on the plane y = 0 reached after ≥ 1 specular event, their power in W, power
    into the sphere's cone in W): midpoint quadrature over the cone in (cos θ, φ), n × 2n
    rays, each split by exact Fresnel at every sphere hit (depth ≤ 10), all in NumPy."""
    axis = (c - lp) / np.linalg.norm(c - lp)
    d = np.linalg.norm(c - lp)
    cos_max = math.sqrt(1 - (R / d) ** 2)
    omega = 2 * math.pi * (1 - cos_max)
    ct = 1 - (np.arange(n) + 0.5) / n * (1 - cos_max)
    ph = (np.arange(2 * n) + 0.5) / (2 * n) * 2 * math.pi
    ct, ph = (a.ravel() for a in np.meshgrid(ct, ph, indexing="ij"))
    st = np.sqrt(1 - ct ** 2)
    e1 = np.cross(axis, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    dirs = (st * np.cos(ph))[:, None] * e1 + (st * np.sin(ph))[:, None] * e2 + ct[:, None] * axis
    w = np.full(len(ct), INTENSITY * omega / len(ct))
    org = np.broadcast_to(lp, dirs.shape).copy()
    inside = np.zeros(len(ct), bool)
    pts, pws = [], []
    for _ in range(10):
        oc = org - c
        b = np.sum(oc * dirs, 1)
        disc = b * b - (np.sum(oc * oc, 1) - R * R)
        t = np.where(inside, -b + np.sqrt(np.maximum(disc, 0)), -b - np.sqrt(np.maximum(disc, 0)))
        hit = (disc > 0) & (t > 1e-9)
        # rays leaving the sphere downwards reach the plane
        down = ~hit & ~inside & (dirs[:, 1] < 0)
        tp = -org[down, 1] / dirs[down, 1]
        pts.append(org[down] + tp[:, None] * dirs[down])
        pws.append(w[down])
        org, dirs, w, inside, t = org[hit], dirs[hit], w[hit], inside[hit], t[hit]
        p = org + t[:, None] * dirs
        nrm = (p - c) / R
        nrm = np.where(inside[:, None], -nrm, nrm)  # facing the incoming ray
        cos_i = -np.sum(dirs * nrm, 1)
        eta = np.where(inside, 1 / IOR, IOR)
        f = _fresnel(cos_i, eta)
        refl = dirs + 2 * cos_i[:, None] * nrm
        k = 1 / eta
        cos_t = np.sqrt(np.clip(1 - k ** 2 * (1 - cos_i ** 2), 0, 1))
        refr = k[:, None] * dirs + (k * cos_i - cos_t)[:, None] * nrm
        org = np.concatenate([p, p])
        dirs = np.concatenate([refl, refr])
        w = np.concatenate([w * f, w * (1 - f)])
        inside = np.concatenate([inside, ~inside])
        alive = w > 1e-12
        org, dirs, w, inside = org[alive], dirs[alive], w[alive], inside[alive]
    return np.concatenate(pts), np.concatenate(pws), INTENSITY * omega


def reference_power_on_plane(c: np.ndarray, lp: np.ndarray, box: float, n: int = 800
                             ) -> tuple[float, float]:
    """(power on the plane within |x − c_x|, |z − c_z| < box, power into the cone), W."""
    pts, pw, into = reference_hits(c, lp, n)
    on = (np.abs(pts[:, 0] - c[0]) < box) & (np.abs(pts[:, 2] - c[2]) < box)
    return float(pw[on].sum()), into


def _views(d: dict):
    sc = parse_scene(d)
    return sc.world, prepare_scenes(sc.world).views


def irradiance_grid(pmap: PhotonMap, center: np.ndarray, half: float, step: float,
                    which: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Kernel-estimated irradiance (W/m²) of the mixed and real solutions on a grid of the
    plane y = 0, and the grid's x, z coordinates."""
    xs = np.arange(center[0] - half + step / 2, center[0] + half, step)
    zs = np.arange(center[2] - half + step / 2, center[2] + half, step)
    gx, gz = np.meshgrid(xs, zs, indexing="ij")
    n = gx.size
    p = mi.Point3f(mi.Float(gx.ravel()), dr.zeros(mi.Float, n), mi.Float(gz.ravel()))
    nrm = mi.Vector3f(dr.zeros(mi.Float, n), dr.ones(mi.Float, n), dr.zeros(mi.Float, n))
    em, er = pmap.estimate(p, nrm, dr.full(mi.UInt32, which, n), dr.full(mi.Bool, True, n))
    return (np.asarray(em)[0].reshape(gx.shape), np.asarray(er)[0].reshape(gx.shape), gx, gz)


# --------------------------------------------------------------------------------- tests
def test_single_photon_kernel_normalisation():
    """One photon of 1 W: the estimate at it is 2/(πh²) (Eq. 4.5 over h²) and integrates to
    1 W over the plane. Rejects a kernel without its 2/π or h², a kernel over the 3D ball
    (∫ = 4/3·…), and a grid search that misses neighbouring cells (photon on a cell corner)."""
    h = 0.02
    for pos in ([0.0, 0.0, 0.0], [0.04, 0.0, -0.04], [0.0399999, 0.0, 0.0400001]):
        z = mi.Float([0.0])
        sp = StoredPhotons(mi.Point3f(*(mi.Float([v]) for v in pos)), mi.Vector3f(z, z + 1, z),
                           mi.Color3f(z + 1, z + 1, z + 1), mi.UInt32([SHARED]))
        pm = PhotonMap.build([sp], [h])
        em, er, gx, gz = irradiance_grid(pm, np.array(pos), 0.03, h / 40)
        assert np.array_equal(em, er)
        assert em.sum() * (h / 40) ** 2 == pytest.approx(1.0, rel=2e-3)
        peak = irradiance_grid(pm, np.array(pos), h / 1000, h / 500)[0].max()
        assert peak == pytest.approx(2 / (math.pi * h * h), rel=1e-3)


def test_hash_grid_equals_brute_force():
    """The hash-grid estimate equals a brute-force sum over all photons (NumPy, float64) at
    random queries, classes split. Rejects missing or doubly visited cells (hash collisions
    of two of the 8 cells), a wrong side test, class bookkeeping errors."""
    rng = np.random.default_rng(3)
    n, h = 4000, 0.05
    pos = rng.uniform(-0.3, 0.3, (n, 3)).astype(np.float32)
    pos[:, 1] *= 0.1
    wi = rng.normal(size=(n, 3)).astype(np.float32)
    flux = rng.uniform(0.1, 1.0, (n, 3)).astype(np.float32)
    cls = rng.integers(0, 3, n).astype(np.uint32)
    sp = StoredPhotons(mi.Point3f(*pos.T), mi.Vector3f(*wi.T), mi.Color3f(*flux.T),
                       mi.UInt32(cls))
    pm = PhotonMap.build([sp], [h])
    q = rng.uniform(-0.3, 0.3, (500, 3)).astype(np.float32)
    q[:, 1] *= 0.1
    qn = np.tile(np.array([0, 1, 0], np.float32), (500, 1))
    em, er = pm.estimate(mi.Point3f(*q.T), mi.Vector3f(*qn.T), dr.zeros(mi.UInt32, 500),
                         dr.full(mi.Bool, True, 500))
    d2 = np.sum((q[:, None, :].astype(np.float64) - pos[None]) ** 2, axis=2)
    k = np.where((d2 < h * h) & ((wi @ qn[0]) > 0)[None], (2 / math.pi) * (1 - d2 / h ** 2)
                 / h ** 2, 0.0)
    ref_m = k @ np.where((cls != REAL_ONLY)[:, None], flux, 0.0)
    ref_r = k @ np.where((cls != 1)[:, None], flux, 0.0)
    np.testing.assert_allclose(np.asarray(em).T, ref_m, rtol=2e-4, atol=1e-3)
    np.testing.assert_allclose(np.asarray(er).T, ref_r, rtol=2e-4, atol=1e-3)
    assert (ref_m > 0).mean() > 0.5  # not vacuous


def test_emission_power_equals_cone_solid_angle():
    """Σ Φ of the photons shot at a sphere equals I·Ω_sphere (checklist 14, within 1e-4: the
    disk samples are stratified) and every photon hits the sphere. Rejects Kán's literal disk
    of radius R (misses the rim: Ω too small), a missing 1/p(ω) or 1/N."""
    world, views = _views(sphere_scene())
    c, lp, _ = focus_geometry()
    em = emit_photons(world, views, 40_000, seed=1)
    omega = 2 * math.pi * (1 - math.sqrt(1 - (R / DIST) ** 2))
    np.testing.assert_allclose(em.power, INTENSITY * omega, rtol=1e-4)
    si = views.mixed.scene.ray_intersect(em.rays)
    hit_glass = np.asarray(views.mixed.hit_shape(si)) == 1
    assert hit_glass.mean() > 0.999


def test_overlapping_generators_are_merged():
    """Two spheres whose cones overlap become one bounding sphere (no direction sampled
    twice); disjoint cones stay apart. Rejects sampling each cone separately (double power
    in the overlap)."""
    light = np.zeros(3)
    a, b = Cone(np.array([0.0, -1.0, 0.0]), 0.1), Cone(np.array([0.15, -1.0, 0.0]), 0.1)
    far = Cone(np.array([0.0, 1.0, 0.0]), 0.1)
    out = merge_cones([a, b, far], light)
    assert len(out) == 2
    big = [cn for cn in out if cn.center[1] < 0][0]
    for s in (a, b):
        assert np.linalg.norm(s.center - big.center) + s.radius <= big.radius + 1e-9


@pytest.fixture(scope="module")
def virtual_sphere_map():
    world, views = _views(sphere_scene())
    ps = PhotonSettings(photons=400_000, radius=0.004)
    em = emit_photons(world, views, ps.photons, seed=0)
    sp = trace_photons(views, em, 8, seed=0)
    return em, sp, PhotonMap.build([sp], ps.radii())


def test_photon_path_length_follows_max_depth():
    """``max_depth`` counts vertices, Mitsuba's convention: the ball-lens caustic L S S D
    needs 4, so ``max_depth = 3`` stores only the photons reflected once off the sphere
    (L S D, a few % by Fresnel). Rejects an off-by-one that lets a photon make
    ``max_depth − 1`` specular bounces."""
    world, views = _views(sphere_scene())
    em = emit_photons(world, views, 20_000, seed=1)
    stored = {d: np.asarray(trace_photons(views, em, d, seed=1).flux)[0].sum() for d in (3, 4)}
    assert 0 < stored[3] < 0.2 * stored[4]


def test_caustic_energy_matches_fresnel_reference(virtual_sphere_map):
    """The caustic's power on the plane (the kernel estimate integrated over a 0.5 m square
    around the sphere) equals the power through the sphere after Fresnel losses, from an
    independent NumPy tracer with exact Fresnel splitting, within 5 % (issue acceptance;
    the photon count gives ≪ 1 % Monte Carlo error). Rejects a missing Fresnel weight (photon
    flux not reduced at the reflect/refract choice), lost internal-reflection paths, a wrong
    kernel normalisation, photons stored before their second refraction."""
    _, sp, pm = virtual_sphere_map
    c, lp, _ = focus_geometry()
    half, step = 0.25, 0.002
    em, _, _, _ = irradiance_grid(pm, c, half, step)
    est = em.sum() * step * step
    ref, into = reference_power_on_plane(c, lp, half)
    assert ref < 0.95 * into  # Fresnel losses and reflections out of the box are real
    assert est == pytest.approx(ref, rel=0.05)
    # the stored photons inside the square say the same (integral of the kernel = 1)
    p = np.asarray(sp.p)
    inside = (np.abs(p[0] - c[0]) < half - 0.01) & (np.abs(p[2] - c[2]) < half - 0.01)
    assert np.asarray(sp.flux)[0][inside].sum() == pytest.approx(ref, rel=0.05)


def test_caustic_peak_at_paraxial_focus(virtual_sphere_map):
    """The irradiance peak lies within one kernel radius (4 mm) of the paraxial focus of the
    ball lens (f = nR/(2(n−1)), thin-lens imaging of the light), on a plane through the
    focus, with the light 30° off the vertical. Rejects wrong refraction (e.g. η inverted
    moves the focus by centimetres) and a missing displacement along the tilted axis."""
    _, _, pm = virtual_sphere_map
    _, _, focus = focus_geometry()
    em, _, gx, gz = irradiance_grid(pm, focus, 0.03, 0.0005)
    i = np.unravel_index(np.argmax(em), em.shape)
    peak = np.array([gx[i], 0.0, gz[i]])
    assert np.linalg.norm(peak - focus) < 0.004
    assert em[i] > 50 * INTENSITY / DIST ** 2  # a real focus, far above direct irradiance


def test_no_virtual_object_composite_is_frame_with_real_glass_caustic():
    """No virtual object, a real glass sphere focusing a caustic: the composite equals the
    frame bit for bit, the mixed layer shows the caustic (it is in the photograph).
    Rejects treating real-generator photons as mixed-only (a delta where the real caustic
    is)."""
    scene = make(sphere_scene(glass_role="real"))
    on = render(scene, True, photons=50_000)
    off = render(scene, False)
    np.testing.assert_array_equal(on.composite, scene.frame)
    assert not np.any(on.delta)
    assert (on.mixed - off.mixed).max() > 0.05
    assert on.stats["photons_shared"] == on.stats["photons_stored"] > 0


def test_real_glass_with_unrelated_virtual_object_gives_no_caustic_delta():
    """A real glass sphere's caustic with a virtual box beside it: where the real caustic is,
    the delta is the same with and without photon caustics (to float round-off) though I_m
    gains the caustic. Only the few photons the sphere reflects onto the box differ (the box
    shades them: mixed-only on the box, real-only behind it). Rejects tagging photons
    mixed-only because the world has virtual objects."""
    box = {"name": "box", "role": "virtual", "type": "box", "size": [0.1, 0.1, 0.1],
           "transform": {"translate": [-0.3, 0.05, 0.2]},
           "material": {"type": "diffuse", "albedo": 0.5}}
    scene = make(sphere_scene(glass_role="real", extra=[box]))
    on = render(scene, True, photons=50_000)
    off = render(scene, False)
    caustic = (on.mixed - off.mixed).max(axis=2) > 0.02
    assert caustic.sum() > 20
    np.testing.assert_allclose(on.delta[caustic], off.delta[caustic], atol=2e-6)
    assert on.stats["photons_mixed_only"] < 0.01 * on.stats["photons_shared"]


def test_virtual_glass_caustic_lands_in_the_delta():
    """A virtual glass sphere over the real plane: its caustic appears in I_m − I_r on real
    pixels (positive), I_r gets nothing from it. Rejects adding caustics to both solutions."""
    scene = make(sphere_scene())
    on = render(scene, True, photons=50_000)
    off = render(scene, False)
    gain = (on.delta - off.delta)[on.mask == 0]
    assert gain.max() > 0.05 and gain.min() > -1e-6
    np.testing.assert_allclose(on.real, off.real, atol=1e-6)
    assert on.stats["photons_mixed_only"] == on.stats["photons_stored"]
    for k in ("time_photons", "time_photon_index", "time_trace"):
        assert on.stats[k] > 0


def test_virtual_glass_caustic_under_ppm():
    """Progressive maps of a virtual-glass-only caustic: every photon is mixed-only, so the
    real solution's maps are all empty. Rejects joining the maps with a bare ``dr.concat``
    (it fails on zero-width parts) and adding the caustic to I_r."""
    scene = make(sphere_scene(w=24, h=18))
    on = render(scene, True, photons=20_000, ppm_iterations=3)
    off = render(scene, False)
    assert on.stats["photons_mixed_only"] == on.stats["photons_stored"] > 0
    assert (on.delta - off.delta)[on.mask == 0].max() > 0.05
    np.testing.assert_allclose(on.real, off.real, atol=1e-6)


def test_virtual_blocker_removes_real_caustic_exactly():
    """A virtual opaque box between the light and a real glass sphere: the real-only photons
    retraced in µ rebuild the real caustic, so I_r's caustic equals the caustic of the world
    without the box (same photons, same order: to round-off), and the delta there is its
    negative. Rejects skipping the µ retrace (the blocked caustic would stay in the
    composite) and retracing with other random numbers."""
    c, lp, _ = focus_geometry()
    mid = (c + lp) / 2
    box = {"name": "blocker", "role": "virtual", "type": "box", "size": [0.3, 0.02, 0.3],
           "transform": {"translate": [float(x) for x in mid]},
           "material": {"type": "diffuse", "albedo": 0.5}}
    blocked = make(sphere_scene(glass_role="real", extra=[box]))
    alone = make(sphere_scene(glass_role="real"))
    kw = {"photons": 50_000}
    b_on, b_off = render(blocked, True, **kw), render(blocked, False)
    a_on, a_off = render(alone, True, **kw), render(alone, False)
    real_caustic = a_on.mixed - a_off.mixed
    assert real_caustic.max() > 0.05
    np.testing.assert_allclose(b_on.real - b_off.real, real_caustic, atol=1e-5)
    assert b_on.stats["photons_real_only"] > 0
    removed = (b_on.delta - b_off.delta)[b_on.mask == 0]
    assert removed.min() < -0.05


@pytest.mark.parametrize("key,value", [("photons", 0), ("photon_radius", -0.01),
                                       ("photon_radius", 0.0), ("ppm_iterations", 0),
                                       ("ppm_alpha", 1.0)])
def test_bad_photon_options_name_the_field(key, value):
    """Zero photons, a non-positive radius, no PPM iteration, α = 1 → InputError naming the
    option (the CLI turns it into exit 2)."""
    scene = make(sphere_scene())
    with pytest.raises(InputError, match=f"options.{key}"):
        render(scene, True, **{key: value})


def test_ppm_radius_sequence():
    """h_{i+1}² = h_i² (i + α)/(i + 1) exactly (Hachisuka 2008 / Knaus & Zwicker 2011)."""
    r = PhotonSettings(radius=0.02, ppm_iterations=4, ppm_alpha=0.5).radii()
    assert r[0] == 0.02
    for i in range(1, 4):
        assert r[i] ** 2 == pytest.approx(r[i - 1] ** 2 * (i + 0.5) / (i + 1), rel=1e-12)


def _bin_error(pm: PhotonMap, k: int, eref: np.ndarray, half: float, b: float) -> float:
    """Relative RMS difference of the K-map average kernel estimate, box-averaged over
    ``b``-wide bins (3 × 3 points per bin), to the reference bin irradiance."""
    _, _, focus = focus_geometry()
    acc = 0.0
    for i in range(k):
        acc = acc + irradiance_grid(pm, focus, half, b / 3, which=i)[0]
    n = eref.shape[0]
    est = (acc / k)[:3 * n, :3 * n].reshape(n, 3, n, 3).mean(axis=(1, 3))
    return float(np.sqrt(np.mean((est - eref) ** 2) / np.mean(eref ** 2)))


def test_progressive_photon_mapping_converges_to_the_reference():
    """PPM (radius h_{i+1}² = h_i² (i + α)/(i + 1), one map per iteration, averaged) gets
    closer to the exact caustic (2 mm bins of the NumPy Fresnel tracer's irradiance around
    the focus) as iterations are added, while a fixed radius with all those photons in one
    map does not (its error is the kernel's bias). Rejects a radius that does not shrink
    (PPM would equal the fixed-radius error), maps not averaged with equal weights, a
    shrinking radius without the photon-count growth behind it."""
    c, lp, focus = focus_geometry()
    pts, pw, _ = reference_hits(c, lp, 500)
    half, b = 0.012, 0.002
    edges_x = np.arange(focus[0] - half, focus[0] + half + 1e-9, b)
    edges_z = np.arange(focus[2] - half, focus[2] + half + 1e-9, b)
    eref = np.histogram2d(pts[:, 0], pts[:, 2], bins=[edges_x, edges_z], weights=pw)[0] / b ** 2
    world, views = _views(sphere_scene())
    errs = {}
    for k in (1, 4, 16):
        ps = PhotonSettings(photons=20_000, radius=0.006, ppm_iterations=k, ppm_alpha=0.5)
        maps, _ = build_photon_maps(world, views, ps)
        errs[k] = _bin_error(PhotonMap.build(maps, ps.radii()), k, eref, half, b)
    ps = PhotonSettings(photons=16 * 20_000, radius=0.006)
    maps, _ = build_photon_maps(world, views, ps)
    fixed = _bin_error(PhotonMap.build(maps, ps.radii()), 1, eref, half, b)
    assert errs[1] > errs[4] > errs[16]
    assert errs[16] < 0.8 * fixed, (errs, fixed)


def test_sphere_light_has_the_point_lights_intensity():
    """A `sphere` light (the ground truth's stand-in for a point light) lights a diffuse
    plane as the point light of the same intensity does: radiance I/(πr²) over its
    projected area πr² (Mitsuba's `path`, within 4 standard errors, plus the 1e-4 relative
    near-field difference). Rejects I/(4πr²) (a factor 4) and a one-sided emitter."""
    def plane(light: dict) -> dict:
        return {"camera": {"resolution": [8, 6], "fov_y_deg": 20,
                           "look_at": {"origin": [0.0, 1.0, 0.5], "target": [0.0, 0.0, 0.0]}},
                "shapes": [{"name": "floor", "role": "real", "type": "rectangle",
                            "size": [4, 4], "normal": [0, 1, 0],
                            "material": {"type": "diffuse", "albedo": 0.5}}],
                "lights": [light]}

    pos = [0.1, 0.8, 0.0]
    pt = make(plane({"type": "point", "position": pos, "intensity": 2.0}))
    sp = make(plane({"type": "sphere", "position": pos, "radius": 0.01, "intensity": 2.0}))
    ref = get_method("reference")
    a = ref(pt, RenderSettings(spp=4, max_depth=2))
    s = ref(sp, RenderSettings(spp=256, max_depth=2))
    diff = s.real.astype(np.float64) - a.real
    se = s.stderr["real"].astype(np.float64)
    assert np.all(np.abs(diff) <= 4 * se + 1e-3 * a.real)
    assert a.real.mean() > 0.1


@pytest.mark.parametrize("option,needle", [("photons=0", "options.photons"),
                                           ("photon_radius=-0.01", "options.photon_radius")])
def test_cli_bad_photon_option_exits_2(tmp_path, option, needle):
    """`arlight render` with zero photons or a negative radius: exit status 2 and one message
    naming the option, no traceback, no output written."""
    import json
    import shutil
    import subprocess
    import sys
    from pathlib import Path

    from arlight.io.images import write_png

    d = sphere_scene(w=16, h=12)
    d["frame"] = {"image": "frame.png"}
    (tmp_path / "scene.json").write_text(json.dumps(d))
    write_png(tmp_path / "frame.png", np.full((12, 16, 3), 90, np.uint8))
    exe = shutil.which("arlight", path=str(Path(sys.executable).parent))
    out = tmp_path / "out"
    r = subprocess.run([exe, "render", str(tmp_path / "scene.json"), "-m", "onepass",
                        "--option", "caustics=photons", "--option", option, "-o", str(out)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    assert needle in r.stderr and "Traceback" not in r.stderr
    assert not out.exists()


@pytest.mark.slow
def test_caustic_matches_small_sphere_light_ground_truth(tmp_path):
    """The photon caustic of a point light carries the energy of the caustic Mitsuba's
    `path` renders (:func:`arlight.synthetic.synthesize`, no code shared with the method)
    for a 2 cm sphere light of the same intensity: over the caustic's pixels (dilated by
    3 px, real pixels only, so the bulb's ~3 mm blur stays inside) within 3 standard errors
    (~8 % at 4096 spp; measured: 77.1 vs 71.5 ± 6.1 at 2 cm, 77.1 vs 77.5 ± 5.5 at 3 cm;
    a 2 mm bulb gave no hit at all, 1 cm a heavy-tailed ±15 %). Rejects a caustic off by a
    factor (kernel normalisation, flux, BSDF factor) or in the wrong place."""
    from scipy.ndimage import binary_dilation

    from arlight.synthetic import synthesize

    world = sphere_scene(w=64, h=48)
    world["lights"] = [{"type": "sphere", "position": world["lights"][0]["position"],
                        "radius": 0.02, "intensity": INTENSITY}]
    ph = synthesize(parse_scene(world), spp=4096, batches=16, cache_dir=tmp_path)
    proxy = parse_scene(sphere_scene(w=64, h=48)).with_frame(ph.frame)
    opts = {"caustics": "photons", "photons": 200_000, "photon_radius": 0.004,
            "reproject": False}
    on = get_method("onepass")(proxy, RenderSettings(spp=16, seed=1, options=opts))
    off = get_method("onepass")(proxy, RenderSettings(spp=16, seed=1,
                                                      options={"reproject": False}))
    gain = (on.composite - off.composite).mean(axis=2)
    region = binary_dilation(gain > 0.02 * gain.max(), iterations=3) & (on.mask == 0)
    est = float((on.composite - off.composite)[region].sum())
    ref = float((ph.ground_truth - off.composite)[region].sum())
    se = float(np.sqrt((np.square(ph.ground_truth_stderr) + np.square(off.stderr["composite"])
                        + np.square(on.stderr["composite"]))[region].sum()))
    assert est > 5 * se  # the caustic is resolved
    assert abs(est - ref) < 3 * se, (est, ref, se)


def test_spot_light_photons_follow_its_beam():
    """A spot light aimed at the sphere with a beam wider than the sphere's cone shoots the
    power I·Ω into it; aimed away (the sphere outside its cut-off) it stores no photon.
    Rejects treating spots as point lights (their direction and fall-off ignored)."""
    c, lp, _ = focus_geometry()
    omega = 2 * math.pi * (1 - math.sqrt(1 - (R / DIST) ** 2))
    for target, expect in ((c, INTENSITY * omega), (2 * lp - c, 0.0)):
        d = sphere_scene()
        d["lights"] = [{"type": "spot", "position": [float(x) for x in lp],
                        "target": [float(x) for x in target], "intensity": INTENSITY,
                        "cutoff_deg": 20.0, "beam_width_deg": 15.0}]
        world, views = _views(d)
        em = emit_photons(world, views, 20_000, seed=2)
        np.testing.assert_allclose(em.power, expect, rtol=1e-4, atol=1e-9)
        assert (trace_photons(views, em, 8, seed=2).count > 0) == (expect > 0)


def test_caustic_renders_are_deterministic():
    """Equal seeds give bitwise equal renders with caustics (stable sort, fixed photon
    order, hashed random numbers); another seed gives other photons."""
    scene = make(sphere_scene())
    a = render(scene, True, photons=30_000)
    b = render(scene, True, photons=30_000)
    np.testing.assert_array_equal(a.composite, b.composite)
    c = get_method("onepass")(scene, RenderSettings(spp=4, seed=1, options={
        "caustics": "photons", "photons": 30_000}))
    assert not np.array_equal(a.composite, c.composite)


def test_real_caustic_seen_in_a_virtual_mirror_is_not_added_twice():
    """A virtual mirror shows the table where a real glass sphere focuses its caustic. With
    camera-image reprojection (Kán §5.2) those pixels take the frame, which already holds
    the real caustic, so the photon estimate adds only Σ_m − Σ_r there (≈ 0: the mirror
    barely touches the photons); without reprojection the proxy is shaded and the caustic
    is added. Rejects adding Σ_m at reprojected points (the caustic counted twice)."""
    c, lp, focus = focus_geometry()
    cam, m = np.array([0.35, 0.55, 0.55]), np.array([-0.05, 0.15, -0.25])
    n = (cam - m) / np.linalg.norm(cam - m) + (focus - m) / np.linalg.norm(focus - m)
    mirror = {"name": "mirror", "role": "virtual", "type": "rectangle", "size": [0.2, 0.2],
              "normal": [float(x) for x in n / np.linalg.norm(n)],
              "transform": {"translate": [float(x) for x in m]},
              "material": {"type": "mirror", "reflectance": 0.9}}
    scene = make(sphere_scene(glass_role="real", extra=[mirror]))
    gains = {}
    for rp in (True, False):
        on = render(scene, True, photons=100_000, photon_radius=0.004, reproject=rp)
        off = get_method("onepass")(scene, RenderSettings(spp=4, options={"reproject": rp}))
        in_mirror = on.mask > 0.99
        gains[rp] = float((on.mixed - off.mixed)[in_mirror].sum())
    assert gains[False] > 1.0
    assert abs(gains[True]) < 0.02 * gains[False]
