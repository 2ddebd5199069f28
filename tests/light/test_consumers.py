"""Each AR export shaded the way its consumer shades it gives our irradiance (issue 10).

The consumers' formulas are re-implemented here from their published sources:

* ARCore's hello_ar sample (``environmental_hdr.frag`` + ``HelloArActivity``): the app
  multiplies the 27 SH floats by ``sphericalHarmonicFactors`` and the shader sums them
  with the polynomials ``1, y, z, x, xy, yz, 3z^2-1, xz, x^2-y^2`` for ``E/pi``; the main
  light adds ``intensity * max(n.l, 0)`` (times albedo/pi).
* three.js (``shGetIrradianceAt`` in ``lights_pars_begin.glsl.js`` / TSL
  ``getShIrradianceAt``): ``0.886227 c0 + 2*0.511664 (c1 y + c2 z + c3 x) + 2*0.429043
  (c4 xy + c5 yz + c7 xz) + c6 (0.743125 z^2 - 0.247708) + 0.429043 c8 (x^2 - y^2)`` is
  irradiance; ``XREstimatedLight`` turns the primary light into a DirectionalLight of
  colour * intensity = primaryLightIntensity placed along primaryLightDirection.
* Chrome's WebXR on ARCore passes ARCore's SH through unchanged, so a page written for
  ARCore's numbers shades them with the hello_ar formula.
* ARKit/SceneKit (our stated assumption): a light of ``I`` lumens is SceneKit's colour
  factor ``I/1000``; a white diffuse surface facing it shows that factor, which is
  ``E/pi`` for a Lambertian surface.
"""

from __future__ import annotations

import numpy as np
import pytest

from arlight.light.estimate import LightEstimate, arcore_shader_factors
from arlight.sphere import sh
from arlight.sphere.envmap import equirect_directions


def unit(v) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


@pytest.fixture(scope="module")
def est() -> LightEstimate:
    """A sun off every axis, a large warm window, a coloured sky: band-1 and band-2 terms
    of every sign are non-zero, so any sign slip shows."""
    d = equirect_directions(96)
    sky = 0.2 + 0.15 * d[..., 1:2] + 0.05 * d[..., 0:1] * np.array([1.0, 0.5, 0.2])
    img = np.broadcast_to(sky, d.shape).astype(np.float32).copy()
    img[d @ unit([0.5, 0.6, -0.62]) > np.cos(np.radians(2.0))] = [900.0, 850.0, 700.0]
    img[d @ unit([-0.7, 0.3, 0.6]) > np.cos(np.radians(15.0))] = [6.0, 4.0, 2.5]
    return LightEstimate.from_envmap(img, n_lights=8, timestamp=0.0)


def normals(n: int = 64) -> np.ndarray:
    v = np.random.default_rng(7).normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def ours(est: LightEstimate, n: np.ndarray) -> np.ndarray:
    """Our irradiance as the AR layouts carry it: L2 SH of everything but the main light
    (extra lights folded in) plus the main light's exact cosine."""
    return (sh.irradiance(est.ambient_sh(2), n)
            + np.clip(n @ est.main_direction, 0, None)[:, None] * est.main_irradiance)


def hello_ar(coeffs27: list[float], direction, intensity, n: np.ndarray) -> np.ndarray:
    c = np.asarray(coeffs27).reshape(9, 3) * arcore_shader_factors()[:, None]
    x, y, z = n.T
    p = np.stack([np.ones_like(x), y, z, x, y * x, y * z, 3 * z * z - 1, z * x, x * x - y * y],
                 axis=1)
    return np.pi * (p @ c) + np.clip(n @ np.asarray(direction), 0, None)[:, None] * intensity


def three_sh_irradiance(c: np.ndarray, n: np.ndarray) -> np.ndarray:
    x, y, z = (v[:, None] for v in n.T)
    return (c[0] * 0.886227
            + c[1] * 2.0 * 0.511664 * y + c[2] * 2.0 * 0.511664 * z
            + c[3] * 2.0 * 0.511664 * x
            + c[4] * 2.0 * 0.429043 * x * y + c[5] * 2.0 * 0.429043 * y * z
            + c[6] * (0.743125 * z * z - 0.247708) + c[7] * 2.0 * 0.429043 * x * z
            + c[8] * 0.429043 * (x * x - y * y))


def three_directional(d: dict, n: np.ndarray) -> np.ndarray:
    p, i = d["primaryLightDirection"], d["primaryLightIntensity"]
    rgb = np.array([i["x"], i["y"], i["z"]])
    intensity = rgb.max()
    color = rgb / intensity
    l_dir = unit([p["x"], p["y"], p["z"]])
    return np.clip(n @ l_dir, 0, None)[:, None] * (color * intensity)


def close(a: np.ndarray, b: np.ndarray) -> None:
    np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5 * np.abs(b).max())


def test_arcore_layout_in_the_hello_ar_shader(est):
    """ARCore's sample shading of our arcore export = our irradiance. Rejects SH without
    the Condon-Shortley signs, a main direction pointing the way the light travels, and
    the main light left inside the ambient SH (counted twice)."""
    d = est.to_json("arcore")
    n = normals()
    close(hello_ar(d["environmentalHdrAmbientSphericalHarmonics"],
                   d["environmentalHdrMainLightDirection"],
                   np.asarray(d["environmentalHdrMainLightIntensity"]), n), ours(est, n))


def test_webxr_threejs_convention_in_threejs(est):
    """three.js's shGetIrradianceAt + XREstimatedLight's directional light on our webxr
    export (threejs convention) = our irradiance. Rejects CS-phase coefficients and
    ARCore's pre-multiplied factors."""
    d = est.to_json("webxr", sh_convention="threejs")
    assert d["shConvention"] == "threejs"
    c = np.asarray(d["sphericalHarmonicsCoefficients"]).reshape(9, 3)
    n = normals()
    close(three_sh_irradiance(c, n) + three_directional(d, n), ours(est, n))


def test_webxr_arcore_convention_is_what_chrome_delivers(est):
    """With sh_convention='arcore' the webxr SH equal the arcore export's numbers (Chrome
    copies ARCore's through), so the hello_ar formula shades them right and three.js's
    formula shades them wrong. Rejects a switch that changes nothing."""
    d = est.to_json("webxr", sh_convention="arcore")
    np.testing.assert_allclose(d["sphericalHarmonicsCoefficients"],
                               est.to_json("arcore")["environmentalHdrAmbientSphericalHarmonics"])
    n = normals()
    p, i = d["primaryLightDirection"], d["primaryLightIntensity"]
    close(hello_ar(d["sphericalHarmonicsCoefficients"], [p["x"], p["y"], p["z"]],
                   np.array([i["x"], i["y"], i["z"]]), n), ours(est, n))
    wrong = three_sh_irradiance(np.asarray(d["sphericalHarmonicsCoefficients"]).reshape(9, 3), n)
    right = sh.irradiance(est.ambient_sh(2), n)
    assert np.abs(wrong - right).max() > 0.05 * np.abs(right).max()
    back = LightEstimate.from_json(d)
    np.testing.assert_allclose(back.sh, est.ambient_sh(2), atol=1e-9)


def test_arkit_lumens_in_scenekit(est):
    """ARKit layout: primaryLightIntensity = 1000 Y(E)/pi lumens; SceneKit's factor
    I/1000 on a white diffuse surface facing the light equals the Lambertian E/pi
    (luminance), and 1000 lm is the neutral light E = pi. The direction is the one the
    light travels. SH: three planes in the three.js (no CS phase) basis, our assumption.
    Rejects passing the irradiance through as lumens (off by 1000/pi)."""
    d = est.to_json("arkit")
    lum = float(est.main_irradiance @ sh.LUMINANCE)
    assert d["primaryLightIntensity"] == pytest.approx(1000 * lum / np.pi, rel=1e-12)
    n = normals()
    scenekit = d["primaryLightIntensity"] / 1000 * np.clip(
        n @ -np.asarray(d["primaryLightDirection"]), 0, None)
    np.testing.assert_allclose(scenekit, np.clip(n @ est.main_direction, 0, None) * lum / np.pi,
                               rtol=1e-12, atol=1e-12)
    neutral = LightEstimate.from_json({"layout": "arkit", "primaryLightIntensity": 1000.0,
                                       "primaryLightDirection": [0, -1, 0],
                                       "sphericalHarmonicsCoefficients": [0.0] * 27})
    np.testing.assert_allclose(neutral.main_irradiance, np.pi)
    planes = np.asarray(d["sphericalHarmonicsCoefficients"]).reshape(3, 9).T
    close(three_sh_irradiance(planes, n), sh.irradiance(est.ambient_sh(2), n))
