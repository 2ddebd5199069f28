"""Small worlds for the probeless tests: the synthetic room, seen at CI resolution."""

from __future__ import annotations

import numpy as np
import pytest

from arlight.backend.mitsuba_scene import build_views
from arlight.probeless import synthetic_rgbd as S
from arlight.scene.model import ARScene, Material, Shape


def box(name: str, size, centre, role: str = "real", albedo: float = 0.6) -> Shape:
    """An axis-aligned box shape."""
    m = np.eye(4)
    m[:3, 3] = centre
    mat = Material(f"m{albedo}", "diffuse", {"albedo": [albedo] * 3, "texture": None,
                                             "two_sided": True})
    return Shape(name, role, "box", {"size": list(map(float, size))}, m, mat)


def views_of(shapes, camera=None):
    """Mitsuba views of ``shapes`` (no lights: the probeless pipeline never uses them)."""
    cam = camera or S.camera_path(1, False, 80, 60)[0]
    return build_views(ARScene(camera=cam, shapes=list(shapes), lights=[]))


@pytest.fixture(scope="module")
def room_camera():
    return S.camera_path(1, False, 80, 60)[0]


@pytest.fixture(scope="module")
def room_views(room_camera):
    return views_of(S.room_shapes(), room_camera)
