"""The size the light reduction gives its lights for soft shadows (issue #33,
:class:`arlight.realtime.light_reduction.ReducedLight` ``spread`` / ``extent``)."""

from __future__ import annotations

import math

import numpy as np

from arlight.realtime.light_reduction import _area, _environment
from arlight.sphere.envmap import equirect_directions


def test_environment_light_spread_is_the_disc_radius():
    """An environment that is a dim sky plus a bright uniform disc of angular radius 10°
    reduces to one directional light pointing away from the disc's centre with ``spread``
    within 1° of 10° (the radius computed here from the disc we painted, not by the
    extraction). Rejects dropping the spread (0: a hard shadow for a 20° wide source) and
    the main light's spread left out of the reduction's ordering (the extra lights')."""
    h = 256
    d = equirect_directions(h)  # (H, W, 3)
    centre = np.array([0.3, 0.8, -0.5])
    centre /= np.linalg.norm(centre)
    img = np.full(d.shape, 0.05)
    img[d @ centre > math.cos(math.radians(10.0))] = 50.0
    lights, _ = _environment("sky", img, 0.0, 4, 4.0)
    assert len(lights) == 1
    assert np.degrees(np.arccos(-lights[0].axis @ centre)) < 0.5
    assert abs(math.degrees(lights[0].spread) - 10.0) < 1.0, math.degrees(lights[0].spread)


def test_area_grid_extents_tile_the_rectangle():
    """An area light's ``g × g`` cosine points: each point's patch ``position ± extent``
    lies in the rectangle and the patches' areas (``4 |a × b|``) sum to its area. Rejects
    extents of the whole rectangle at every point and half-edges taken as edges."""
    p = {"to_world": np.diag([1.0, 1.0, 1.0, 1.0]), "size": [0.6, 0.4], "radiance": 2.0}
    pts = _area("lamp", p, 3)
    assert len(pts) == 9
    total = sum(4 * np.linalg.norm(np.cross(*lt.extent)) for lt in pts)
    assert math.isclose(total, 0.6 * 0.4, rel_tol=1e-9)
    for lt in pts:
        corners = [lt.position + sa * lt.extent[0] + sb * lt.extent[1]
                   for sa in (-1, 1) for sb in (-1, 1)]
        assert all(abs(c[0]) <= 0.3 + 1e-9 and abs(c[1]) <= 0.2 + 1e-9 for c in corners)
