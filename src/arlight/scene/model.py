"""In-memory AR scene: the validated content of a scene file.

Every shape carries a role, ``"real"`` (part of the proxy of the real world) or ``"virtual"``
(inserted). Lights are real: they stand for the real illumination (estimated or measured).
Materials and lights keep their validated parameters in canonical form (floats, RGB triples,
absolute paths) in ``params``; :mod:`arlight.scene.schema` documents every field and unit.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

from arlight.scene.camera import Camera

Role = Literal["real", "virtual"]


@dataclass(frozen=True)
class Material:
    """A surface material: ``type`` is one of :data:`arlight.scene.schema.MATERIAL_TYPES`."""

    name: str
    type: str
    params: dict[str, Any]


@dataclass(frozen=True)
class MeshData:
    """Triangle mesh in object space: positions ``(V, 3)`` float32 (metres before transform),
    faces ``(F, 3)`` uint32, optional per-vertex texture coordinates ``(V, 2)``."""

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray | None = None


@dataclass(frozen=True)
class Shape:
    """A real or virtual shape with its object-to-world transform and material."""

    name: str
    role: Role
    type: str
    params: dict[str, Any]
    to_world: np.ndarray
    material: Material
    mesh: MeshData | None = None

    @property
    def is_virtual(self) -> bool:
        return self.role == "virtual"


@dataclass(frozen=True)
class Light:
    """A light of the real world; ``type`` is one of :data:`arlight.scene.schema.LIGHT_TYPES`.

    ``radiance_map`` holds the equirectangular radiance for ``envmap`` and ``sh`` lights
    (already converted from angular maps or SH coefficients, before ``scale``).
    """

    name: str
    type: str
    params: dict[str, Any]
    radiance_map: np.ndarray | None = None


@dataclass
class ARScene:
    """Camera, background frame, real proxy, virtual objects and lights.

    Attributes:
        camera: the calibrated camera (intrinsics, pose, lens, transfer function).
        shapes: real and virtual shapes.
        lights: the real illumination.
        frame: the camera image ``I_c`` as linear radiance ``(H, W, 3)`` float32, or None
            (a "world" used only to synthesise photographs needs no frame).
        frame_codes: the raw code values when the frame came from an LDR file, kept so that
            an unchanged frame is written back byte-identical.
        source: the scene file, when loaded from one.
        raw: the scene dictionary as read, with file paths made absolute.
    """

    camera: Camera
    shapes: list[Shape]
    lights: list[Light]
    frame: np.ndarray | None = None
    frame_codes: np.ndarray | None = None
    source: Path | None = None
    raw: dict[str, Any] = field(default_factory=dict)

    @property
    def real_shapes(self) -> list[Shape]:
        return [s for s in self.shapes if s.role == "real"]

    @property
    def virtual_shapes(self) -> list[Shape]:
        return [s for s in self.shapes if s.role == "virtual"]

    @property
    def has_virtual(self) -> bool:
        return any(s.is_virtual for s in self.shapes)

    @property
    def resolution(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.camera.width, self.camera.height

    def without_virtual(self) -> ARScene:
        """The same scene with every virtual shape removed."""
        return replace(self, shapes=self.real_shapes)

    def resized(self, width: int, height: int) -> ARScene:
        """The scene seen by the same camera at another resolution.

        The frame, if any, is box-filtered; that needs the old size to be an integer
        multiple of the new one (a ValueError says otherwise).
        """
        cam = self.camera.resized(width, height)
        raw = copy.deepcopy(self.raw)
        raw_cam = raw.setdefault("camera", {})
        raw_cam["resolution"] = [width, height]
        if "intrinsics" in raw_cam:
            raw_cam["intrinsics"] = {"fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy}
        out = replace(self, camera=cam, frame=None, frame_codes=None, raw=raw)
        if self.frame is None:
            return out
        h, w = self.camera.height, self.camera.width
        if h % height or w % width or h // height != w // width:
            raise ValueError(f"cannot box-filter a {w}×{h} frame to {width}×{height}")
        k = h // height
        small = self.frame.reshape(height, k, width, k, 3).mean(axis=(1, 3))
        return out.with_frame(small.astype(np.float32))

    def with_frame(self, frame: np.ndarray, codes: np.ndarray | None = None) -> ARScene:
        """The same scene with another background frame (linear radiance ``(H, W, 3)``)."""
        h, w = self.camera.height, self.camera.width
        if frame.shape != (h, w, 3):
            raise ValueError(f"frame shape {frame.shape} != camera resolution {(h, w, 3)}")
        return replace(self, frame=np.asarray(frame, dtype=np.float32), frame_codes=codes)
