"""In-memory AR scene: the validated content of a scene file, split into world and view.

* :class:`World` — what stays the same from frame to frame: the real proxy, the virtual
  objects in their rest pose, materials and lights.
* :class:`FrameView` — one frame of that world: the camera (intrinsics, pose, lens,
  transfer), the background image, optional depth, per-frame object transforms, a timestamp.
  A video is one world and many views.
* :class:`ARScene` — a world seen in one view (what a scene file holds); ``scene.world`` and
  ``scene.view`` split it, :meth:`ARScene.compose` joins them.

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
    faces ``(F, 3)`` uint32, optional per-vertex texture coordinates ``(V, 2)`` and unit
    vertex normals ``(V, 3)`` float32 (None: flat faces). ``normals_from`` says where the
    normals came from: ``"file"``, ``"recompute"`` or ``"flat"``."""

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray | None = None
    normals: np.ndarray | None = None
    normals_from: str = "flat"


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
    group: str | None = None
    """For a part of a ``model`` entry: the entry's name (object transforms and saving
    address the whole model by it); None otherwise."""

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


def _posed_shapes(shapes: list[Shape], transforms: dict[str, np.ndarray]) -> list[Shape]:
    """Shapes with ``transforms[name]`` applied; a model entry's name (``Shape.group``)
    moves all of its parts."""
    groups = {s.group for s in shapes if s.group is not None}
    unknown = sorted(set(transforms) - {s.name for s in shapes} - groups)
    if unknown:
        raise ValueError(f"object transform for unknown shape {unknown[0]!r}")

    def key(s: Shape) -> str | None:
        return s.name if s.name in transforms else (
            s.group if s.group in transforms else None)

    return [replace(s, to_world=np.asarray(transforms[k], np.float64) @ s.to_world)
            if (k := key(s)) is not None else s for s in shapes]


class _ShapeRoles:
    """Shapes by role, for the classes that hold a ``shapes`` list."""

    shapes: list[Shape]

    @property
    def real_shapes(self) -> list[Shape]:
        return [s for s in self.shapes if s.role == "real"]

    @property
    def virtual_shapes(self) -> list[Shape]:
        return [s for s in self.shapes if s.role == "virtual"]

    @property
    def has_virtual(self) -> bool:
        return any(s.is_virtual for s in self.shapes)


@dataclass
class World(_ShapeRoles):
    """The static part of an AR scene: real proxy, virtual objects, materials, lights.

    Attributes:
        shapes: real and virtual shapes in their rest pose (world coordinates, metres).
        lights: the real illumination.
        source: the file the world was loaded from, if any.
        raw: the scene dictionary as read (paths absolute); used for hashing and saving.
    """

    shapes: list[Shape]
    lights: list[Light]
    source: Path | None = None
    raw: dict[str, Any] = field(default_factory=dict)

    def posed(self, transforms: dict[str, np.ndarray]) -> World:
        """The world with ``transforms[name]`` (4×4, world space) applied on the left of the
        named shapes' object-to-world matrices; ValueError for an unknown name."""
        if not transforms:
            return self
        return replace(self, shapes=_posed_shapes(self.shapes, transforms))


def box_filtered(frame: np.ndarray | None, depth: np.ndarray | None, width: int,
                 height: int) -> tuple[np.ndarray | None, np.ndarray | None]:
    """``frame`` ``(H, W, 3)`` and ``depth`` ``(H, W)`` (either may be None) box-filtered to
    ``height × width``: the frame's mean over each ``k × k`` block, the depth's over its
    known (finite, positive) values (NaN where none is). ``H, W`` must be the same integer
    multiple ``k`` of ``height, width`` (a ValueError says otherwise)."""
    ref = frame if frame is not None else depth
    if ref is None:
        return None, None
    h, w = ref.shape[:2]
    if h % height or w % width or h // height != w // width:
        raise ValueError(f"cannot box-filter a {w}×{h} frame to {width}×{height}")
    k = h // height
    small_depth = None
    if depth is not None:
        d = depth.reshape(height, k, width, k)
        known = np.isfinite(d) & (d > 0)
        n = known.sum(axis=(1, 3))
        total = np.where(known, d, 0.0).sum(axis=(1, 3))
        with np.errstate(invalid="ignore", divide="ignore"):
            small_depth = np.where(n > 0, total / n, np.nan).astype(np.float32)
    small = None
    if frame is not None:
        small = frame.reshape(height, k, width, k, 3).mean(axis=(1, 3)).astype(np.float32)
    return small, small_depth


@dataclass
class FrameView:
    """One frame of a world: what changes from frame to frame.

    Attributes:
        camera: the calibrated camera of this frame (intrinsics, pose, lens, transfer).
        frame: the background image ``I_c``, linear radiance ``(H, W, 3)`` float32, or None.
        frame_codes: raw code values of an LDR frame (for byte-identical output), or None.
        depth: optional depth ``(H, W)`` float32, metres along the camera's +z axis; NaN or
            0 where unknown (RGB-D input).
        object_transforms: shape name -> 4×4 world-space transform applied to that shape's
            rest pose in this frame (rigid motion of a tracked or animated object).
        timestamp: capture time in seconds, or None.
    """

    camera: Camera
    frame: np.ndarray | None = None
    frame_codes: np.ndarray | None = None
    depth: np.ndarray | None = None
    object_transforms: dict[str, np.ndarray] = field(default_factory=dict)
    timestamp: float | None = None

    def __post_init__(self) -> None:
        h, w = self.camera.height, self.camera.width
        if self.frame is not None and self.frame.shape != (h, w, 3):
            raise ValueError(f"frame shape {self.frame.shape} != camera resolution {(h, w, 3)}")
        if self.depth is not None and self.depth.shape != (h, w):
            raise ValueError(f"depth shape {self.depth.shape} != camera resolution {(h, w)}")

    def resized(self, width: int, height: int) -> FrameView:
        """This frame seen by the same camera at ``width × height`` (an integer fraction of
        its size): frame and depth box-filtered (:func:`box_filtered`), no code values (they
        describe the full-size frame)."""
        frame, depth = box_filtered(self.frame, self.depth, width, height)
        return replace(self, camera=self.camera.resized(width, height), frame=frame,
                       frame_codes=None, depth=depth)


@dataclass
class ARScene(_ShapeRoles):
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
        depth: optional depth image ``(H, W)`` in metres (see :class:`FrameView`).
        timestamp: capture time in seconds, or None.

    ``shapes`` are posed for this frame; :attr:`world` and :attr:`view` split the scene into
    its static and per-frame parts.
    """

    camera: Camera
    shapes: list[Shape]
    lights: list[Light]
    frame: np.ndarray | None = None
    frame_codes: np.ndarray | None = None
    source: Path | None = None
    raw: dict[str, Any] = field(default_factory=dict)
    depth: np.ndarray | None = None
    timestamp: float | None = None

    @property
    def world(self) -> World:
        """The static part (shapes as posed in this scene, lights)."""
        return World(shapes=self.shapes, lights=self.lights, source=self.source, raw=self.raw)

    @property
    def view(self) -> FrameView:
        """The per-frame part (camera, frame, depth, timestamp; shapes are already posed)."""
        return FrameView(camera=self.camera, frame=self.frame, frame_codes=self.frame_codes,
                         depth=self.depth, timestamp=self.timestamp)

    @classmethod
    def compose(cls, world: World, view: FrameView) -> ARScene:
        """The world seen in ``view``, with the view's object transforms applied."""
        return cls(camera=view.camera, shapes=world.posed(view.object_transforms).shapes,
                   lights=world.lights, frame=view.frame, frame_codes=view.frame_codes,
                   source=world.source, raw=world.raw, depth=view.depth,
                   timestamp=view.timestamp)

    @property
    def resolution(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.camera.width, self.camera.height

    def without_virtual(self) -> ARScene:
        """The same scene with every virtual shape removed."""
        return replace(self, shapes=self.real_shapes)

    def resized(self, width: int, height: int) -> ARScene:
        """The scene seen by the same camera at another resolution.

        The frame and depth, if any, are box-filtered (:func:`box_filtered`); that needs the
        old size to be an integer multiple of the new one (a ValueError says otherwise).
        """
        cam = self.camera.resized(width, height)
        raw = copy.deepcopy(self.raw)
        raw_cam = raw.setdefault("camera", {})
        raw_cam["resolution"] = [width, height]
        if "intrinsics" in raw_cam:
            raw_cam["intrinsics"] = {"fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy}
        out = replace(self, camera=cam, frame=None, frame_codes=None, depth=None, raw=raw)
        if self.frame is None and self.depth is None:
            return out
        frame, out.depth = box_filtered(self.frame, self.depth, width, height)
        return out if frame is None else out.with_frame(frame)

    def with_frame(self, frame: np.ndarray, codes: np.ndarray | None = None) -> ARScene:
        """The same scene with another background frame (linear radiance ``(H, W, 3)``)."""
        h, w = self.camera.height, self.camera.width
        if frame.shape != (h, w, 3):
            raise ValueError(f"frame shape {frame.shape} != camera resolution {(h, w, 3)}")
        return replace(self, frame=np.asarray(frame, dtype=np.float32), frame_codes=codes)
