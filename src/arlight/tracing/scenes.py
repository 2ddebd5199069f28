"""The prepared state of the path-tracing methods: a world and its two Mitsuba views.

Shared by ``reference``, ``onepass`` and ``dic`` (their ``prepare`` builds the real-only µ
and mixed ρ scenes once per world, see :class:`arlight.methods.fragments.PathScenesMethod`).
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.mitsuba_scene import SceneViews, build_views
from arlight.scene.model import World


def frame_gather(frame: np.ndarray):
    """A function pixel-index -> frame radiance (Color3f) for use inside kernels."""
    flat = np.ascontiguousarray(frame.reshape(-1, 3), dtype=np.float32)
    table = mi.Color3f(flat[:, 0], flat[:, 1], flat[:, 2])
    return lambda pixel: dr.gather(mi.Color3f, table, pixel)


@dataclass
class PathScenes:
    """Prepared state of the path tracers: the world and its two Mitsuba views."""

    world: World
    views: SceneViews


def prepare_scenes(world: World) -> PathScenes:
    """Build the real-only (µ) and mixed (ρ) Mitsuba scenes of ``world``."""
    return PathScenes(world, build_views(world))


__all__ = ["PathScenes", "frame_gather", "prepare_scenes"]
