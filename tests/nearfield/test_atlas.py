"""Checklist items 2 (atlas geometry) and 4 (dilation)."""

from __future__ import annotations

import numpy as np

from arlight.nearfield.atlas import dilate, layout_charts, proxy_mesh, rasterize
from tests.nearfield.conftest import room, world


def _atlas(res=96, extra=None):
    m = proxy_mesh(world(room(extra=extra)))
    lay = layout_charts(m, res)
    return m, lay, rasterize(m, lay, 4)


def test_area_sums_to_mesh_area_and_positions_lie_on_the_mesh():
    box = [{"name": "crate", "role": "real", "type": "box", "size": [0.3, 0.2, 0.5],
            "transform": {"rotate": [0, 1, 0, 30], "translate": [0.3, 0.1, -0.4]},
            "material": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}}]
    m, lay, g = _atlas(extra=box)
    assert lay.charts == 5 + 6
    assert abs(g.area.sum() / m.face_areas.sum() - 1) < 0.01
    # every texel centroid lies in the plane of its face and inside the face's bounds
    cov = g.covered
    f = g.face[cov]
    p = g.position[cov]
    n = m.face_normals[f]
    v0 = m.vertices[m.faces[f, 0]]
    assert np.max(np.abs(np.einsum("ni,ni->n", p - v0, n))) < 1e-5
    lo = m.vertices[m.faces[f]].min(1) - 1e-5
    hi = m.vertices[m.faces[f]].max(1) + 1e-5
    assert np.all((p >= lo) & (p <= hi))
    # normals are the faces' normals; the texel map of a face sends its centroid to its texel
    assert np.allclose(g.normal[cov], n)
    ac = lay.texel_of(f, p)
    rows, cols = np.nonzero(cov)
    assert np.all(np.floor(ac[:, 0]) == cols) and np.all(np.floor(ac[:, 1]) == rows)


def test_interior_texels_have_the_full_texel_area():
    m, lay, g = _atlas()
    full = np.isclose(g.area, lay.texel_size**2)
    assert full.sum() > 0.8 * g.covered.sum()
    assert np.all(g.area <= lay.texel_size**2 * (1 + 1e-9))


def test_dilation_fills_two_rings_and_keeps_interior():
    valid = np.zeros((12, 12), bool)
    valid[4:8, 4:8] = True
    vals = np.zeros((12, 12, 3))
    vals[valid] = np.arange(48, dtype=float).reshape(16, 3)
    out = dilate(vals, valid, 2)
    assert np.array_equal(out[valid], vals[valid])  # interior unchanged
    ring2 = np.zeros_like(valid)
    ring2[2:10, 2:10] = True
    assert np.all(np.any(out[ring2 & ~valid] != 0, axis=-1))  # filled within 2 texels
    assert np.all(out[~ring2] == 0)  # nothing beyond
    # a filled neighbour is the mean of the valid 8-neighbours: texel (3, 4) sees (4,4), (4,5)
    assert np.allclose(out[3, 4], (vals[4, 4] + vals[4, 5]) / 2)
