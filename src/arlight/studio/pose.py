"""Where the studio has moved a virtual object: a rigid placement on the real surface.

A virtual shape's studio pose is a translation, a rotation about the world's up axis (+Y,
``docs/conventions.md``) and a uniform scale, all about the shape's *anchor* — the bottom
centre of its rest-pose bounding box, the point that stands on the support surface. Its
world-space transform (applied on the left of the rest ``to_world``, as
:attr:`arlight.scene.model.FrameView.object_transforms` wants) is

    M = T(anchor + offset) · R_y(yaw) · S(scale) · T(−anchor)

so the identity pose (offset 0, yaw 0, scale 1) leaves the shape where the scene file put it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

SCALE_RANGE = (0.05, 20.0)
"""Allowed uniform scale factors (dimensionless): beyond them an object vanishes or swallows
the scene and the methods' volumes (voxel grids, RSMs) lose all resolution."""

MAX_OFFSET = 1e3
"""Largest translation from the rest pose, metres (a drag off into the sky is refused)."""


@dataclass(frozen=True)
class ObjectPose:
    """A virtual shape's placement relative to its rest pose.

    Attributes:
        anchor: bottom centre of the rest-pose bounding box, world metres (fixed per shape).
        offset: translation of the anchor, world metres.
        yaw_deg: rotation about +Y through the anchor, degrees (counter-clockwise seen from
            above).
        scale: uniform scale about the anchor, in :data:`SCALE_RANGE`.
    """

    anchor: tuple[float, float, float]
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    yaw_deg: float = 0.0
    scale: float = 1.0

    def __post_init__(self) -> None:
        for name in ("anchor", "offset"):
            v = getattr(self, name)
            if len(v) != 3 or not all(math.isfinite(x) for x in v):
                raise ValueError(f"{name} must be three finite numbers, got {v}")
        if max(abs(x) for x in self.offset) > MAX_OFFSET:
            raise ValueError(f"offset {self.offset} is beyond ±{MAX_OFFSET:g} m")
        if not math.isfinite(self.yaw_deg):
            raise ValueError(f"yaw_deg must be finite, got {self.yaw_deg}")
        lo, hi = SCALE_RANGE
        if not (math.isfinite(self.scale) and lo <= self.scale <= hi):
            raise ValueError(f"scale must be in [{lo:g}, {hi:g}], got {self.scale}")

    @property
    def position(self) -> np.ndarray:
        """Where the anchor stands now, world metres."""
        return np.add(self.anchor, self.offset)

    @property
    def is_rest(self) -> bool:
        return self.offset == (0.0, 0.0, 0.0) and self.yaw_deg == 0.0 and self.scale == 1.0

    def matrix(self) -> np.ndarray:
        """The 4×4 world-space transform ``T(anchor + offset) R_y(yaw) S(scale) T(−anchor)``."""
        a = np.asarray(self.anchor, np.float64)
        c, s = math.cos(math.radians(self.yaw_deg)), math.sin(math.radians(self.yaw_deg))
        rs = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]) * self.scale
        m = np.eye(4)
        m[:3, :3] = rs
        m[:3, 3] = a + np.asarray(self.offset, np.float64) - rs @ a
        return m

    def moved_to(self, position: np.ndarray) -> ObjectPose:
        """The same pose with the anchor at world ``position``."""
        off = tuple(float(x) for x in np.asarray(position, np.float64) - self.anchor)
        return ObjectPose(self.anchor, off, self.yaw_deg, self.scale)

    def with_(self, yaw_deg: float | None = None, scale: float | None = None) -> ObjectPose:
        """The same placement with another yaw and/or scale."""
        return ObjectPose(self.anchor, self.offset,
                          self.yaw_deg if yaw_deg is None else float(yaw_deg),
                          self.scale if scale is None else float(scale))

    def to_json(self) -> dict[str, object]:
        return {"position": [float(x) for x in self.position], "yaw_deg": self.yaw_deg,
                "scale": self.scale}
