"""onepass with light selection by importance is unbiased on the worlds where the global
power selection failed (issue #35): compared with ``reference`` (Mitsuba's own ``path``
integrator: uniform selection, area sampling — an independent implementation) within 3 SE.

Wrong implementations rejected: a selection pdf that differs between ``sample`` and ``pdf``
(MIS weights not summing to one: a bias wherever BSDF samples hit the lights, e.g. the large
rectangle and the sky), a cosine-weighted sky whose lower hemisphere is lost for good (the
real box's dark side would lose its ground bounce), a spot whose importance cuts it off
inside its cone.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest

import arlight
from arlight.methods import RenderSettings, get_method
from arlight.stats import agreement_fraction
from tests.methods.test_onepass import make

ENVMAP = str(Path(arlight.__file__).parent / "data/light/grace_latlong_256x128.hdr")
DIFFUSE = {"type": "diffuse", "albedo": [0.6, 0.55, 0.5]}


def _world(lights: list[dict], ground: float) -> dict:
    """A ground of side ``ground`` (m), a real box, a virtual sphere, the camera above."""
    return {
        "camera": {"resolution": [24, 18], "fov_y_deg": 50,
                   "look_at": {"origin": [0.0, 1.2, 2.6], "target": [0.0, 0.2, 0.0]}},
        "shapes": [
            {"name": "ground", "role": "real", "type": "rectangle", "size": [ground, ground],
             "normal": [0, 1, 0], "material": DIFFUSE},
            {"name": "box", "role": "real", "type": "box", "size": [0.4, 0.4, 0.4],
             "transform": {"translate": [-0.6, 0.2, -0.3]},
             "material": {"type": "diffuse", "albedo": [0.7, 0.3, 0.2]}},
            {"name": "ball", "role": "virtual", "type": "sphere", "radius": 0.25,
             "transform": {"translate": [0.3, 0.25, 0.1]}, "material": DIFFUSE},
        ],
        "lights": lights,
    }


WORLDS = {
    # a 40 m ground, a dim sky and one 10 cm light of high radiance (power weights gave the
    # sky ~99 % of the samples here)
    "small-light-large-ground": _world([
        {"type": "constant", "radiance": 0.05},
        {"type": "area", "size": [0.1, 0.1], "normal": [0, -1, 0],
         "transform": {"translate": [0.2, 1.2, 0.4]}, "radiance": 800.0}], 40.0),
    # six point lights over five orders of magnitude, a spot and a small bulb
    "many-lights": _world([
        *({"type": "point", "position": [math.cos(k) * 1.5, 0.6 + 0.3 * k, math.sin(k) * 1.5],
           "intensity": 10.0 ** (k - 3)} for k in range(6)),
        {"type": "spot", "position": [0.0, 2.0, 1.0], "target": [0.3, 0.0, 0.1],
         "intensity": 20.0, "cutoff_deg": 25.0, "beam_width_deg": 15.0},
        {"type": "sphere", "position": [-1.0, 0.8, 0.8], "radius": 0.05, "intensity": 2.0}],
        6.0),
    # an HDR environment and a sun over a 20 m ground
    "environment-and-sun": _world([
        {"type": "envmap", "file": ENVMAP, "scale": 0.3, "rotation_deg": 40.0},
        {"type": "directional", "direction": [0.4, -1.0, -0.3], "irradiance": 2.0}], 20.0),
}


@pytest.mark.parametrize("name", [
    "small-light-large-ground",
    # ~20 s each; the sampler-level MIS tests (tests/sampling/test_lights.py) cover every
    # light type, an environment map and a sun in the fast tier
    pytest.param("many-lights", marks=pytest.mark.slow),
    pytest.param("environment-and-sun", marks=pytest.mark.slow)])
def test_importance_selection_agrees_with_reference(name):
    scene = make(WORLDS[name], 0.2)
    s = dict(spp=256, max_depth=5, rr_depth=4)
    one = get_method("onepass")(scene, RenderSettings(
        **s, seed=3, options={"reproject": False, "replica_mode": "scrambles",
                              "light_sampling": "importance"}))
    ref = get_method("reference")(scene, RenderSettings(**s, seed=8))
    for layer in ("mixed", "real", "composite"):
        frac = agreement_fraction(getattr(one, layer), one.stderr[layer],
                                  getattr(ref, layer), ref.stderr[layer],
                                  dof_a=one.stats["stderr_dof"])
        assert frac >= 0.99, (name, layer, frac)
