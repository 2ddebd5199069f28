"""Every interactive method compiles its kernels once per world: frames with the virtual
object moved and turned, the camera moved and a new seed reuse them (issue #32: a kernel
compiled per frame costs seconds on the CPU). Rejects per-frame values compiled into a
kernel as literals — seeds, camera poses, volume origins that follow the object, light SH
measured from the object's new centre, the AO rays' length from the turned object's box
(ibl, bench_motion 1.40 before bb06628), lamp positions — and NumPy buffers of varying
alignment (:func:`arlight.jit.aligned`)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from arlight.demo import DEMO_DIR
from arlight.methods import RenderSettings, get_method
from arlight.scene.load import load_scene
from arlight.scene.model import FrameView
from tests.kernels import traced_kernels

MIN_OPS = 30
"""Kernels counted: 30 operations or more. Below are Dr.Jit's own conversions of a
``Color3f`` to NumPy (14–23 operations), whose code holds the array's width, which the
footprint changes with the pose. 100, the default, missed the per-pose exact-sum scale and
cone offsets (issue #32) and nearfield's strided ray columns (31 operations, an alignment per
frame)."""


@pytest.fixture(scope="module")
def demo():
    return load_scene(DEMO_DIR / "scene.toml").resized(64, 48)


@pytest.mark.parametrize("name,calls", [
    *((n, "symbolic") for n in ("dir", "dlpv", "dvct", "ibl", "prt", "nearfield", "onepass")),
    *((n, "evaluated") for n in ("dir", "dlpv", "dvct", "ibl", "prt"))])
def test_moving_frames_reuse_the_compiled_kernels(demo, name, calls):
    """``evaluated``: Dr.Jit's virtual calls evaluated, as the studio's drag frames run them
    (``StudioConfig.drag_calls``) — rejects dvct's surround rays with evaluated calls
    (before 8de9164: two kernels of ~6,000 operations compiled on every moving frame, a
    drag frame 2–4 s)."""
    import drjit as dr

    if calls == "evaluated":
        with dr.scoped_set_flag(dr.JitFlag.SymbolicCalls, False):
            return _moving_frames(demo, name)
    return _moving_frames(demo, name)


def _moving_frames(demo, name: str) -> None:
    method = get_method(name)
    prepared = {}
    # prepare's kernels count as seen: a pose that casts again a proxy map prepare cast
    # (dvct's directional RSMs, only when their snapped sphere moves) reuses its kernel
    seen = traced_kernels(lambda: prepared.setdefault("state", method.prepare(demo.world)),
                          min_ops=MIN_OPS)
    state = prepared["state"]
    view = demo.view
    obj = next(s.name for s in demo.world.shapes if s.is_virtual)
    for k in range(4):
        t = np.eye(4)  # moved and turned 2° a frame (bench_motion's turn): its box changes
        c, s = np.cos(np.radians(2.0 * k)), np.sin(np.radians(2.0 * k))
        t[:3, :3] = [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]
        t[0, 3], t[2, 3] = 0.01 * k, 0.005 * k
        pose = view.camera.world_from_camera.copy()
        pose[:3, 3] += [0.003 * k, 0.0, 0.0]
        frame = FrameView(dataclasses.replace(view.camera, world_from_camera=pose),
                          frame=view.frame, depth=view.depth,
                          object_transforms={obj: t} if k else {})
        kernels = traced_kernels(lambda f=frame, k=k: method.render(
            state, f, RenderSettings(spp=1, seed=k)), min_ops=MIN_OPS)
        if k >= 2:  # frame 1 is the first moved one (its pose path); then nothing is new
            assert kernels <= seen, f"{len(kernels - seen)} kernels new in moving frame {k}"
        seen |= kernels


def _lamp_moved(lights, k: int):
    """The demo's lights with the area lamp ``k`` cm along +x and ``k`` % warmer."""
    out = []
    for lt in lights:
        if lt.type == "area":
            m = np.array(lt.params["to_world"], np.float64)
            m[0, 3] += 0.01 * k
            lt = dataclasses.replace(lt, params={
                **lt.params, "to_world": m,
                "radiance": [c * (1.0 + 0.01 * k) for c in lt.params["radiance"]]})
        out.append(lt)
    return out


@pytest.mark.parametrize("name", ["dir", "dlpv", "dvct", "ibl", "prt", "onepass"])
def test_relit_frames_reuse_the_compiled_kernels(demo, name):
    """A lamp moved and recoloured every frame (``BaseMethod.relight``, issue #32: light
    changes update what depends on the light) launches no kernel the earlier relit frames
    did not: rejects the lamp's position, axis or intensity compiled into a kernel as
    literals — before this test, dlpv (the RSM's rays took them as Python floats), dvct
    (its light direction, likewise) and onepass (Mitsuba's rectangle rebuilt its to_world
    as a literal from its scalar copy on update) each compiled kernels per lamp value."""
    method = get_method(name)
    settings = RenderSettings(spp=1, seed=0)
    state = method.prepare(demo.world, settings)
    seen: set[str] = set()
    for k in range(1, 5):
        def frame(k=k):
            method.relight(state, _lamp_moved(demo.world.lights, k), settings)
            method.render(state, demo.view, settings)
        kernels = traced_kernels(frame, min_ops=MIN_OPS)
        if k >= 3:
            assert kernels <= seen, f"{len(kernels - seen)} kernels new in relit frame {k}"
        seen |= kernels


def test_nearfield_turning_stretching_object_reuses_the_kernels(demo):
    """nearfield's virtual objects are traced in object space through opaque pose entries
    (``backend.object_space``): frames that turn and non-uniformly stretch the bunny launch
    no kernel the earlier moved frames did not. Rejects the pose's matrix entries compiled
    into the G-buffer or shadow kernels as literals (one kernel per pose)."""
    method = get_method("nearfield")
    state = method.prepare(demo.world)
    seen: set[str] = set()
    for k in range(1, 5):
        a = np.radians(10.0 * k)
        t = np.diag([1.0 + 0.05 * k, 1.0 - 0.03 * k, 1.0 + 0.02 * k, 1.0])
        t[[0, 0, 2, 2], [0, 2, 0, 2]] *= [np.cos(a), np.sin(a), -np.sin(a), np.cos(a)]
        t[0, 3] = 0.01 * k
        frame = dataclasses.replace(demo.view, object_transforms={"bunny": t})
        kernels = traced_kernels(lambda f=frame, k=k: method.render(
            state, f, RenderSettings(spp=1, seed=k)), min_ops=MIN_OPS)
        if k >= 3:
            assert kernels <= seen, f"{len(kernels - seen)} kernels new in moving frame {k}"
        seen |= kernels
