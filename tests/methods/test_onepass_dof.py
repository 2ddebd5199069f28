"""Depth of field through onepass (Kán §3.4, Eq. 3.1–3.3; checklist 7)."""

from __future__ import annotations

import numpy as np
import pytest

from arlight.methods import RenderSettings, get_method
from arlight.scene.load import parse_scene


def point_scene(aperture: float, focus: float, shape: str = "disk", depth: float = 3.0,
                size: float = 0.02, res: int = 48) -> object:
    """A tiny square emitter facing the camera at ``depth`` m, nothing else."""
    d = {"camera": {"resolution": [res, res], "fov_y_deg": 20,
                    "look_at": {"origin": [0, 0, 0], "target": [0, 0, -1]},
                    "aperture_radius": aperture, "focus_distance": focus,
                    "aperture_shape": shape},
         "shapes": [{"name": "ball", "role": "virtual", "type": "sphere", "radius": 0.05,
                     "transform": {"translate": [0.25, 0.25, -2.0]}}],
         "lights": [{"type": "area", "size": [size, size], "normal": [0, 0, 1],
                     "transform": {"translate": [0, 0, -depth]}, "radiance": 100.0}]}
    scene = parse_scene(d)
    return scene.with_frame(np.zeros((res, res, 3), np.float32))


def test_zero_aperture_equals_pinhole():
    """With aperture 0 the focus distance and aperture shape cannot matter: bitwise equal."""
    s = RenderSettings(spp=4, max_depth=3, seed=1)
    a = get_method("onepass")(point_scene(0.0, 1.0), s)
    b = get_method("onepass")(point_scene(0.0, 7.0, "square"), s)
    np.testing.assert_array_equal(a.composite, b.composite)
    np.testing.assert_array_equal(a.mask, b.mask)


@pytest.mark.parametrize("shape,var_per_d2", [("disk", 1 / 16), ("square", 1 / 12)])
def test_blur_matches_circle_of_confusion(shape, var_per_d2):
    """The blur spot of a point at depth z has the thin-lens diameter within 10 %.

    A uniform disk of diameter D has per-axis variance D²/16 (a square of side D: D²/12);
    the pixel box and the emitter's own image add (1 + w²)/12.
    """
    depth, focus = 3.0, 1.5
    scene = point_scene(0.13, focus, shape, depth)
    cam = scene.camera
    coc = float(cam.circle_of_confusion(np.array([depth]))[0])
    assert 8 < coc < 20
    img = get_method("onepass")(scene, RenderSettings(spp=256, max_depth=1, seed=4)).mixed
    lum = img.mean(axis=2).astype(np.float64)
    ys, xs = np.mgrid[0:cam.height, 0:cam.width] + 0.5
    total = lum.sum()
    mx, my = (lum * xs).sum() / total, (lum * ys).sum() / total
    var = 0.5 * ((lum * (xs - mx) ** 2).sum() + (lum * (ys - my) ** 2).sum()) / total
    w = 0.02 * cam.fy / depth  # image of the emitter itself, pixels
    diameter = np.sqrt((var - (1.0 + w * w) / 12.0) / var_per_d2)
    assert diameter == pytest.approx(coc, rel=0.10)
    assert abs(mx - cam.cx) < 0.5 and abs(my - cam.cy) < 0.5


def test_in_focus_point_stays_sharp():
    scene = point_scene(0.13, 3.0)
    img = get_method("onepass")(scene, RenderSettings(spp=64, max_depth=1, seed=4)).mixed
    lum = img.mean(axis=2)
    lit = np.argwhere(lum > 1e-3 * lum.max())
    assert np.ptp(lit[:, 0]) <= 2 and np.ptp(lit[:, 1]) <= 2


def test_mask_is_averaged_over_lens_samples():
    """A defocused virtual edge gives fractional mask values (blends with the frame)."""
    scene = point_scene(0.13, 1.0)
    layers = get_method("onepass")(scene, RenderSettings(spp=64, max_depth=1, seed=4))
    frac = (layers.mask > 0.02) & (layers.mask < 0.98)
    assert frac.sum() > 10
