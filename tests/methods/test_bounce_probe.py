"""The frozen bounce probe (issue #32): ibl's and prt's probe at the virtual objects
(:func:`arlight.realtime.ibl_shading.bounce_probe`) replays a ``dr.freeze`` recording of its
path tracing for each new centre, records anew for each scene generation (a new scene, or
one changed in place through :meth:`SceneView.update`), and is bitwise the probe traced
without freezing.

Each test names the wrong implementation it rejects."""

from __future__ import annotations

import gc
from dataclasses import replace

import numpy as np
import pytest

from arlight.backend.mitsuba_scene import build_views
from arlight.demo import DEMO_DIR
from arlight.methods.base import relight_views
from arlight.realtime import ibl_shading as ib
from arlight.scene.load import load_scene
from tests.methods.test_relight import changed_lights

CENTRES = [np.array([0.0, 0.1, 0.0]), np.array([0.03, 0.1, -0.02]),
           np.array([-0.05, 0.12, 0.04])]
"""Probe centres (m): the bunny's and two poses around it."""


@pytest.fixture(scope="module")
def world():
    return load_scene(DEMO_DIR / "scene.toml").world


def _probe(view, centre, env):
    """The probe of ``view`` (a SceneView: frozen) or its bare scene (traced anew)."""
    return ib.bounce_probe(view, centre, env, threshold=3.0, spp=4)


def _same(a: ib.BounceProbe, b: ib.BounceProbe) -> bool:
    return np.array_equal(a.full, b.full) and np.array_equal(a.diffuse, b.diffuse)


def _recordings() -> int:
    return ib._frozen_probe_radiance.n_recordings


def test_frozen_probe_follows_poses_and_lamps_moved_in_place(world):
    """Over three centres, a lamp moved and recoloured by ``relight_views`` and moved back,
    the frozen probe equals bitwise the probe traced without freezing (the view's bare
    scene); the centres replay one recording (no new one per pose), each in-place change
    records once. Rejects a probe remembered per scene (stale after the lamp moved), a
    frozen function keyed without the view's generation (the move back replays the
    recording of the moved lamp: no new recording) and one that records per centre (the
    origin compiled in)."""
    env = ib.environment_map(world)
    views = build_views(world)
    real = views.real
    first = None
    for k, c in enumerate(CENTRES):
        before = _recordings()
        p = _probe(real, c, env)
        assert _same(p, _probe(real.scene, c, env)), f"centre {k}"
        assert _recordings() == before + (k == 0), f"centre {k} recorded anew"
        first = p if first is None else first
    moved = changed_lights(world.lights, "lamp")
    probes = []
    for before_lights, after_lights in ((world.lights, moved), (moved, world.lights)):
        generation, before = real.generation, _recordings()
        assert relight_views(views, before_lights, after_lights)
        assert real.generation != generation
        p = _probe(real, CENTRES[0], env)
        assert _same(p, _probe(real.scene, CENTRES[0], env))
        assert _recordings() == before + 1
        probes.append(p)
    assert not np.array_equal(probes[0].full, first.full)  # the lamp's move is seen
    assert _same(probes[1], first)  # and moving it back restores the probe


def test_a_new_scene_records_anew(world):
    """A scene built again after the old one is gone (here: the table's albedo changed, a
    layout of Dr.Jit variables Dr.Jit alone would replay) records its own probe, bitwise
    the unfrozen one. Rejects a frozen key without the generation (a replay across scenes:
    correct today only as far as Dr.Jit's traversal sees every plugin member) and a key
    on ``id(scene)``, which a new scene can reuse."""
    env = ib.environment_map(world)
    views = build_views(world)
    _probe(views.real, CENTRES[0], env)
    del views
    gc.collect()
    table = next(s for s in world.shapes if s.name == "table")
    other = replace(world, shapes=[
        replace(s, material=replace(s.material, params={**s.material.params,
                                                         "albedo": [0.1, 0.7, 0.1]}))
        if s is table else s for s in world.shapes])
    views = build_views(other)
    before = _recordings()
    p = _probe(views.real, CENTRES[1], env)
    assert _recordings() == before + 1
    assert _same(p, _probe(views.real.scene, CENTRES[1], env))
