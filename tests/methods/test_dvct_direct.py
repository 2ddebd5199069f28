"""dvct's real pixels: the virtual objects' shadows from shadow rays (``direct = rays``), the
lost bounce (``lost_bounce``) and the real surround of a virtual pixel (``surround_rays``),
issue #33.

References are independent of the code under test: Mitsuba's own direct-only render of a
floor with a black cube (the photograph without and with it, ``tests/realtime/
test_shading_shadows.py``: no bounce, the change is the shadow alone) and closed forms
computed here in NumPy. Each test names the wrong implementation it rejects."""

from __future__ import annotations

import math

import numpy as np
import pytest

from arlight.methods import RenderSettings, get_method
from arlight.methods.dvct import diffuse_cone_set, surround_set
from arlight.scene.load import parse_scene
from tests.shadow_worlds import POINT, shadow_error, shadow_scene

SMALL = {"volume_size": 32, "rsm_size": 64, "gbuffer_spp": 4}


def test_point_shadow_from_rays_matches_mitsuba(point_world):
    """Under a point light dvct's change of the floor (``direct = rays``, ``lost_bounce``
    off) is within 10 % of Mitsuba's on the changed floor pixels (:func:`shadow_error`,
    measured 0.04). Rejects Franke's shadow cone through ``V_η`` (``direct = cones``: 0.12,
    the voxelised cube's blurred, shifted outline) and the ``−R_µ`` VPLs of the shadowed
    floor read back by the floor's own diffuse cones (``lost_bounce`` on: 0.10 — a plane
    cannot light itself, the true lost bounce here is zero); with both, 0.19."""
    scene, photo = point_world
    rays = shadow_error(scene, photo, "dvct", **SMALL, direct="rays", lost_bounce=False)
    cones = shadow_error(scene, photo, "dvct", **SMALL, direct="cones", lost_bounce=False)
    lost = shadow_error(scene, photo, "dvct", **SMALL, direct="rays", lost_bounce=True)
    assert rays < 0.06, (rays, cones, lost)
    assert cones > 0.09 and lost > 0.08, (rays, cones, lost)


def test_area_light_soft_shadow_from_rays_matches_mitsuba(area_world):
    """Under an area light (a wide penumbra in Mitsuba's render) the rays' soft shadow
    (``shadow_samples`` = 8 over the reduced patch) is within 25 % of Mitsuba's change
    (measured 0.18); a hard shadow of the reduced point (``shadow_samples`` = 1: 0.57) and
    the shadow cone (``direct = cones``: 0.73, the cone's aperture from the patch's area
    disk cannot follow the penumbra) are the wrong implementations this rejects."""
    scene, photo = area_world
    soft = shadow_error(scene, photo, "dvct", **SMALL, direct="rays", lost_bounce=False)
    hard = shadow_error(scene, photo, "dvct", **SMALL, direct="rays", lost_bounce=False,
                         shadow_samples=1)
    cones = shadow_error(scene, photo, "dvct", **SMALL, direct="cones", lost_bounce=False)
    assert soft < 0.25, (soft, hard, cones)
    assert hard > 0.4 and cones > 0.4, (soft, hard, cones)


@pytest.mark.parametrize("direct", ["rays", "cones"])
def test_frame_unchanged_without_a_virtual_object(direct):
    """Without a virtual object (a real box on the floor casting a real shadow) the
    composite is the photograph bit for bit and the delta zero, with either direct mode.
    Rejects a direct change that is not a difference of the mixed and the real scene
    (e.g. the real box's shadow removed again)."""
    d = shadow_scene(POINT, 48, 36)
    d["shapes"][1]["role"] = "real"
    d["shapes"][1]["material"]["albedo"] = 0.5
    frame = np.random.default_rng(0).random((36, 48, 3)).astype(np.float32)
    scene = parse_scene(d).with_frame(frame)
    out = get_method("dvct")(scene, RenderSettings(options={**SMALL, "direct": direct}))
    assert not np.any(out.delta)
    assert np.array_equal(out.composite, frame)


def _sky_share(dirs: np.ndarray, w: np.ndarray, tilt: float) -> float:
    """Weighted share of ``dirs`` (normal frame, z = normal) above the horizon of a floor
    for a normal tilted by ``tilt`` (rad) from the up direction (about the local x axis)."""
    up = np.array([0.0, math.sin(tilt), math.cos(tilt)])
    return float(w[dirs @ up > 0.0].sum() / w.sum())


def test_surround_rays_estimate_the_sky_view_factor():
    """``surround_set`` is cosine-distributed: its weights sum to π, it integrates
    ``<n, ω>`` over the hemisphere to ``2π/3`` (closed form: ``∫ cos² θ dω``), and the
    cosine-weighted share of open sky above an infinite floor for a normal tilted by ``β``
    from the vertical, the view factor ``(1 + cos β)/2`` (closed form), is within 0.05 for
    β in 0–120° with 64 rays (measured 0.039: a ray is 1/64). Rejects the nine cone axes
    as rays (steps: off by up to 0.22 where the normal crosses the horizon — the band
    across a bevelled cube's face on world-1000007) and directions uniform over the
    hemisphere instead of cosine-weighted (they integrate ``<n, ω>`` to π/2)."""
    dirs, w = surround_set(64)
    assert w.sum() == pytest.approx(math.pi)
    assert np.allclose(np.linalg.norm(dirs, axis=1), 1.0) and dirs[:, 2].min() > 0.0
    assert (w * dirs[:, 2]).sum() == pytest.approx(2.0 * math.pi / 3.0, rel=0.01)
    tilts = np.radians(np.arange(0.0, 121.0, 5.0))
    want = (1.0 + np.cos(tilts)) / 2.0
    got = np.array([_sky_share(dirs, w, t) for t in tilts])
    assert np.abs(got - want).max() < 0.05, np.abs(got - want).max()
    nine, w9, _ = diffuse_cone_set(60.0)
    old = np.array([_sky_share(nine, w9, t) for t in tilts])
    assert np.abs(old - want).max() > 0.1
