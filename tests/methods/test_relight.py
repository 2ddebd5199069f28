"""Light updates (issue #32): ``BaseMethod.relight(state, lights)`` recomputes what depends on
the light and keeps the rest; renders afterwards equal bitwise those of a state prepared
from scratch with the new lights, at rest and in a pose.

Each test names the wrong implementation it rejects."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from arlight.backend.mitsuba_scene import build_views
from arlight.methods import RenderSettings, get_method
from arlight.methods.base import relight_views
from arlight.scene.load import parse_world
from arlight.scene.model import Light
from tests.methods.test_pose_incremental import (  # noqa: F401
    MOVES,
    SMALL,
    _equal,
    demo,
    nearfield_light,
    options_for,
    view_hits,
)

RELIT = ["dir", "dlpv", "dvct", "ibl", "prt", "onepass", "reference", "probeless",
         "nearfield"]
"""Methods whose ``relit`` keeps the Mitsuba views (ibl and prt not when the environment
changes: they prepare again)."""
UNLIT = {"probeless", "nearfield"}
"""Methods whose frames do not depend on the scene's lights (probeless estimates the light
from the frame; nearfield's comes from its light file)."""


def changed_lights(lights: list[Light], change: str) -> list[Light]:
    """The demo's lights with ``change``: ``lamp`` — the area lamp 20 cm further along -x,
    10 cm lower and warmer; ``environment`` — the environment map turned by 40° and
    brighter (same types: updates in place)."""
    out = []
    for lt in lights:
        p = dict(lt.params)
        if lt.type == "area" and change == "lamp":
            m = np.array(p["to_world"], np.float64)
            m[:3, 3] += [-0.2, -0.1, 0.0]
            p.update(to_world=m, radiance=[50.0, 40.0, 25.0])
        elif lt.type == "envmap" and change == "environment":
            p.update(scale=0.9, rotation_deg=40.0)
        out.append(replace(lt, params=p))
    return out


def moved_lamp(lights: list[Light]) -> list[Light]:
    """Both changes of :func:`changed_lights` at once."""
    return changed_lights(changed_lights(lights, "lamp"), "environment")


def estimate_lights() -> list[Light]:
    """Other light types (what ``LightEstimate.to_scene_lights`` gives: a directional sun and
    an SH remainder): no update in place."""
    return parse_world({"lights": [
        {"type": "directional", "direction": [0.3, -0.8, 0.2], "irradiance": [3.0, 2.8, 2.5]},
        {"type": "sh", "coefficients": [[0.8] * 3, [0.0] * 3, [0.3, 0.3, 0.2], [0.0] * 3]}]}
        ).lights


@pytest.mark.parametrize("change", ["lamp", "environment"])
@pytest.mark.parametrize("method", RELIT)
def test_relight_equals_a_fresh_preparation(demo, method, change, request):  # noqa: F811
    """A state rendered at rest and in a pose, then relit (a moved, warmer lamp; or a
    turned, brighter environment), renders in that pose, another pose and at rest bitwise
    what a state prepared from scratch with those lights renders, and keeps its Mitsuba
    views. Rejects a relight that keeps the old reduced lights, RSMs, cone radii, ambient or
    light SH, leaves the views' emitters (or the area lamp's geometry) where they were,
    updates only the rest data and not the posed data, or prepares everything again."""
    m = get_method(method)
    s = RenderSettings(spp=1, options=options_for(method, request))
    state = m.prepare(demo.world, s)
    views = state.data.views
    posed_view = replace(demo.view, object_transforms={"bunny": MOVES[0]})
    before = m.render(state, posed_view, s)
    lights = changed_lights(demo.world.lights, change)
    m.relight(state, lights, s)
    assert (state.data.views is views) == (method not in ("ibl", "prt")
                                           or change == "lamp")
    fresh = m.prepare(replace(demo.world, lights=lights), s)
    for view in (posed_view, replace(demo.view, object_transforms={"bunny": MOVES[1]}),
                 demo.view):
        assert _equal(m.render(state, view, s), m.render(fresh, view, s))
    assert _equal(m.render(state, posed_view, s), before) == (method in UNLIT)


@pytest.mark.parametrize("method", ["dir", "ibl", "onepass"])
def test_other_light_types_prepare_again(demo, method):  # noqa: F811
    """Lights of other types (a directional sun and an SH sky instead of an environment
    map and an area lamp) cannot be set in place: the state is prepared again and still
    renders what a fresh preparation renders. Rejects a relight that copies parameters
    into emitters of another type or keeps the area lamp's geometry."""
    m = get_method(method)
    s = RenderSettings(spp=1, options=SMALL[method])
    state = m.prepare(demo.world, s)
    view = replace(demo.view, object_transforms={"bunny": MOVES[0]})
    m.render(state, view, s)
    m.relight(state, estimate_lights(), s)
    fresh = m.prepare(replace(demo.world, lights=estimate_lights()), s)
    assert _equal(m.render(state, view, s), m.render(fresh, view, s))
    assert _equal(m.render(state, demo.view, s), m.render(fresh, demo.view, s))


def _up_hits(views) -> dict[str, np.ndarray]:
    """Distance, normal and shape index of rays straight up from a grid above the table
    under the demo's lamp (old and moved), in both views."""
    import mitsuba as mi

    x, z = np.meshgrid(np.linspace(0.1, 0.8, 24), np.linspace(-0.05, 0.55, 20))
    n = x.size
    return view_hits(views, mi.Ray3f(
        mi.Point3f(x.ravel().astype(np.float32), np.full(n, 0.3, np.float32),
                   z.ravel().astype(np.float32)),
        mi.Vector3f(np.zeros(n, np.float32), np.ones(n, np.float32), np.zeros(n, np.float32))))


def test_relight_views_moves_the_lamp_geometry(demo):  # noqa: F811
    """Rays up from the table hit the moved area lamp where views built with the new lights
    hit it (distance, normal, shape index), in both views; lights of other types are
    refused. Rejects a light update that changes the emitters' radiance but not the lamp's
    rectangle, rebuilds no acceleration structure, or copies parameters between types."""
    views = build_views(demo.world)
    before = _up_hits(views)
    new = moved_lamp(demo.world.lights)
    assert relight_views(views, demo.world.lights, new)
    fresh = _up_hits(build_views(replace(demo.world, lights=new)))
    moved = _up_hits(views)
    for name in ("real", "mixed"):
        assert np.array_equal(moved[name], fresh[name], equal_nan=True)
        assert not np.array_equal(moved[name], before[name], equal_nan=True)
    assert not relight_views(views, new, estimate_lights())


@pytest.mark.parametrize("method", ["dlpv", "dvct"])
def test_relit_rsms_are_cast_for_the_new_lights(demo, method):  # noqa: F811
    """After a relight the proxy's RSMs belong to the new reduced lights. Rejects a relight
    that keeps the old maps: frames would still be right (``rsm_pair`` casts maps of
    another light set again for that frame only) but every frame would pay for the
    cast."""
    m = get_method(method)
    s = RenderSettings(spp=1, options=SMALL[method])
    state = m.prepare(demo.world, s)
    m.render(state, replace(demo.view, object_transforms={"bunny": MOVES[0]}), s)
    m.relight(state, changed_lights(demo.world.lights, "lamp"), s)
    assert state.last.real_maps.lights is state.last.lights
    assert state.data.real_maps.lights is state.data.lights
