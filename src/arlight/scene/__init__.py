"""AR scenes: the static world (real proxy, virtual objects, lights) and per-frame views
(camera, background frame, depth, object poses); the scene file format."""

from arlight.scene.camera import Camera
from arlight.scene.load import (
    load_scene,
    load_view,
    load_world,
    parse_scene,
    parse_view,
    parse_world,
)
from arlight.scene.model import ARScene, FrameView, Light, Material, Shape, World
from arlight.scene.save import save_scene

__all__ = ["ARScene", "Camera", "FrameView", "Light", "Material", "Shape", "World",
           "load_scene", "load_view", "load_world", "parse_scene", "parse_view", "parse_world",
           "save_scene"]
