"""Voxelisation, mip chains and cone tracing (:mod:`arlight.realtime.voxels`, Franke §5.4).

Each test names the wrong implementation it rejects."""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from arlight.jit import ensure_variant
from arlight.realtime.sh_volume import Grid
from arlight.realtime.voxels import (
    ConeVolumes,
    Voxels,
    build_mips,
    eta_level0,
    pack,
    shape_triangles,
    trace_cones,
    voxelize,
)
from arlight.scene.load import parse_scene

ensure_variant()


def _points_on(tri: np.ndarray, count: int, seed: int = 0) -> np.ndarray:
    r = np.random.default_rng(seed).random((count, 2))
    flip = r.sum(1) > 1
    r[flip] = 1 - r[flip]
    return tri[0] + r[:, :1] * (tri[1] - tri[0]) + r[:, 1:] * (tri[2] - tri[0])


def _point_triangle_distance(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Distance of points to a triangle by dense sampling of the triangle (an upper bound,
    fine enough for a tolerance of half a cell)."""
    s = _points_on(tri, 20000, seed=1)
    return np.array([np.min(np.linalg.norm(s - q, axis=1)) for q in p])


def test_voxelisation_is_conservative_and_tight():
    """Every point of a thin, tilted triangle lies in an occupied cell (conservative: no hole
    where a sample-based or centre-based voxeliser leaves one), and every occupied cell
    touches the triangle (its centre within √3/2 cells of it: rejects marking the whole
    bounding box)."""
    g = Grid(np.zeros(3), 1.0 / 32, 32)
    tri = np.array([[0.11, 0.13, 0.09], [0.87, 0.79, 0.21], [0.31, 0.22, 0.93]])
    vx = voxelize(tri[None], g)
    pts = _points_on(tri, 100000)
    cells = np.floor(pts * 32).astype(int)
    flat = cells[:, 0] + 32 * (cells[:, 1] + 32 * cells[:, 2])
    assert vx.alpha[flat].min() == 1.0
    idx = vx.index
    centres = (np.stack([idx % 32, (idx // 32) % 32, idx // 1024], 1) + 0.5) / 32
    d = _point_triangle_distance(centres, tri)
    assert d.max() <= (math.sqrt(3) / 2 + 0.05) / 32
    lo, hi = np.floor(tri.min(0) * 32), np.floor(tri.max(0) * 32)
    assert vx.occupied < 0.5 * np.prod(hi - lo + 1)  # far fewer than the bounding box
    n = vx.unit_normals()
    expect = np.cross(tri[1] - tri[0], tri[2] - tri[0])
    assert np.allclose(n, expect / np.linalg.norm(expect), atol=1e-9)


def test_shape_triangles_have_the_shape_area_and_pose():
    """Primitive tessellations in their world pose: a 2×1 rectangle has area 2 and lies in
    its plane; a box of edge 0.4 has area 0.96; a sphere of radius 0.5 is close to 4πr²
    (rejects the unit canonical frame left unscaled, or the transform not applied)."""
    d = {"camera": {"resolution": [4, 4], "fov_y_deg": 45,
                    "look_at": {"origin": [0, 0, 3], "target": [0, 0, 0]}},
         "shapes": [
             {"name": "r", "role": "real", "type": "rectangle", "size": [2, 1],
              "normal": [0, 1, 0], "transform": {"translate": [0, 0.25, 0]},
              "material": {"type": "diffuse", "albedo": 0.5}},
             {"name": "b", "role": "real", "type": "box", "size": [0.4] * 3,
              "material": {"type": "diffuse", "albedo": 0.5}},
             {"name": "s", "role": "virtual", "type": "sphere", "radius": 0.5,
              "transform": {"translate": [1, 2, 3]},
              "material": {"type": "diffuse", "albedo": 0.5}}],
         "lights": [{"type": "constant", "radiance": 1.0}]}
    shapes = parse_scene(d).world.shapes

    def area(t):
        return 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1).sum()

    rect, box, sph = (shape_triangles(s) for s in shapes)
    assert area(rect) == pytest.approx(2.0) and np.allclose(rect[..., 1], 0.25)
    assert area(box) == pytest.approx(6 * 0.16)
    assert area(sph) == pytest.approx(math.pi, rel=0.02)
    assert np.allclose(sph.reshape(-1, 3).mean(0), [1, 2, 3], atol=0.02)


def test_mip_levels_are_box_filters_of_the_level_below():
    """Each level equals the 2×2×2 mean of the one below (NumPy reshape-mean peer), with
    cells laid out x fastest; rejects swapped axes, off-by-one children or a sum instead of
    a mean."""
    g = Grid(np.zeros(3), 0.1, 8)
    rng = np.random.default_rng(0)
    a = rng.random((8, 8, 8, 3)).astype(np.float32)  # [z, y, x, c]
    vol = build_mips(pack(a.reshape(-1, 3)), g, 3)
    assert vol.levels == 4
    cur = a.astype(np.float64)
    for lvl in range(1, 4):
        m = cur.shape[0] // 2
        cur = cur.reshape(m, 2, m, 2, m, 2, 3).mean(axis=(1, 3, 5))
        assert np.allclose(vol.level(lvl), cur, atol=1e-6)


def _slab_volumes(n: int = 8, layers: dict[int, tuple[float, float]] | None = None,
                  real: set[int] = frozenset()) -> tuple[ConeVolumes, Grid]:
    """Volumes with whole x-layers of occupancy α and intensity I (``layers[x] = (α, I)``);
    layers in ``real`` count as real geometry too; normals zero (isotropic cells)."""
    g = Grid(np.zeros(3), 1.0, n)
    alpha = np.zeros((n, n, n, 2), np.float32)
    light = np.zeros((n, n, n, 3), np.float32)
    for x, (a, i) in (layers or {}).items():
        alpha[:, :, x, 0] = a
        if x in real:
            alpha[:, :, x, 1] = a
        light[:, :, x, :] = i
    vols = ConeVolumes(build_mips(pack(alpha.reshape(-1, 2)), g, 2),
                       build_mips(pack(np.zeros((n ** 3, 3))), g, 3),
                       build_mips(pack(light.reshape(-1, 3)), g, 3))
    return vols, g


def test_front_to_back_accumulation_is_the_standard_form():
    """Two half-transparent layers: a ray (aperture 0) through their cell centres gathers
    ``c = c1 + (1 − α1) c2`` and ``α = α1 + (1 − α1) α2`` (the standard [CNS+11] form). The
    printed Eq. 5.18 ``c = α0 c0 + (1 − α0) α_v c_v`` would fade the first layer (c = 0.5·…)
    and is rejected."""
    vols, g = _slab_volumes(layers={3: (0.5, 1.0), 5: (0.5, 2.0)})
    o = mi.Point3f(0.5, 4.5, 4.5)
    r = trace_cones(vols, o, mi.Vector3f(1, 0, 0), 0.0, dr.inf, mi.Bool(True))
    assert float(r.a_all[0]) == pytest.approx(0.75, abs=1e-6)
    assert float(r.a_real[0]) == pytest.approx(0.0, abs=1e-6)
    # premultiplied radiance of a layer: I / s² = 1 and 2 (α is coverage, already in c_l)
    assert float(r.radiance.x[0]) == pytest.approx(1.0 + 0.5 * 2.0, abs=1e-5)


def test_added_occlusion_counts_only_virtual_geometry():
    """A half-covering real layer (the receiving surface seen by a cone's own samples, or a
    real occluder) adds nothing: ``1 − keep = 0`` although ``a_all = a_real = 0.5``; an
    opaque virtual layer adds 1 — also behind the real layer, whose own shadow is the
    caller's question. Rejects an added occlusion taken from ``a_all`` alone, and the
    difference ``a_all − a_real``, which a saturated real layer drives to 0."""
    o, d = mi.Point3f(0.5, 4.5, 4.5), mi.Vector3f(1, 0, 0)
    vols, _ = _slab_volumes(layers={3: (0.5, 0.0)}, real={3})
    r = trace_cones(ConeVolumes(vols.alpha), o, d, 0.0, dr.inf, mi.Bool(True))
    assert float(r.a_all[0]) == pytest.approx(0.5, abs=1e-6)
    assert float(r.added[0]) == pytest.approx(0.0, abs=1e-6)
    vols, _ = _slab_volumes(layers={3: (1.0, 0.0), 5: (1.0, 0.0)}, real={3})
    r = trace_cones(ConeVolumes(vols.alpha), o, d, 0.0, dr.inf, mi.Bool(True))
    assert float(r.a_all[0] - r.a_real[0]) == pytest.approx(0.0, abs=1e-6)
    assert float(r.added[0]) == pytest.approx(1.0, abs=1e-3)
    # the cone stops at t_max: a light in front of the layer sees no occluder
    r = trace_cones(ConeVolumes(vols.alpha), o, d, 0.0, 3.0, mi.Bool(True))
    assert float(r.added[0]) == 0.0


def test_wide_cones_see_a_surface_with_its_radiance_at_every_level():
    """A cone of 60° aperture towards a lit plane 24 cells away arrives at a coarse level and
    still gathers most of the plane's radiance ``I/s²`` (the ``2^l`` scaling of a block's
    radiance); its coverage is ``shells`` times that of one sheet (≈ 1 with ``shells = 1``,
    half with 0.5). Rejects raw mip means, which fade a thin surface by ``2^−l`` (c ≈ 0.2 I
    here), and a coverage that ignores the ``shells`` argument."""
    vols, _ = _slab_volumes(n=32, layers={28: (1.0, 3.0)})
    o = mi.Point3f(4.0, 16.0, 16.0)
    alpha = {}
    for shells in (0.5, 1.0):
        r = trace_cones(vols, o, mi.Vector3f(1, 0, 0), math.tan(math.radians(30)), dr.inf,
                        mi.Bool(True), shells=shells)
        alpha[shells] = float(r.a_all[0])
        assert 0.7 * 3.0 < float(r.radiance.x[0]) < 1.5 * 3.0
    assert alpha[1.0] > 0.65
    assert 0.4 < alpha[0.5] / alpha[1.0] < 0.6


@pytest.mark.parametrize("aperture", [20.0, 60.0])
def test_cone_gather_of_a_lit_plane_is_its_radiance_at_every_distance(aperture):
    """One cone towards an opaque plane of radiance ``L = I/s²`` (an x-layer of a 64³
    volume), from 26 distances of 4–24 cells in steps of 0.8 cells (every phase against
    the cells and levels): a cone whose whole cross-section meets the plane gathers ``L``
    (the analytic integral of a uniform radiance over the cone's solid angle, normalised
    by it); measured 0.83–1.0. Rejects the step of one cone diameter at a level one finer
    than the diameter's (issue #33: 0.4–1.07 by phase, samples that skip the plane), and a
    step of one finest cell at coarse levels (the plane counted several times: > 1.3)."""
    vols, _ = _slab_volumes(n=64, layers={48: (1.0, 1.0)})
    got = []
    for d in np.arange(4.0, 24.5, 0.8):
        o = mi.Point3f(48.5 - float(d), 32.0, 32.0)
        r = trace_cones(vols, o, mi.Vector3f(1, 0, 0), math.tan(math.radians(aperture / 2)),
                        dr.inf, mi.Bool(True), shells=1.0)
        got.append(float(r.radiance.x[0]))
    got = np.array(got)
    assert np.all((got > 0.8) & (got < 1.1)), got.round(2)


def test_eta_level0_keeps_real_and_all_occupancy():
    """``V_η`` level 0: α_all is the union of real and virtual cells, α_real the real ones,
    normals unit (rejects overwriting the real occupancy with the virtual one)."""
    g = Grid(np.zeros(3), 1.0, 4)
    real = Voxels.from_hits(g, np.array([0, 1, 1]), np.array([[0, 1, 0], [0, 2, 0],
                                                              [0, 1, 0.0]]))
    virt = Voxels.from_hits(g, np.array([1, 5]), np.array([[1, 0, 0], [0, 0, 3.0]]))
    alpha, normal = eta_level0(real, virt)
    a = np.array(alpha).reshape(-1, 2)
    assert a[[0, 1, 5], 0].tolist() == [1, 1, 1] and a[[0, 1, 5], 1].tolist() == [1, 1, 0]
    assert a[:, 0].sum() == 3 and a[:, 1].sum() == 2
    nv = np.array(normal).reshape(-1, 3)
    assert np.allclose(np.linalg.norm(nv[[0, 1, 5]], axis=1), 1.0)
    assert np.allclose(nv[1], np.array([1, 3, 0]) / math.sqrt(10))


def test_back_faces_dim_a_surface_seen_from_behind():
    """With V_η normals (``back_faces``), a lit layer whose normal points away from the cone
    shows no radiance, facing the cone it shows ``I/s²``; without normals it is isotropic.
    Rejects the sign of the back-face test inverted."""
    n = 8
    g = Grid(np.zeros(3), 1.0, n)
    alpha = np.zeros((n, n, n, 2), np.float32)
    light = np.zeros((n, n, n, 3), np.float32)
    alpha[:, :, 4, 0] = 1.0
    light[:, :, 4, :] = 2.0
    o, d = mi.Point3f(0.5, 4.5, 4.5), mi.Vector3f(1, 0, 0)
    for nx, expect in ((1.0, 0.0), (-1.0, 2.0)):
        nrm = np.zeros((n, n, n, 3), np.float32)
        nrm[:, :, 4, 0] = nx
        vols = ConeVolumes(build_mips(pack(alpha.reshape(-1, 2)), g, 2),
                           build_mips(pack(nrm.reshape(-1, 3)), g, 3),
                           build_mips(pack(light.reshape(-1, 3)), g, 3))
        r = trace_cones(vols, o, d, 0.0, dr.inf, mi.Bool(True))
        assert float(r.radiance.x[0]) == pytest.approx(expect, abs=1e-5)
        iso = trace_cones(ConeVolumes(vols.alpha, None, vols.light), o, d, 0.0, dr.inf,
                          mi.Bool(True))
        assert float(iso.radiance.x[0]) == pytest.approx(2.0, abs=1e-5)


def _aniso_layer(n: int, normal: np.ndarray, intensity: float) -> tuple[ConeVolumes, Grid]:
    """An opaque x-layer at x = 4 of Lambertian emitters of peak intensity ``I`` and unit
    ``normal``, binned as dvct's injection does (slot ``2a + (n_a < 0)`` gets
    ``I |n_a|``), written here in NumPy."""
    g = Grid(np.zeros(3), 1.0, n)
    alpha = np.zeros((n, n, n, 2), np.float32)
    alpha[:, :, 4, 0] = 1.0
    light = np.zeros((n, n, n, 6, 3), np.float32)
    for a in range(3):
        light[:, :, 4, 2 * a + int(normal[a] < 0), :] += intensity * abs(normal[a])
    return ConeVolumes(build_mips(pack(alpha.reshape(-1, 2)), g, 2), None,
                       build_mips(pack(light.reshape(-1, 18)), g, 18)), g


@pytest.mark.parametrize("normal", [(-1.0, 0.0, 0.0), (-0.6, 0.8, 0.0), (-0.6, -0.48, 0.64)])
def test_anisotropic_cells_show_the_lambertian_intensity_towards_the_cone(normal):
    """An anisotropic radiance volume (6 directions × RGB, issue #33): a ray (aperture 0)
    along ``d`` starting at the centre of an opaque lit cell gathers
    ``Σ_a |ω_a| c_slot(a)`` with ``ω = −d``, which for ``ω`` whose components share the
    normal's signs is ``I <n, ω>``; from behind (every
    ``ω_a n_a ≤ 0``) it gathers 0. Rejects the slot of the travel direction instead of the
    direction towards the viewer (front and back swapped) and weights ``ω_a²``
    (``I Σ ω_a² |n_a|``)."""
    nrm = np.array(normal)
    vols, _ = _aniso_layer(8, nrm, 2.0)
    for d, expect in (([1.0, 0.0, 0.0], 2.0 * -nrm[0]),
                      ([0.6, -0.8, 0.0], 2.0 * (max(0.0, -0.6 * nrm[0]) + max(0.0, 0.8 * nrm[1]))),
                      ([-1.0, 0.0, 0.0], 0.0)):
        o = mi.Point3f(4.5, 4.5, 4.5)
        r = trace_cones(vols, o, mi.Vector3f(*d), 0.0, dr.inf, mi.Bool(True))
        assert float(r.radiance.x[0]) == pytest.approx(expect, abs=1e-5), (d, normal)


def test_anisotropic_mips_box_filter_every_slot():
    """The mip chain of an 18-channel volume is the 2×2×2 mean of each channel separately
    (NumPy peer). Rejects a 3-channel packet gather that strides over whole cells (slots of
    neighbouring cells mixed)."""
    n = 8
    g = Grid(np.zeros(3), 1.0, n)
    x = np.random.default_rng(3).random((n, n, n, 18)).astype(np.float32)
    mv = build_mips(pack(x.reshape(-1, 18)), g, 18)
    peer = x.reshape(n // 2, 2, n // 2, 2, n // 2, 2, 18).mean(axis=(1, 3, 5))
    np.testing.assert_allclose(mv.level(1), peer, rtol=1e-5, atol=1e-6)


def test_occluded_bounce_subtracts_what_the_virtual_objects_hide():
    """``ConeVolumes.occluded`` (issue #33, dvct's ``occluded_bounce``): a ray through a
    half-covering virtual layer (α 0.5, not real) towards a real lit layer of first-bounce
    radiance ρ = 3 (V_Δ there 0) gathers ``Δ − (1 − k) ρ = −1.5`` — the bounce the virtual
    layer hides; without the occluded volume 0. Rejects subtracting ``(1 − a_all) ρ`` (the
    light that gets through) and the sign flipped."""
    n = 8
    g = Grid(np.zeros(3), 1.0, n)
    alpha = np.zeros((n, n, n, 2), np.float32)
    alpha[:, :, 3, 0] = 0.5
    alpha[:, :, 5, :] = 1.0
    rho = np.zeros((n, n, n, 3), np.float32)
    rho[:, :, 5, :] = 3.0
    av = build_mips(pack(alpha.reshape(-1, 2)), g, 2)
    zero = build_mips(pack(np.zeros((n ** 3, 3))), g, 3)
    rv = build_mips(pack(rho.reshape(-1, 3)), g, 3)
    o, d = mi.Point3f(0.5, 4.5, 4.5), mi.Vector3f(1, 0, 0)
    r = trace_cones(ConeVolumes(av, None, zero, rv), o, d, 0.0, dr.inf, mi.Bool(True),
                    alpha_for_light=2)
    assert float(r.radiance.x[0]) == pytest.approx(-1.5, abs=1e-5)
    r = trace_cones(ConeVolumes(av, None, zero), o, d, 0.0, dr.inf, mi.Bool(True),
                    alpha_for_light=2)
    assert float(r.radiance.x[0]) == pytest.approx(0.0, abs=1e-6)
    with pytest.raises(ValueError, match="alpha_for_light 2"):
        trace_cones(ConeVolumes(av, None, zero, rv), o, d, 0.0, dr.inf, mi.Bool(True))


def test_cover_is_the_largest_normal_component_per_axis():
    """``Voxels.cover`` of a tilted plane (unit normal (0, 0.6, 0.8), two triangles) is
    (0, 0.6, 0.8) in every cell, also where both triangles touch the cell; a union keeps
    the larger per axis. Rejects summing the triangles' components (1.2, 1.6 → clipped to
    1 in the cells along the shared diagonal)."""
    g = Grid(np.zeros(3), 1.0, 16)
    n = np.array([0.0, 0.6, 0.8])
    u = np.array([1.0, 0.0, 0.0])
    v = np.cross(n, u)
    c = np.array([8.0, 8.0, 8.0])
    q = [c + 6 * (a * u + b * v) for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    vox = voxelize(np.array([[q[0], q[1], q[2]], [q[0], q[2], q[3]]]), g, with_cover=True)
    assert vox.occupied > 100
    np.testing.assert_allclose(vox.cover, np.broadcast_to(n, vox.cover.shape), atol=1e-6)
    other = Voxels.from_hits(g, vox.index[:1], np.array([[1.0, 0.0, 0.0]]), with_cover=True)
    both = vox.union(other)
    first = np.searchsorted(both.index, vox.index[0])
    np.testing.assert_allclose(both.cover[first], [1.0, 0.6, 0.8], atol=1e-6)


def test_directional_occupancy_is_the_projected_cover():
    """A radiance cone given ``ConeVolumes.cover`` sees a cell's occupancy along its
    direction, ``Σ_a |d_a| cover_a``: one sample at the centre of an x-sheet cell
    (cover (1, 0, 0)) along (0.8, 0.6, 0) gives α 0.8 and premultiplied radiance
    ``I · |d_x|`` from the anisotropic light; isotropic α gives 1. Rejects the cover ignored
    and ``Σ_a d_a² cover_a`` (0.64)."""
    vols, g = _aniso_layer(8, np.array([-1.0, 0.0, 0.0]), 2.0)
    cov = np.zeros((8, 8, 8, 6), np.float32)
    cov[:, :, 4, 0] = 1.0
    cov[:, :, 4, 3] = 1.0
    cv = ConeVolumes(vols.alpha, None, vols.light, None,
                     build_mips(pack(cov.reshape(-1, 6)), g, 6))
    o, d = mi.Point3f(4.5, 4.5, 4.5), mi.Vector3f(0.8, 0.6, 0.0)
    r = trace_cones(cv, o, d, 0.0, 0.5, mi.Bool(True))
    assert float(r.a_all[0]) == pytest.approx(0.8, abs=1e-6)
    assert float(r.a_real[0]) == pytest.approx(0.8, abs=1e-6)
    assert float(r.radiance.x[0]) == pytest.approx(2.0 * 0.8, abs=1e-5)
    iso = trace_cones(ConeVolumes(vols.alpha, None, vols.light), o, d, 0.0, 0.5, mi.Bool(True))
    assert float(iso.a_all[0]) == pytest.approx(1.0, abs=1e-6)


def test_a_lane_without_direction_gathers_nothing():
    """A lane whose direction is zero (a G-buffer sample of no surface: zero normal) is
    inactive: no occlusion, no radiance. Rejects marching it in place — it accumulated the
    occupancy of its start cell, and with directional occupancy (zero for a zero direction)
    it never stopped (the box exit is 10¹² away)."""
    vols, g = _aniso_layer(8, np.array([-1.0, 0.0, 0.0]), 2.0)
    r = trace_cones(ConeVolumes(vols.alpha, None, vols.light), mi.Point3f(4.5, 4.5, 4.5),
                    mi.Vector3f(*(mi.Float(np.zeros(1, np.float32)) for _ in range(3))), 0.5,
                    dr.inf, mi.Bool(True))
    assert float(r.a_all[0]) == 0.0 and float(r.radiance.x[0]) == 0.0
