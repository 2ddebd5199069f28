"""``dvct`` while the virtual object moves (issue #32): a placement that turning keeps, the
proxy's voxels cut from a window voxelised once, directional RSMs that cover a snapped
sphere — and every pose bitwise what preparing the posed world renders.

Each test names the wrong implementation it rejects."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from arlight.backend.mitsuba_scene import build_views
from arlight.demo import DEMO_DIR
from arlight.methods import RenderSettings, get_method
from arlight.methods.dvct import SPEC, directional_coverage, place_volume
from arlight.realtime.sh_volume import Grid
from arlight.realtime.shading import virtual_bounds
from arlight.realtime.voxels import LatticeVoxels, shape_triangles, voxelize
from arlight.scene.load import load_scene
from tests.methods.test_pose_incremental import rigid

SMALL = {"volume_size": 16, "rsm_size": 32}


@pytest.fixture(scope="module")
def demo():
    return load_scene(DEMO_DIR / "scene.toml").resized(80, 60)


def _same(a, b) -> bool:
    return (np.array_equal(a.index, b.index) and np.array_equal(a.normal_sum, b.normal_sum)
            and (a.cover is None) == (b.cover is None)
            and (a.cover is None or np.array_equal(a.cover, b.cover)))


def test_a_cut_of_the_window_is_the_grid_voxelised_directly(demo):
    """The proxy voxelised over a window of the world lattice and cut to grids at several
    offsets (corners of the window included) holds bitwise what voxelising each grid
    directly gives, covers included, and the same cells as the window-relative voxelisation.
    Rejects a cut with a wrong offset or cell order, and one that keeps cells outside the
    grid."""
    shapes = demo.world.real_shapes
    tris = np.concatenate([shape_triangles(s) for s in shapes])
    grid = Grid(origin=np.array([-7.0, -3.0, -9.0]) * 0.02, cell=0.02, n=16)
    win = LatticeVoxels.around(shapes, grid, with_cover=True)
    assert win.window.n == 32
    for shift in ([0, 0, 0], [8, 8, 8], [-8, -8, -8], [3, -5, 7], [8, -8, 1]):
        g = Grid(origin=grid.origin + np.array(shift) * grid.cell, cell=grid.cell, n=16)
        cut = win.cut(g)
        direct = voxelize(tris, g, with_cover=True, lattice=True)
        assert direct.occupied > 0 and _same(cut, direct)
        assert np.array_equal(cut.index, voxelize(tris, g).index)
    outside = Grid(origin=grid.origin + np.array([9, 0, 0]) * grid.cell, cell=grid.cell, n=16)
    assert win.cut(outside) is None
    assert win.cut(Grid(origin=grid.origin, cell=0.021, n=16)) is None


def test_turning_keeps_the_cells_and_moving_shifts_them_by_whole_cells(demo):
    """With ``volume_extent`` ``frame`` the cell is the bunny's own-frame box edge (mesh
    vertices, computed here in NumPy) × scale / n rounded to float32, the same for every
    turn, and the origin a whole multiple of it; with ``box`` (Franke) a turn changes the
    cell. Rejects an extent from the world-axis box, an unrounded cell (turns change its
    last bits) and an origin off the lattice."""
    opts = SPEC.parse_options(SMALL)
    bunny = next(s for s in demo.world.shapes if s.name == "bunny")
    v = np.asarray(bunny.mesh.vertices, np.float64)
    m = np.asarray(bunny.to_world, np.float64)[:3, :3]
    edge = float(np.max(np.linalg.norm(m, axis=0) * (v.max(0) - v.min(0))))
    cells, box_cells = set(), set()
    for angle in (0.0, 5.0, 30.0, 77.0):
        posed = demo.world.posed({"bunny": rigid(angle, [0.013 * angle / 77, 0.0, 0.0])})
        bounds = virtual_bounds(posed, build_views(posed).mixed)
        g = place_volume(posed, bounds, opts)
        cells.add(g.cell)
        assert g.cell == float(np.float32(edge * 2.0 / 16))
        assert np.array_equal(g.origin, np.rint(g.origin / g.cell) * g.cell)
        box = SPEC.parse_options({**SMALL, "volume_extent": "box"})
        box_cells.add(place_volume(posed, bounds, box).cell)
    assert len(cells) == 1 and len(box_cells) > 1


def test_directional_coverage_holds_the_volume_and_moves_in_steps():
    """The snapped sphere contains the 8 corners of every volume it is made for, and stays
    the same sphere while the volume moves less than its step. Rejects a radius without the
    snapping margin, and a centre that follows the volume cell by cell."""
    rng = np.random.default_rng(3)
    for _ in range(200):
        g = Grid(origin=np.round(rng.normal(0, 40, 3)) * 0.01, cell=0.01, n=16)
        c, r = directional_coverage(g)
        corners = g.origin + g.size * np.array([[i, j, k] for i in (0, 1) for j in (0, 1)
                                                for k in (0, 1)])
        assert np.all(np.linalg.norm(corners - c, axis=1) <= r * (1 + 1e-12))
    base = Grid(origin=np.array([0.0, 0.0, 0.0]), cell=0.01, n=16)  # centre 0.08 = 4 steps
    same = Grid(origin=np.array([0.009, 0.0, -0.009]), cell=0.01, n=16)
    far = Grid(origin=np.array([0.011, 0.0, 0.0]), cell=0.01, n=16)
    assert np.array_equal(directional_coverage(base)[0], directional_coverage(same)[0])
    assert not np.array_equal(directional_coverage(base)[0], directional_coverage(far)[0])


def test_poses_reuse_what_they_can_and_equal_a_fresh_preparation(demo):
    """A sequence of poses — turns in place, a 1 cm move, a move past the window's margin
    (the proxy voxelised again), a move back — each renders bitwise what preparing the
    posed world renders, while the volume moves every time: the window is kept while the
    volume stays inside it, the directional maps while their snapped sphere stays, the other
    lights' maps always. Rejects a pose that keeps a window the volume left, keeps
    directional maps whose sphere moved, or voxelises the proxy on every pose."""
    m = get_method("dvct")
    s = RenderSettings(spp=1, options=SMALL)
    state = m.prepare(demo.world, s)
    first = state.data
    kinds = [lt.kind for lt in first.lights.lights]
    assert "directional" in kinds
    # (transform, window kept, directional maps kept); at 16 cells the coverage's step is
    # 2 cells: a 5° turn shifts the volume one cell in z, 1 cm one cell in x (the sphere
    # stays), a 30° turn and 5 cm two to three cells (across a step)
    seq = [(rigid(-5.0, [0.0, 0.0, 0.0]), True, True),
           (rigid(0.0, [0.01, 0.0, 0.0]), True, True),
           (rigid(30.0, [0.0, 0.0, 0.05]), True, False),
           (rigid(25.0, [0.6, 0.0, 0.2]), False, False),
           (rigid(40.0, [0.0, 0.0, 0.01]), False, False)]
    for transform, window, maps in seq:
        view = replace(demo.view, object_transforms={"bunny": transform})
        posed = m.render(state, view, s)
        data = m.pose(state, {"bunny": transform}, s)
        fresh_state = m.prepare(demo.world.posed({"bunny": transform}), s)
        fresh = m.render(fresh_state, demo.view, s)
        for k in ("mixed", "delta", "mask", "composite"):
            assert np.array_equal(getattr(posed, k), getattr(fresh, k)), k
        assert _same(data.real_voxels, fresh_state.data.real_voxels)
        assert not np.array_equal(data.grid.origin, first.grid.origin)
        assert (data.real_window is first.real_window) == window
        assert all((a is b) == (maps or k != "directional") for k, a, b in zip(
            kinds, data.real_maps.mu, first.real_maps.mu, strict=True))


def test_moving_frames_compile_no_kernel(demo):
    """Frames with the bunny turned 5° and moved 1 cm further every frame (as bench_motion)
    launch no kernel of 30 or more operations that an earlier frame did not launch — the
    small reductions included that ``test_kernel_reuse`` leaves out (below 100 operations).
    Rejects per-frame widths or data-dependent scales compiled into kernels as literals:
    the shadow cones' per-light offsets (the real lanes' count changes with the pose) and
    the fixed-point scale of the exact injection sums (``exact_sum``), both of which compiled
    kernels on every moving frame (the scale: :func:`test_exact_sums_of_any_scale_share_a_kernel`).
    (Below 30 operations: the Mitsuba update's scatters of NumPy buffers whose alignment
    varies.)"""
    import drjit as dr

    m = get_method("dvct")
    s = RenderSettings(spp=1, options=SMALL)
    state = m.prepare(demo.world, s)
    seen: set[str] = set()
    for i in range(1, 6):
        view = replace(demo.view, object_transforms={
            "bunny": rigid(5.0 * i, [0.01 * i, 0.0, 0.004 * i * i])})
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        try:
            m.render(state, view, s)
        finally:
            history = dr.kernel_history()
            dr.set_flag(dr.JitFlag.KernelHistory, False)
        kernels = {k["hash"] for k in history if k.get("type") == dr.KernelType.JIT
                   and k.get("operation_count", 0) >= 30}
        if i >= 3:
            assert kernels <= seen, f"{len(kernels - seen)} kernels new in moving frame {i}"
        seen |= kernels


def test_exact_sums_of_any_scale_share_a_kernel():
    """The injection's order-independent sums (:func:`~arlight.realtime.exact_sum.
    scatter_sum_exact`) of values 1000× larger — another fixed-point scale — launch the
    kernels the first sums launched, and still sum exactly (against NumPy). Rejects the scale
    as a literal (a new kernel whenever a moving object changed the injected flux's range)."""
    import drjit as dr
    import mitsuba as mi

    from arlight.jit import aligned
    from arlight.realtime.exact_sum import scatter_sum_exact

    rng = np.random.default_rng(5)
    idx = rng.integers(0, 7, 500)
    base = rng.random(500).astype(np.float32)
    seen = None
    for factor in (1.0, 1000.0):
        vals = (base * factor).astype(np.float32)
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        try:
            out = scatter_sum_exact([mi.Float(aligned(vals, np.float32))],
                                    mi.UInt32(aligned(idx, np.uint32)), mi.Bool(True), 7)[0]
            got = np.array(out)
        finally:
            history = dr.kernel_history()
            dr.set_flag(dr.JitFlag.KernelHistory, False)
        kernels = {k["hash"] for k in history if k.get("type") == dr.KernelType.JIT}
        want = np.bincount(idx, weights=vals.astype(np.float64), minlength=7)
        assert np.allclose(got, want, rtol=1e-6)
        if seen is not None:
            assert kernels <= seen
        seen = kernels
