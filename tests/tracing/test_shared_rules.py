"""dic's camera walk and the one-pass tracer follow one set of rules (issue #29).

With paths of two vertices (direct light only; the splat buffer then plays no part) the walk
and the tracer compute the same estimator — one light sample and one BSDF-sampled ray
combined by MIS, the one-pass shadow rays, the real continuation at virtual hits — from the
same random dimensions, so they agree *sample by sample*. Changing a rule in its one place
(:class:`~arlight.tracing.onepass.LightSelection`, :class:`~arlight.tracing.onepass.HitRules`)
changes both, and they still agree; the dic and onepass methods both change with it.

Wrong implementations rejected: a walk that samples lights itself (Mitsuba's
``scene.sample_emitter_direction``, or its own copy of the power-based selection), a walk
with its own copy of the shadow-ray or fork rules, a walk with its own random-number
bookkeeping (other dimensions or another hash than the tracer's sampler), dic building its
walk without the record tracer's light selection.
"""

from __future__ import annotations

import copy

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from arlight.methods import RenderSettings, get_method
from arlight.sampling.stream import LaneSampler
from arlight.tracing.irradiance_shading import CameraWalk, SplatLookup
from arlight.tracing.onepass import (
    HitRules,
    LightSelection,
    OnePassTracer,
    TracerOptions,
    lane_keys,
)
from arlight.tracing.scenes import prepare_scenes
from tests.conftest import area_light_scene, env_mirror_scene, load, with_constant_frame

W, H, SPP = 16, 12, 4


def two_light_scene():
    """The area-light room plus a point light: the selection has a choice to make."""
    d = copy.deepcopy(area_light_scene(W, H))
    d["lights"].append({"type": "point", "position": [-0.6, 1.2, 0.8], "intensity": 3.0})
    return with_constant_frame(load(d))


def _np(c) -> np.ndarray:
    return np.stack([np.asarray(x, np.float64) for x in (c.x, c.y, c.z)], axis=1)


def _rays(camera) -> mi.Ray3f:
    v, u = np.mgrid[0:camera.height, 0:camera.width]
    uv = np.repeat(np.stack([u.ravel() + 0.5, v.ravel() + 0.5], axis=1), SPP, axis=0)
    uv += np.random.default_rng(3).uniform(-0.4, 0.4, uv.shape)
    o, d = (x.astype(np.float32) for x in camera.pixel_rays(uv))
    return mi.Ray3f(mi.Point3f(o[:, 0], o[:, 1], o[:, 2]), mi.Vector3f(d[:, 0], d[:, 1], d[:, 2]))


def _setup(scene):
    views = prepare_scenes(scene.world).views
    rays = _rays(scene.camera)
    n = W * H
    lookup = SplatLookup(scene.camera, np.zeros((n, 3)), np.zeros((n, 3)))
    return views, rays, lookup


@pytest.fixture(scope="module")
def setup():
    return _setup(two_light_scene())


@pytest.fixture(scope="module")
def mirror_setup():
    """Environment light, a real mirror showing the virtual ball: delta-specular
    continuation, forks behind the mirror, environment importance sampling and MIS."""
    return _setup(with_constant_frame(load(env_mirror_scene(W, H))))


def both(setup, light_sampling: str = "mitsuba", sampler: str = "independent"):
    """Per-sample (L_m, L_r) of the one-pass tracer and of dic's walk, paths of 2 vertices,
    the walk sampling lights through the tracer's selection, both with one lane sampler."""
    views, rays, lookup = setup
    n = dr.width(rays.d)
    if sampler == "independent":
        key = LaneSampler.independent(lane_keys(n, mi.UInt32(7)))
    else:
        lane = dr.arange(mi.UInt32, n)
        key = LaneSampler.for_samples(sampler, lane // SPP, mi.UInt32(0), lane % SPP,
                                      mi.UInt32(7))
    tracer = OnePassTracer(views.mixed, views.real,
                           TracerOptions(max_depth=2, reproject=False,
                                         light_sampling=light_sampling))
    walk = CameraWalk(views, lookup, 2, tracer.light_selection)
    t, w = tracer.trace_onepass(rays, key), walk.trace(rays, key)
    return (_np(t.mixed), _np(t.real)), (_np(w.mixed), _np(w.real))


def assert_same(t, w):
    for a, b in zip(t, w, strict=True):
        np.testing.assert_allclose(b, a, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize(("scene", "light_sampling", "sampler"),
                         [("two_lights", "mitsuba", "independent"),
                          ("two_lights", "solid_angle", "sobol"),
                          ("two_lights", "importance", "sobol"),
                          ("env_mirror", "mitsuba", "sobol"),
                          ("env_mirror", "importance", "independent")])
def test_walk_equals_tracer_sample_by_sample(request, scene, light_sampling, sampler):
    """Direct light (paths of 2 vertices): the walk is the tracer's estimator, sample by
    sample, whatever the light selection and the sampler (this replaces a statistical
    comparison of the dic and onepass methods, kept in the slow tier)."""
    fixture = "setup" if scene == "two_lights" else "mirror_setup"
    t, w = both(request.getfixturevalue(fixture), light_sampling, sampler)
    assert_same(t, w)
    assert np.abs(t[0] - t[1]).max() > 0.01  # the ball (or its shadow): mixed ≠ real


def _swapped_sample(orig):
    """Another light selection: the selection number shifted by one half (each sample picks
    another light; still uniform, so still unbiased)."""
    def sample(self, view, it, u, active, imps=None):
        ux = u.x + 0.5
        return orig(self, view, it, mi.Point2f(dr.select(ux >= 1.0, ux - 1.0, ux), u.y),
                    active, imps)
    return sample


def _real_sees_mixed(orig):
    """A wrong visibility rule: the real solution takes the mixed shadow ray's answer (the
    virtual object shadows the real-only scene)."""
    def shadow(self, ray, active, *, to_mixed, to_real, c, no_real=None):
        vis_m, vis_r = orig(self, ray, active, to_mixed=to_mixed, to_real=to_real, c=c,
                            no_real=no_real)
        if vis_m is None:
            return vis_m, vis_r
        return vis_m, vis_m if to_real is True else vis_m & to_real
    return shadow


def _never_fork(orig):
    """A wrong ray-type rule: a path never forks (no real continuation through the ball)."""
    def fork(self, active, role, depth, forked, fork_depth):
        return orig(self, active & False, role, depth, forked, fork_depth)
    return fork


CHANGES = {"light_selection": (LightSelection, "sample", _swapped_sample),
           "shadow_rule": (HitRules, "shadow", _real_sees_mixed),
           "fork_rule": (HitRules, "fork", _never_fork)}


@pytest.mark.parametrize("change", sorted(CHANGES))
def test_changing_a_rule_in_its_one_place_changes_both(setup, monkeypatch, change):
    before_t, before_w = both(setup)
    cls, name, make = CHANGES[change]
    monkeypatch.setattr(cls, name, make(getattr(cls, name)))
    after_t, after_w = both(setup)
    changed = [not np.allclose(a, b, rtol=1e-3, atol=1e-4)
               for a, b in zip((*before_t, *before_w), (*after_t, *after_w), strict=True)]
    if change == "light_selection":  # both solutions of both
        assert all(changed), changed
    else:  # the rules of the real solution: its estimate changes in both
        assert changed[1] and changed[3], changed
    assert_same(after_t, after_w)


def test_dic_and_onepass_methods_both_follow_the_selection(monkeypatch):
    """End to end: the changed selection reaches dic's records and walk and onepass."""
    scene = two_light_scene()
    runs = {"dic": RenderSettings(spp=2, max_depth=2, seed=1, options={"rays": 4}),
            "onepass": RenderSettings(spp=2, max_depth=2, seed=1,
                                      options={"light_sampling": "mitsuba"})}
    before = {m: get_method(m)(scene, s).mixed for m, s in runs.items()}
    monkeypatch.setattr(LightSelection, "sample", _swapped_sample(LightSelection.sample))
    after = {m: get_method(m)(scene, s).mixed for m, s in runs.items()}
    for m in runs:
        assert not np.allclose(before[m], after[m], rtol=1e-3, atol=1e-4), m
