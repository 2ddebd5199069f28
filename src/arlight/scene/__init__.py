"""AR scenes: camera, frame, real proxy, virtual objects and lights; the scene file format."""

from arlight.scene.camera import Camera
from arlight.scene.load import load_scene, parse_scene
from arlight.scene.model import ARScene, Light, Material, Shape

__all__ = ["ARScene", "Camera", "Light", "Material", "Shape", "load_scene", "parse_scene"]
