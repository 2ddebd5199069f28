"""Drag frames compile nothing (issue #32): a studio drag frame moves the object every
frame, and a kernel compiled per frame costs milliseconds (LLVM: 5–10 ms for a 67-operation
kernel) on top of a frame budget of about 100 ms. Unlike ``tests/methods/
test_kernel_reuse.py`` (kernels of ≥ 100 operations) kernels from :data:`MIN_OPS` count here.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from arlight.demo import DEMO_DIR
from arlight.methods import RenderSettings, get_method
from arlight.scene.load import load_scene
from tests.kernels import traced_kernels

MIN_OPS = 30
"""Smaller kernels are Dr.Jit's own compress/reduction kernels whose code follows the
per-frame lane counts (16–23 operations on the demo; found in the kernel cache)."""


def _all_kernels(render) -> set[str]:
    """Hashes of the JIT kernels of :data:`MIN_OPS` operations or more that ``render()``
    launches."""
    return traced_kernels(render, MIN_OPS)


@pytest.mark.parametrize("symbolic", [True, False])
@pytest.mark.parametrize("name", ["dlpv", "dir"])
def test_moving_drag_frames_compile_no_kernel(name, symbolic):
    """With symbolic and with evaluated calls (the studio's drag frames). Rejects
    per-frame values compiled into small kernels as literals — dlpv's RSM candidate test
    against the objects' bounding box (``rsm.render_rsm_pair_reusing``) compiled one kernel
    per frame."""
    import drjit as dr

    before = dr.flag(dr.JitFlag.SymbolicCalls)
    dr.set_flag(dr.JitFlag.SymbolicCalls, symbolic)
    try:
        _drag_frames(name)
    finally:
        dr.set_flag(dr.JitFlag.SymbolicCalls, before)


def _drag_frames(name: str) -> None:
    """Five drag frames of ``name`` at 80×60 with its 1/8 drag options, the object moving;
    frames 3 and 4 launch no kernel the earlier ones did not."""
    demo = load_scene(DEMO_DIR / "scene.toml").resized(80, 60)
    method = get_method(name)
    spec = method.spec
    settings = RenderSettings(spp=1, options=spec.drag(spec.parse_options({}), 8))
    state = method.prepare(demo.world, settings)
    seen: set[str] = set()
    for k in range(5):
        t = np.eye(4)
        t[0, 3], t[2, 3] = 0.013 * k - 0.03, 0.007 * (k % 3)
        frame = dataclasses.replace(demo.view, object_transforms={"bunny": t} if k else {})
        kernels = _all_kernels(lambda f=frame: method.render(state, f, settings))
        if k >= 3:  # frame 1 is the first moved one (its pose path)
            assert kernels <= seen, f"{len(kernels - seen)} kernels new in drag frame {k}"
        seen |= kernels
