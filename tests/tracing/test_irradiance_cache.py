"""The irradiance cache's NumPy parts: Tabellion's weight (Eq. 2.15), splatting (Eq. 4.11),
tile miss detection (Kán §4.2.4), invalidation.

Wrong implementations rejected: Ward's weight or a weight without κ, a footprint box that
misses pixels with w > 0, unnormalised interpolation, more than one record per tile per
iteration, a scan that restarts at the tile's first pixel, a miss loop that never covers the
image, splats whose sums depend on how records were batched.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from arlight.scene.camera import Camera, look_at
from arlight.tracing.irradiance_cache import (
    NORMAL_SCALE,
    Records,
    SplatGeometry,
    TileScanner,
    invalidate_near,
    splat,
    tabellion_weight,
)


def test_weight_is_tabellions_equation():
    x = np.array([[0.1, 0.0, 0.0]])
    n = np.array([[0.0, 1.0, 0.0]])
    xi = np.zeros((1, 3))
    # distance term: 0.1 / (0.5 / 2) = 0.4; normals equal
    assert tabellion_weight(x, n, xi, n, np.array([0.5]), 1.0)[0] == pytest.approx(0.6)
    assert tabellion_weight(x, n, xi, n, np.array([0.5]), 2.0)[0] == pytest.approx(0.2)
    # normals 10° apart reach the limit: w = 1 − κ
    a = math.radians(10.0)
    ni = np.array([[math.sin(a), math.cos(a), 0.0]])
    assert tabellion_weight(xi, n, xi, ni, np.array([1.0]), 0.5)[0] == pytest.approx(0.5)
    assert NORMAL_SCALE == pytest.approx(1 / math.sqrt(1 - math.cos(a)))


def plane_geometry(w: int = 40, h: int = 30):
    """A camera looking straight down at the plane y = 0 (every pixel hits it)."""
    cam = Camera.from_fov(w, h, 60.0, world_from_camera=look_at([0, 2, 0], [0, 0, 0],
                                                                 up=(0, 0, -1)))
    v, u = np.mgrid[0:h, 0:w]
    o, d = cam.pixel_rays(np.stack([u.ravel() + 0.5, v.ravel() + 0.5], axis=1))
    t = -o[:, 1] / d[:, 1]
    pos = o + d * t[:, None]
    nrm = np.tile([0.0, 1.0, 0.0], (w * h, 1))
    ones = np.ones(w * h, bool)
    geom = SplatGeometry(pos, nrm, ones, ones, np.zeros(w * h, bool), w, h,
                         np.full((w * h, 3), 0.5))
    return cam, geom


def records_at(geom, pix, e_m, radius=0.4):
    n = len(pix)
    return Records(geom.position[pix], geom.normal[pix], np.asarray(e_m, float),
                   -0.5 * np.asarray(e_m, float), np.full(n, radius), np.zeros(n, np.int64),
                   np.arange(n, dtype=np.uint32), np.arange(n, dtype=np.int64))


def test_splat_matches_brute_force_weights_and_interpolates():
    cam, geom = plane_geometry()
    pix = np.array([5 * 40 + 7, 15 * 40 + 20, 22 * 40 + 31])
    e = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [0.5, 0.5, 0.5]])
    recs = records_at(geom, pix, e)
    buf = splat(recs, geom, cam, kappa=1.0, min_px=0.5, max_px=1000.0)
    # brute force over every (pixel, record) pair
    w = np.stack([tabellion_weight(geom.position, geom.normal,
                                   np.broadcast_to(recs.position[i], geom.position.shape),
                                   np.broadcast_to(recs.normal[i], geom.position.shape),
                                   np.full(len(geom.position), 0.4), 1.0)
                  for i in range(3)], axis=1)
    w = np.maximum(w, 0.0)
    np.testing.assert_allclose(buf.weight, w.sum(axis=1), rtol=1e-12, atol=1e-12)
    e_m, e_d = buf.irradiance()
    covered = w.sum(axis=1) > 0
    np.testing.assert_allclose(e_m[covered], (w @ e)[covered] / w.sum(axis=1)[covered, None])
    np.testing.assert_allclose(e_d, -0.5 * e_m)
    assert np.all(e_m[~covered] == 0)
    assert buf.weight[pix].min() > 0.999  # a record's own pixel has weight 1


def test_splat_is_batch_independent_and_clamps_the_footprint():
    cam, geom = plane_geometry()
    rng = np.random.default_rng(1)
    pix = rng.choice(40 * 30, 25, replace=False)
    recs = records_at(geom, pix, rng.random((25, 3)), radius=0.3)
    whole = splat(recs, geom, cam, 1.0, 0.5, 1000.0)
    again = splat(recs, geom, cam, 1.0, 0.5, 1000.0)
    assert np.array_equal(whole.weight, again.weight)
    parts = splat(recs.take(np.arange(10)), geom, cam, 1.0, 0.5, 1000.0).add(
        splat(recs.take(np.arange(10, 25)), geom, cam, 1.0, 0.5, 1000.0))
    np.testing.assert_allclose(parts.w_mixed, whole.w_mixed, rtol=1e-12)
    # a huge R_i is clamped to max_px pixels: nothing beyond that radius gets weight
    big = records_at(geom, np.array([15 * 40 + 20]), [[1.0, 1.0, 1.0]], radius=1e6)
    buf = splat(big, geom, cam, 1.0, 0.5, 3.0)
    rows, cols = np.divmod(np.flatnonzero(buf.weight > 0), 40)
    assert np.max(np.abs(cols + 0.5 - 20.5)) <= 3 and np.max(np.abs(rows + 0.5 - 15.5)) <= 3


def test_tiles_give_one_record_each_and_resume_where_they_stopped():
    sc = TileScanner(8, 6, 4)  # 2 × 2 tiles, the lower ones cut to 2 rows
    weight = np.zeros(48)
    needs = np.ones(48, bool)
    first = sc.misses(weight, needs)
    assert sorted(first.tolist()) == [0, 4, 32, 36]  # each tile's first pixel
    weight[first] = 1.0
    weight[1] = 1.0  # pixel 1 covered by a neighbour: the scan moves past it
    second = sc.misses(weight, needs)
    assert 2 in second and 5 in second and len(second) == 4
    # a pixel before a tile's cursor is not scanned again
    weight[:] = 1.0
    weight[0] = 0.0
    assert 0 not in sc.misses(weight, needs)
    # pixels that need no irradiance are never misses
    sc2 = TileScanner(8, 6, 4)
    assert len(sc2.misses(np.zeros(48), np.zeros(48, bool))) == 0


def test_miss_loop_covers_every_pixel_that_needs_irradiance():
    cam, geom = plane_geometry(32, 24)
    geom.needs[::7] = False
    sc = TileScanner(32, 24, 8)
    recs = Records.empty()
    buf = splat(recs, geom, cam, 2.0, 0.5, 6.0)
    for _ in range(500):
        pix = sc.misses(buf.weight, geom.needs)
        if len(pix) == 0:
            break
        assert len(pix) <= sc.tiles
        new = records_at(geom, pix, np.ones((len(pix), 3)), radius=1.2)  # ~3 px
        buf = buf.add(splat(new, geom, cam, 2.0, 0.5, 6.0))
        recs = recs.concat(new)
    assert np.all(buf.weight[geom.needs] > 0)
    assert len(recs) < geom.needs.sum() / 3  # interpolation: far fewer records than pixels


def test_invalidate_near_boxes():
    recs = records_at(plane_geometry()[1], np.arange(0, 1200, 100), np.ones((12, 3)))
    lo, hi = np.array([-0.2, -1, -0.2]), np.array([0.2, 1, 0.2])
    near = invalidate_near(recs, [(lo, hi)], 0.1)
    d = np.linalg.norm(np.maximum(np.maximum(lo - recs.position, recs.position - hi), 0),
                       axis=1)
    assert np.array_equal(near, d <= 0.1)
    assert not invalidate_near(recs, [], 0.1).any()
