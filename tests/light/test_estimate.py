"""LightEstimate: construction from maps, scene-light tables, JSON layouts."""

from __future__ import annotations

import json

import numpy as np
import pytest

from arlight.light.estimate import LightEstimate, arcore_shader_factors, sh_to_foreign
from arlight.sphere import sh


def random_dirs(n: int, seed: int = 0) -> np.ndarray:
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


@pytest.fixture
def est(grace) -> LightEstimate:
    return LightEstimate.from_envmap(grace, n_lights=16, sh_order=2, timestamp=12.5)


def test_from_envmap_partitions_the_energy(grace, est):
    full = sh.project_equirect(grace, 2)
    # lights + remainder = the map: equal DC terms (total power), and the L2 SH of the
    # whole environment is close to the map's own L2 SH
    np.testing.assert_allclose(est.total_sh(2)[0], full[0], rtol=1e-6)
    assert np.abs(est.total_sh(2) - full).max() < 0.02 * np.abs(full).max()
    assert len(est.lights) >= 1 and est.timestamp == 12.5
    lum = [lt.irradiance @ sh.LUMINANCE for lt in est.lights]
    assert est.main_irradiance @ sh.LUMINANCE >= max(lum)


def test_irradiance_close_to_brute_force(grace, est):
    from arlight.sphere.envmap import equirect_directions, equirect_solid_angle

    n = random_dirs(40, seed=2)
    d = equirect_directions(grace.shape[0]).reshape(-1, 3)
    w = equirect_solid_angle(grace.shape[0]).ravel()
    brute = (np.clip(n @ d.T, 0, None) * w) @ grace.reshape(-1, 3).astype(np.float64)
    # explicit lights handle the highlights: much better than 9 SH of the raw map
    err_est = np.abs(est.irradiance(n) - brute).mean() / brute.mean()
    err_sh = np.abs(sh.irradiance(sh.project_equirect(grace, 2), n) - brute).mean() / brute.mean()
    assert err_est < 0.05
    assert err_est < err_sh


def test_to_scene_lights_schema(est):
    tables = est.to_scene_lights("directional")
    kinds = [t["type"] for t in tables]
    assert kinds.count("sh") == 1 and kinds.count("directional") == 1 + len(est.lights)
    main = tables[0]
    np.testing.assert_allclose(main["direction"], -est.main_direction)
    assert len(main["irradiance"]) == 3
    sht = tables[-1]["coefficients"]
    assert len(sht) == 9 and all(len(r) == 3 for r in sht)
    pts = est.to_scene_lights("point", room_size=2.5, origin=[0, 1, 0], include_sh=False)
    assert all(t["type"] == "point" for t in pts)
    np.testing.assert_allclose(pts[0]["position"], np.array([0, 1, 0]) + 2.5 * est.main_direction)
    np.testing.assert_allclose(pts[0]["intensity"], est.main_irradiance * 2.5**2)
    json.dumps(tables)  # plain JSON types
    env = est.to_scene_lights(envmap_file="light.hdr.exr")
    assert env == [{"type": "envmap", "file": "light.hdr.exr", "mapping": "equirect",
                    "scale": 1.0, "rotation_deg": 0.0}]
    folded = est.to_scene_lights(include_extra=False)
    np.testing.assert_allclose(folded[-1]["coefficients"], est.ambient_sh(2))


def test_arlight_json_is_lossless(tmp_path, est):
    path = est.save(tmp_path / "light.json")
    back = LightEstimate.load(path)
    np.testing.assert_array_equal(back.sh, est.sh)
    np.testing.assert_array_equal(back.main_direction, est.main_direction)
    np.testing.assert_array_equal(back.main_irradiance, est.main_irradiance)
    assert [lt.to_dict() for lt in back.lights] == [lt.to_dict() for lt in est.lights]
    assert back.timestamp == est.timestamp and back.confidence == est.confidence
    np.testing.assert_array_equal(back.hdr_map, est.hdr_map)


@pytest.mark.parametrize("layout", ["arcore", "arkit", "webxr"])
def test_ar_layouts_roundtrip(layout, est):
    d = json.loads(json.dumps(est.to_json(layout)))
    assert LightEstimate.detect_layout({k: v for k, v in d.items() if k != "layout"}) == layout
    back = LightEstimate.from_json(d)
    np.testing.assert_allclose(back.sh, est.ambient_sh(2), atol=1e-9)
    np.testing.assert_allclose(back.main_direction, est.main_direction, atol=1e-12)
    if layout != "arkit":  # ARKit has a scalar intensity
        np.testing.assert_allclose(back.main_irradiance, est.main_irradiance)
    assert back.timestamp == pytest.approx(est.timestamp, abs=1e-9)
    flat = d.get("sphericalHarmonicsCoefficients",
                 d.get("environmentalHdrAmbientSphericalHarmonics"))
    assert len(flat) == 27


def test_arcore_sample_shader_reproduces_our_irradiance(est):
    """ARCore hello_ar: E/pi = sum_i factor_i c_i p_i(n) with p the shader's polynomials."""
    c = np.asarray(est.to_json("arcore")["environmentalHdrAmbientSphericalHarmonics"]).reshape(
        9, 3) * arcore_shader_factors()[:, None]
    n = random_dirs(30, seed=3)
    x, y, z = n.T
    p = np.stack([np.ones_like(x), y, z, x, y * x, y * z, 3 * z * z - 1, z * x, x * x - y * y],
                 axis=1)
    shader = p @ c
    ours = sh.irradiance(est.ambient_sh(2), n) / np.pi
    np.testing.assert_allclose(shader, ours, rtol=2e-5, atol=1e-6 * np.abs(ours).max())


def test_arcore_factors_match_published_constants():
    published = [0.282095, -0.325735, 0.325735, -0.325735, 0.273137, -0.273137, 0.078848,
                 -0.273137, 0.136569]
    np.testing.assert_allclose(arcore_shader_factors(), published, atol=1e-6)


def test_foreign_basis_signs():
    # a lobe toward +X (ours) shows in the Condon-Shortley C_1^1 with a negative sign
    c = sh.directional_light_coeffs([1.0, 0, 0], [1, 1, 1], 2)
    cs, no_cs = sh_to_foreign(c, True), sh_to_foreign(c, False)
    assert cs[3, 0] < 0 < no_cs[3, 0]
    assert abs(cs[1, 0]) < 1e-12 and abs(cs[2, 0]) < 1e-12


def test_bad_json_names_the_file_and_key(tmp_path):
    p = tmp_path / "x.json"
    p.write_text(json.dumps({"layout": "arcore", "environmentalHdrMainLightDirection": [0, 1, 0]}))
    with pytest.raises(ValueError, match=r"x\.json.*environmentalHdrAmbientSphericalHarmonics"):
        LightEstimate.load(p)
    p.write_text("not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        LightEstimate.load(p)
    with pytest.raises(ValueError, match="confidence"):
        LightEstimate(confidence=2.0)
