"""Several lights' RSM pairs from one cast into the mixed view (issue #32,
:func:`arlight.realtime.rsm.render_rsm_pairs_reusing`): bit for bit each light's pair cast
on its own."""

from __future__ import annotations

import numpy as np

from arlight.backend.mitsuba_scene import build_views
from arlight.demo import DEMO_DIR
from arlight.realtime.light_reduction import reduce_lights
from arlight.realtime.rsm import (
    ROLE_VIRTUAL,
    RSMPair,
    light_rays,
    render_rsm,
    render_rsm_pairs_reusing,
    replace_texels,
    rsm_subset,
    subset_rays,
)
from arlight.realtime.shading import virtual_bounds
from arlight.scene.load import load_scene

FIELDS = ("position", "normal", "albedo", "role", "shape", "t", "direction", "flux_in",
          "flux_out")


def _one_light(views, rays, mu, box) -> RSMPair:
    """The pair of one light on its own: its rays that cross the box cast into the mixed
    view, the virtual hits put into ``mu`` (the per-light code before the batch)."""
    import drjit as dr
    import mitsuba as mi

    lo, hi = box
    pad = 1e-4 * max(float(np.max(hi - lo)), 1e-3)
    bbox = mi.BoundingBox3f(mi.ScalarPoint3f(*(lo - pad)), mi.ScalarPoint3f(*(hi + pad)))
    cand = dr.compress(bbox.ray_intersect(mi.Ray3f(rays.origin, rays.direction))[0])
    if dr.width(cand) == 0:
        return RSMPair(mu, cand, rsm_subset(mu, cand))
    sub = render_rsm(views.mixed, subset_rays(rays, cand))
    virt = dr.compress(sub.role == ROLE_VIRTUAL)
    changed = dr.gather(mi.UInt32, cand, virt)
    return RSMPair(replace_texels(mu, changed, rsm_subset(sub, virt)), changed,
                   rsm_subset(mu, changed))


def test_batched_pairs_equal_one_cast_per_light():
    """The demo's lights (three after reduction) and a light whose map misses the object
    (no candidate ray): each pair equals that light's pair cast on its own. Rejects a
    batch whose lights read the first light's slice of the cast (offsets not advanced, or
    advanced past a light without candidates), and texels put back at the wrong light's
    indices."""
    world = load_scene(DEMO_DIR / "scene.toml").world
    views = build_views(world)
    box = virtual_bounds(world, views.mixed)
    lights = reduce_lights(world).lights
    assert len(lights) >= 2
    centre, radius = (box[0] + box[1]) / 2.0, float(np.linalg.norm(box[1] - box[0]))
    rays = [light_rays(lt, 48, (centre, radius)) for lt in lights]
    far = light_rays(lights[0], 8, (centre + [50.0, 0.0, 0.0], 0.1))  # misses the box
    rays = [rays[0], far, *rays[1:]]
    mus = [render_rsm(views.real, r) for r in rays]
    got = render_rsm_pairs_reusing(views, rays, mus, box)
    changed = []
    for pair, r, mu in zip(got, rays, mus, strict=True):
        want = _one_light(views, r, mu, box)
        for a, b in ((pair.rho, want.rho), (pair.mu(), want.mu())):
            for name in FIELDS:
                assert np.array_equal(np.array(getattr(a, name)),
                                      np.array(getattr(b, name))), name
        assert np.array_equal(np.array(pair.changed), np.array(want.changed))
        changed.append(np.array(pair.changed).size)
    assert changed[1] == 0 and sum(changed) > changed[0] > 0
