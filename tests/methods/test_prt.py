"""``prt``: per-vertex SH precomputed radiance transfer (Franke's rigid pipeline) with AR-OOF
shadows on the real surfaces."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from arlight.errors import InputError
from arlight.methods import RenderSettings, get_method
from arlight.methods.prt import prepare
from arlight.realtime.prt_transfer import cached_transfer, check_mesh, precompute, vertex_values
from arlight.scene.model import MeshData
from arlight.sphere.sh import Y00
from tests.conftest import diffuse, env_mirror_scene
from tests.conftest import parsed_with_constant_frame as make

SMALL = {"oof_shells": 8, "oof_directions": 256, "directions": 256}
BUNNY = "src/arlight/data/scenes/meshes/bunny.ply"


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("ARLIGHT_CACHE", str(tmp_path / "cache"))


def bunny_scene(w: int = 48, h: int = 36, rotate_deg: float = 0.0, env_deg: float = 0.0,
                floor: bool = False, virtual: bool = True) -> dict:
    from pathlib import Path

    d = env_mirror_scene(w, h)
    d["lights"][0]["rotation_deg"] = env_deg
    shapes = [d["shapes"][0]] if floor else []
    if virtual:
        shapes.append({"name": "bunny", "role": "virtual", "type": "mesh",
                       "file": str(Path(BUNNY).resolve()),
                       "transform": {"scale": 0.6, "rotate": [0.0, 1.0, 0.0, rotate_deg]},
                       "material": diffuse([0.8, 0.7, 0.6])})
    d["shapes"] = shapes
    d["camera"] = {"resolution": [w, h], "fov_y_deg": 30,
                   "look_at": {"origin": [0.0, 0.5, 1.8], "target": [0.0, 0.3, 0.0]}}
    return d


def run(scene, **opts):
    return get_method("prt")(scene, RenderSettings(options={**SMALL, **opts}))


def test_no_virtual_object_returns_the_frame_exactly():
    """No virtual object → composite == frame bit for bit; rejects shading or a shadow factor
    that touches real pixels when nothing virtual is there."""
    scene = make(bunny_scene(floor=True, virtual=False))
    layers = run(scene)
    assert np.array_equal(layers.composite, scene.frame)
    assert not np.any(layers.delta)


def test_rotating_the_object_equals_rotating_the_light_the_other_way():
    """Bunny turned by 70° about +Y under the map vs the bunny at rest under the map turned by
    −70°: identical per-vertex shading to float tolerance (issue #13); rejects rotating the
    light by R instead of Rᵀ, a transfer stored in world space and an environment rotation
    that disagrees with the object transform's convention."""
    a = prepare(make(bunny_scene(rotate_deg=70.0)).world, _options())
    b = prepare(make(bunny_scene(env_deg=-70.0)).world, _options())
    va, vb = a.vertex_values()[0], b.vertex_values()[0]
    assert np.abs(va).max() > 0.1
    np.testing.assert_allclose(va, vb, rtol=1e-5, atol=1e-6 * np.abs(va).max())


def _options(**kw):
    return get_method("prt").options(RenderSettings(options={**SMALL, **kw}))


def _rel_error(ours, ref, mask) -> float:
    from scipy.ndimage import binary_erosion

    m = binary_erosion(mask > 0.999, iterations=1)
    return float(np.mean(np.abs(ours[m] - ref[m]) / np.maximum(ref[m], 1e-6)))


def test_self_shadowed_prt_is_closer_to_reference_than_unshadowed_sh():
    """Non-convex bunny under the HDR map, direct light only: PRT with ray-traced
    self-occlusion has a smaller mean relative error against Mitsuba (4096 spp, max_depth 2)
    than the unshadowed transfer (= SH irradiance) (issue #13); rejects a visibility that is
    ignored or inverted and a transfer without the 1/π."""
    scene = make(bunny_scene())
    ref = get_method("reference")(scene, RenderSettings(spp=4096, max_depth=2, seed=5))
    shadowed = run(scene, order=3, directions=1024)
    plain = run(scene, order=3, shadowed=False)
    m = shadowed.mask * ref.mask
    e_s, e_p = _rel_error(shadowed.mixed, ref.mixed, m), _rel_error(plain.mixed, ref.mixed, m)
    print(f"mean abs rel error: PRT {e_s:.4f}, unshadowed SH {e_p:.4f}")
    assert e_s < e_p


def test_unoccluded_vertex_reflects_a_uniform_sky_exactly():
    """A single triangle (no self-occlusion) under uniform radiance 1: ``Σ t_k l_k = 1`` at
    every vertex to 1 % (Eq. 2.37 normalisation); rejects a missing 1/π or 4π/K weight."""
    mesh = MeshData(np.array([[0, 0, 0], [1, 0, 0], [0, 0, -1]], np.float32),
                    np.array([[0, 1, 2]], np.uint32),
                    normals=np.tile(np.float32([0, 1, 0]), (3, 1)))
    t = precompute(mesh, order=2, directions=4096)
    light = np.zeros((9, 3))
    light[0] = 1.0 / Y00
    np.testing.assert_allclose(vertex_values(t, light, np.eye(3)), 1.0, rtol=0.01)


def test_transfer_is_cached_on_disk_by_mesh_content(tmp_path):
    """The second request for the same mesh reads the cache (no precomputation time), a
    changed vertex misses it; rejects a key by file name or by object identity."""
    from arlight.realtime import prt_transfer

    mesh = MeshData(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.float32),
                    np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], np.uint32))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        a = cached_transfer(mesh, tmp_path, directions=64)
        prt_transfer._MEMORY.clear()
        b = cached_transfer(mesh, tmp_path, directions=64)
        moved = MeshData(mesh.vertices + np.float32(0.1), mesh.faces)
        c = cached_transfer(moved, tmp_path, directions=64)
    assert not a.from_cache and b.from_cache and not c.from_cache
    assert len(list((tmp_path / "prt").glob("*.npz"))) == 2
    np.testing.assert_array_equal(a.transfer, b.transfer)


def test_order_beyond_the_precomputed_one_is_a_clear_error():
    """Transfer precomputed to order 2, shading asked for order 3 → ValueError naming both;
    rejects silently padding the transfer with zeros."""
    mesh = MeshData(np.array([[0, 0, 0], [1, 0, 0], [0, 0, -1]], np.float32),
                    np.array([[0, 1, 2]], np.uint32),
                    normals=np.tile(np.float32([0, 1, 0]), (3, 1)))
    t = precompute(mesh, order=2, directions=64)
    with pytest.raises(ValueError, match="order 3.*order 2"):
        vertex_values(t, np.zeros((16, 3)), np.eye(3), order=3)


def test_mesh_without_normals_and_non_manifold_mesh_get_clear_warnings():
    """No normals → smooth normals with a warning; an edge shared by three faces → a warning
    that names it non-manifold; no faces → ValueError; rejects silently black or NaN
    shading."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0, -1, 0]], np.float32)
    f = np.array([[0, 1, 2], [0, 1, 3], [0, 1, 4]], np.uint32)
    normals, notes = check_mesh(MeshData(v, f), "fan")
    assert np.all(np.isfinite(normals))
    assert any("no vertex normals" in n for n in notes)
    assert any("non-manifold" in n for n in notes)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        t = precompute(MeshData(v, f), directions=64)
    said = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]
    assert any("non-manifold" in m for m in said) and any("normals" in m for m in said)
    assert np.all(np.isfinite(t.transfer))
    with pytest.raises(ValueError, match="faces"):
        check_mesh(MeshData(v, np.zeros((0, 3), np.uint32)))


def test_primitive_virtual_shape_is_an_input_error():
    """A virtual sphere primitive has no vertices to carry transfer: InputError from the
    capability check naming the shape type (the harness's skip); rejects a crash deep in the
    precomputation."""
    d = bunny_scene(virtual=False)
    d["shapes"] = [{"name": "ball", "role": "virtual", "type": "sphere", "radius": 0.2,
                    "material": diffuse(0.5)}]
    with pytest.raises(InputError, match="virtual sphere"):
        run(make(d))


def test_shadow_on_the_floor_and_lit_bunny():
    """Bunny on a real floor: the bunny is lit (positive radiance) and the floor has a
    shadow; rejects barycentrics swapped onto the wrong vertices (NaN/black pixels) and a
    shadow that darkens nothing."""
    layers = run(make(bunny_scene(floor=True), value=0.4))
    m = layers.mask > 0.999
    assert m.sum() > 50 and np.all(layers.mixed[m] > 0.0)
    # (no ``delta <= 0`` on the floor: the shadow factor is clipped to [0, 1] in
    # oof.shadow_factor; its size is tested in tests/realtime/test_oof.py)
    assert layers.delta.min() < -0.02


def test_inter_reflection_adds_light_inside_a_concavity_only():
    """One bounce (albedo 0.8) raises the transfer's l = 0 coefficient at vertices that see
    the object (inside the bunny's creases) and leaves fully open vertices (nothing to
    reflect) unchanged, never exceeding the unshadowed transfer; rejects a bounce that adds
    light everywhere (missing hit mask) or subtracts it (sign)."""
    from arlight.scene.mesh import read_mesh

    raw = read_mesh(BUNNY)
    mesh = MeshData(raw.vertices.astype(np.float32), raw.faces.astype(np.uint32))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t0 = precompute(mesh, directions=256).transfer[:, 0]
        t1 = precompute(mesh, directions=256, bounces=1, albedo=[0.8] * 3).transfer[:, 0]
        free = precompute(mesh, directions=256, shadowed=False).transfer[:, 0]
    gain = t1 - t0
    occluded = t0 < free  # any hit above the horizon lowers t_0; none: bitwise equal
    assert np.all(gain >= -1e-6)
    assert gain[occluded].mean() > 1e-3
    assert np.allclose(gain[~occluded], 0.0, atol=1e-6)
    assert np.all(t1 <= free + 1e-3)


def test_moving_the_object_reuses_the_cached_transfer():
    """A per-frame object transform re-renders from the memory/disk cache (no
    precomputation: ``prt_seconds_per_vertex == 0``) and turns the shading with it; rejects a
    cache key that includes the pose."""
    import math

    scene = make(bunny_scene())
    method = get_method("prt")
    settings = RenderSettings(options=SMALL)
    state = method.prepare(scene.world, settings)
    a = math.radians(40.0)
    turn = np.array([[math.cos(a), 0, math.sin(a), 0], [0, 1, 0, 0],
                     [-math.sin(a), 0, math.cos(a), 0], [0, 0, 0, 1.0]])
    view = scene.view
    moved = type(view)(**{**view.__dict__, "object_transforms": {"bunny": turn}})
    layers = method.render(state, moved, settings)
    assert layers.stats["prt_seconds_per_vertex"] == 0.0
    assert not np.array_equal(layers.mixed, method.render(state, view, settings).mixed)


def sphere_obj(path, rings: int = 24, segments: int = 48) -> str:
    """A unit UV sphere with exact vertex normals as an OBJ file (prt needs a mesh)."""
    th = np.linspace(0.0, np.pi, rings + 1)[1:-1]
    ph = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    t, p = np.meshgrid(th, ph, indexing="ij")
    ring = np.stack([np.sin(t) * np.cos(p), np.cos(t), np.sin(t) * np.sin(p)], -1)
    v = np.concatenate([[[0.0, 1.0, 0.0]], ring.reshape(-1, 3), [[0.0, -1.0, 0.0]]])
    j = np.arange(segments)
    k = (j + 1) % segments
    faces = [np.stack([np.zeros(segments, int), 1 + k, 1 + j], 1)]
    for i in range(rings - 2):
        a, b = 1 + i * segments + j, 1 + i * segments + k
        c, d = a + segments, b + segments
        faces += [np.stack([a, b, d], 1), np.stack([a, d, c], 1)]
    last = len(v) - 1
    base = 1 + (rings - 2) * segments
    faces.append(np.stack([np.full(segments, last), base + j, base + k], 1))
    lines = [f"v {x:.7f} {y:.7f} {z:.7f}\nvn {x:.7f} {y:.7f} {z:.7f}" for x, y, z in v]
    lines += [" ".join(["f"] + [f"{q + 1}//{q + 1}" for q in f]) for f in np.concatenate(faces)]
    path.write_text("\n".join(lines) + "\n")
    return str(path)


def _mesh_sphere_scene(tmp_path, material: dict, lights: list[dict] | None = None,
                       w: int = 48, h: int = 36) -> dict:
    """A mesh sphere (radius 0.3, :func:`sphere_obj`) under the demo HDR map (or
    ``lights``)."""
    d = env_mirror_scene(w, h)
    d["shapes"] = [{"name": "ball", "role": "virtual", "type": "mesh",
                    "file": sphere_obj(tmp_path / "sphere.obj"),
                    "transform": {"scale": 0.3, "translate": [0.0, 0.35, 0.0]},
                    "material": material}]
    if lights is not None:
        d["lights"] = lights
    d["camera"] = {"resolution": [w, h], "fov_y_deg": 25,
                   "look_at": {"origin": [0.0, 0.6, 2.2], "target": [0.0, 0.3, 0.0]}}
    return d


def _vs_mitsuba(layers, scene, spp: int) -> tuple[float, float, np.ndarray]:
    """(mean abs relative error of the interior virtual pixels, ratio of sums, mask)
    against Mitsuba's path tracer with direct light only (``max_depth = 2``)."""
    from scipy.ndimage import binary_erosion

    ref = get_method("reference")(scene, RenderSettings(spp=spp, max_depth=2, seed=3))
    m = binary_erosion((layers.mask > 0.999) & (ref.mask > 0.999))
    assert m.sum() > 250
    a, b = layers.mixed[m], ref.mixed[m]
    return (float(np.mean(np.abs(a - b) / np.maximum(b, 1e-6))),
            float(a.sum() / max(b.sum(), 1e-12)), m)


def test_glossy_sphere_matches_mitsuba_and_glossy_off_does_not(tmp_path):
    """Convex rough-conductor mesh sphere (α 0.3) under the demo HDR map: prt's SoG glossy
    term (Eqs. 4.25–4.26) against Mitsuba's path tracer (``roughconductor``, GGX, direct
    light only, 4096 spp; independent of ibl's GGX code): mean absolute relative error of the
    interior pixels ≤ 15 % (measured 14.0 %, total 0.88: SoG reads darker than the lobe, see
    docs/methods/prt.md), while ``glossy = false`` is over 50 % off; rejects a SoG lookup
    around the wrong direction (normal or view instead of the mirror direction), a missing
    F0, a self-shadowing factor that darkens an unoccluded convex object, and the
    diffuse-only shading (100 %)."""
    scene = make(_mesh_sphere_scene(tmp_path, {"type": "roughconductor", "alpha": 0.3,
                                               "reflectance": [0.9, 0.8, 0.7]}))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # the grazing view's fit residual
        on = run(scene)
    e_on, r_on, _ = _vs_mitsuba(on, scene, 4096)
    e_off, _, _ = _vs_mitsuba(run(scene, glossy=False), scene, 4096)
    print(f"mean abs rel error to Mitsuba: glossy {e_on:.4f} (ratio {r_on:.3f}), "
          f"diffuse only {e_off:.4f}")
    assert e_on <= 0.15 and e_off > 0.5


def test_point_light_falls_off_across_the_object_like_mitsuba(tmp_path):
    """A diffuse mesh sphere (radius 0.3) lit only by a point light 0.45 m from its centre,
    beside the camera: the irradiance falls off across the object as 1/d² and ends at a sharp
    terminator. prt's virtual pixels against Mitsuba's path tracer (direct light, 1024 spp):
    mean absolute relative error of the pixels above 10 % of the peak ≤ 12 % (measured
    8.5 %: pixel-centre shading of a steep gradient at 48×36) and total within 5 %; rejects
    folding the light into SH seen from the object's centre (the previous prt: one ``I/d²``
    for the whole object, the terminator smeared by order-2 SH: 54 %, total 0.60)."""
    light = [{"type": "point", "position": [0.25, 0.55, 0.35], "intensity": 0.5}]
    scene = make(_mesh_sphere_scene(tmp_path, diffuse([0.8, 0.7, 0.6]), light))
    ours = run(scene)
    _, ratio, m = _vs_mitsuba(ours, scene, 1024)
    ref = get_method("reference")(scene, RenderSettings(spp=1024, max_depth=2, seed=3))
    a, b = ours.mixed[m], ref.mixed[m]
    lit = b.sum(-1) > 0.1 * b.sum(-1).max()
    err = float(np.mean(np.abs(a[lit] - b[lit]) / b[lit]))
    print(f"point light: rel error (lit) {err:.4f}, ratio {ratio:.3f}")
    assert err <= 0.12 and abs(ratio - 1.0) <= 0.05


@pytest.mark.parametrize("name", ["bunny-box", "outdoor-env"])
def test_quality_against_ground_truth(name):
    """Graded against Mitsuba's ground truth like the other real-time methods: the composite
    beats the untouched frame overall and on the virtual pixels (measured MSE ratios
    0.40–0.63 overall, 0.17–0.63 virtual) and the relit ring is not clearly worse than the
    frame (0.60–0.64). Rejects transfer applied to the wrong vertices, an unrotated light,
    an unlit object."""
    from tests.methods.test_dlpv import suite_quality

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # SoG fit residual at grazing views
        r = suite_quality("prt", name)
    assert r["all"] < 0.97 and r["virtual"] < 0.7 and r["ring"] < 1.15, r
