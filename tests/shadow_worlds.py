"""A floor, a virtual cube and one light, with Mitsuba's photograph of it: the shadow worlds
of ``tests/realtime/test_shading_shadows.py`` and ``tests/methods/test_dvct_direct.py``
(fixtures ``point_world`` and ``area_world`` in ``tests/conftest.py``)."""

from __future__ import annotations

import numpy as np

from arlight.methods import RenderSettings, get_method
from arlight.scene.load import parse_scene
from arlight.synthetic import synthesize

LUM = np.array([0.2126, 0.7152, 0.0722])
LOOK = {"origin": [0.6, 0.9, 1.6], "target": [0.0, 0.0, 0.0]}
POINT = {"type": "point", "position": [-0.3, 1.3, -0.2], "intensity": 3.0}
AREA = {"type": "area", "size": [0.6, 0.6], "normal": [0, -1, 0],
        "transform": {"translate": [-0.3, 1.0, -0.2]}, "radiance": 12.0}


def shadow_scene(light: dict, w: int = 96, h: int = 72) -> dict:
    """A 2.5 m floor (albedo 0.5), a black 30 cm virtual cube on it, ``light``; seen from
    above at ``w`` × ``h``."""
    return {"camera": {"resolution": [w, h], "fov_y_deg": 40, "look_at": LOOK},
            "shapes": [
                {"name": "floor", "role": "real", "type": "rectangle", "size": [2.5, 2.5],
                 "normal": [0, 1, 0], "material": {"type": "diffuse", "albedo": 0.5}},
                {"name": "cube", "role": "virtual", "type": "box", "size": [0.3] * 3,
                 "transform": {"translate": [0.0, 0.15, 0.0]},
                 "material": {"type": "diffuse", "albedo": 0.0}}],
            "lights": [light]}


def shadow_world(light: dict, eval_cache):
    """The AR scene of :func:`shadow_scene` with Mitsuba's photograph (256 spp, two bounces)
    as its frame, and the photograph."""
    scene = parse_scene(shadow_scene(light))
    photo = synthesize(scene, spp=256, max_depth=2, cache_dir=eval_cache)
    return scene.with_frame(photo.frame), photo


def shadow_error(scene, photo, method: str, **opts) -> float:
    """The method's error on the floor pixels the cube changes (Mitsuba's render changes
    them by > 5 % of the frame): mean ``|composite − GT|`` over the mean ``|frame − GT|``
    (luminance), 0 for the truth and 1 for the frame left as it is."""
    out = get_method(method)(scene, RenderSettings(options=opts))
    fr = np.asarray(photo.frame, np.float64) @ LUM
    gt = np.asarray(photo.ground_truth, np.float64) @ LUM
    comp = np.asarray(out.composite, np.float64) @ LUM
    sel = (np.abs(fr - gt) > 0.05 * fr) & (np.asarray(photo.mask).reshape(fr.shape) < 1e-6)
    assert sel.sum() > 100
    return float(np.abs(comp - gt)[sel].mean() / np.abs(fr - gt)[sel].mean())
