"""Small worlds for the near-field tests (built in code, no files)."""

from __future__ import annotations

import numpy as np

from arlight.scene.load import parse_scene

CAMERA = {"resolution": [48, 32], "fov_y_deg": 50.0,
          "look_at": {"origin": [0.0, 1.0, 2.5], "target": [0.0, 0.6, 0.0]}}


def diffuse(albedo) -> dict:
    return {"type": "diffuse", "albedo": list(albedo)}


def room(virtual: list[dict] | None = None, extra: list[dict] | None = None,
         light: bool = True) -> dict:
    """A 2 m room open at z = +1 (floor, ceiling, three walls), an optional real box, a
    ceiling area light; ``virtual`` shapes added as given."""
    white = diffuse([0.7, 0.7, 0.7])
    shapes = [
        {"name": "floor", "role": "real", "type": "rectangle", "size": [2, 2],
         "normal": [0, 1, 0], "material": white},
        {"name": "ceiling", "role": "real", "type": "rectangle", "size": [2, 2],
         "normal": [0, -1, 0], "transform": {"translate": [0, 2, 0]}, "material": white},
        {"name": "back", "role": "real", "type": "rectangle", "size": [2, 2],
         "normal": [0, 0, 1], "transform": {"translate": [0, 1, -1]}, "material": white},
        {"name": "left", "role": "real", "type": "rectangle", "size": [2, 2],
         "normal": [1, 0, 0], "transform": {"translate": [-1, 1, 0]},
         "material": diffuse([0.7, 0.1, 0.1])},
        {"name": "right", "role": "real", "type": "rectangle", "size": [2, 2],
         "normal": [-1, 0, 0], "transform": {"translate": [1, 1, 0]}, "material": white},
    ] + list(extra or []) + list(virtual or [])
    lights = [{"name": "lamp", "type": "area", "size": [0.4, 0.4], "normal": [0, -1, 0],
               "transform": {"translate": [0, 1.995, 0]}, "radiance": 10.0}] if light else []
    return {"format": "arlight-scene/1", "camera": CAMERA, "shapes": shapes,
            "lights": lights}


def vbox(name: str = "obj", at=(0.0, 0.3, 0.0), size=(0.3, 0.3, 0.3),
         albedo=(0.8, 0.8, 0.8), material: dict | None = None) -> dict:
    return {"name": name, "role": "virtual", "type": "box", "size": list(size),
            "transform": {"translate": list(at)},
            "material": material or diffuse(albedo)}


def world(d: dict):
    return parse_scene(d).world


def scene(d: dict, frame_value: float = 0.3):
    sc = parse_scene(d)
    h, w = sc.view.camera.height, sc.view.camera.width
    return sc.with_frame(np.full((h, w, 3), frame_value, np.float32))
