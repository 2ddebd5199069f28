"""Albedo of the real supporting surface from the linearised photo and the light.

Franke (DLPV, Eq. 1): for a Lambertian surface the observed radiance is ``L = ρ E / π``, so
``ρ = π L / E`` with ``E`` the irradiance the estimated light puts on the surface
(:func:`arlight.insert.lighting.plane_irradiance`, unoccluded). Two estimates:

* ``median``: the per-channel median of ``π L / E`` over the pixels that see the plane
  inside its extent, outside the printed target (the target is not the surface's material)
  and not saturated — the surface's albedo as one RGB value;
* ``texture``: ``π L / E`` per texel of the plane (bilinear lookup of the photo at each
  texel's projection), the median where the camera does not see the plane or the pixel is
  saturated. A shadow falling on the printed board then darkens black and white squares
  alike, as the real one would.

Albedo is clipped to [0, 1]; the photo must be linear radiance in the same units as the
light (an exposure mismatch shows up as an albedo above 1 or implausibly dark).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from arlight.errors import InputError
from arlight.insert.lighting import plane_irradiance
from arlight.scene.camera import Camera
from arlight.scene.model import Light

MAX_TEXELS = 2048
"""Largest side of an albedo texture (texels)."""


@dataclass(frozen=True)
class PlaneRegion:
    """The supporting plane ``Y = 0``: ``lo`` and ``hi`` are its (X, Z) corners (m); the
    printed target's (X, Z) rectangle ``target_lo``/``target_hi`` (m)."""

    lo: tuple[float, float]
    hi: tuple[float, float]
    target_lo: tuple[float, float]
    target_hi: tuple[float, float]

    def inside(self, xz: np.ndarray) -> np.ndarray:
        return np.all((xz >= self.lo) & (xz <= self.hi), axis=-1)

    def on_target(self, xz: np.ndarray, margin: float = 0.0) -> np.ndarray:
        lo, hi = np.subtract(self.target_lo, margin), np.add(self.target_hi, margin)
        return np.all((xz >= lo) & (xz <= hi), axis=-1)


@dataclass
class AlbedoEstimate:
    """Result of :func:`estimate_albedo`.

    Attributes:
        median: RGB albedo of the surface outside the target (median, in [0, 1]).
        pixels: number of pixels the median rests on.
        texture: ``(Ht, Wt, 3)`` albedo texture over the plane (row = +Z, column = +X,
            texel centres at ``lo + (i + 0.5)·texel``), or None for ``median``.
        texel: texel side (m), 0 without a texture.
    """

    median: np.ndarray
    pixels: int
    texture: np.ndarray | None = None
    texel: float = 0.0


def _plane_hits(camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """World (X, Z) where each pixel centre's ray meets ``Y = 0`` ``(H, W, 2)``, and whether
    it does (in front of the camera, from above)."""
    h, w = camera.height, camera.width
    v, u = np.mgrid[0:h, 0:w]
    uv = np.stack([u.ravel() + 0.5, v.ravel() + 0.5], axis=1)
    o, d = camera.pixel_rays(uv)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -o[:, 1] / d[:, 1]
    ok = (t > 0) & (o[:, 1] > 0) & np.isfinite(t)
    p = o + np.where(ok, t, 0)[:, None] * d
    return p[:, [0, 2]].reshape(h, w, 2), ok.reshape(h, w)


def estimate_albedo(frame: np.ndarray, camera: Camera, lights: list[Light],
                    region: PlaneRegion, valid: np.ndarray | None = None,
                    mode: str = "texture", photo: str = "<photo>") -> AlbedoEstimate:
    """Albedo of the plane (see the module docstring).

    Args:
        frame: linear radiance ``(H, W, 3)`` W/(sr·m²), undistorted into ``camera``.
        camera: the registered pinhole camera (world = board frame).
        lights: the real lights (scene model).
        region: plane extent and the printed target's rectangle.
        valid: ``(H, W)`` bool, False for saturated pixels (None: all valid).
        mode: ``"median"`` or ``"texture"``.
    Raises :class:`InputError` when no pixel sees the surface outside the target or the
    light puts no irradiance on the plane."""
    if mode not in ("median", "texture"):
        raise ValueError(f"albedo mode must be 'median' or 'texture', got {mode!r}")
    xz, hit = _plane_hits(camera)
    use = hit & region.inside(xz) & ~region.on_target(xz, margin=0.01)
    if valid is not None:
        use &= valid
    if not use.any():
        raise InputError("no pixel sees the supporting plane outside the marker; enlarge "
                         "the plane (--plane-size) or show more of the surface", file=photo)
    pts = np.stack([xz[use][:, 0], np.zeros(use.sum()), xz[use][:, 1]], axis=1)
    E = plane_irradiance(lights, pts)
    if np.any(np.median(E, axis=0) <= 0):
        raise InputError("the light puts no irradiance on the plane (is it below the "
                         "board?); the albedo cannot be estimated", field="--light")
    rho = np.pi * frame[use].astype(np.float64) / np.maximum(E, 1e-12)
    median = np.clip(np.median(rho, axis=0), 0.0, 1.0)
    if mode == "median":
        return AlbedoEstimate(median=median, pixels=int(use.sum()))
    return _texture(frame, camera, lights, region, valid, median, int(use.sum()))


def _texture(frame: np.ndarray, camera: Camera, lights: list[Light], region: PlaneRegion,
             valid: np.ndarray | None, median: np.ndarray, pixels: int) -> AlbedoEstimate:
    """Per-texel ``π L / E``; texels as small as a pixel's footprint at the target's centre
    (at most :data:`MAX_TEXELS` per side)."""
    size = np.subtract(region.hi, region.lo)
    centre = np.array([(region.target_lo[0] + region.target_hi[0]) / 2, 0.0,
                       (region.target_lo[1] + region.target_hi[1]) / 2])
    dist = np.linalg.norm(centre - camera.position)
    texel = max(dist / max(camera.fx, camera.fy), float(size.max()) / MAX_TEXELS)
    nx, nz = (int(np.ceil(s / texel)) for s in size)
    gx = region.lo[0] + (np.arange(nx) + 0.5) * size[0] / nx
    gz = region.lo[1] + (np.arange(nz) + 0.5) * size[1] / nz
    X, Z = np.meshgrid(gx, gz)
    pts = np.stack([X.ravel(), np.zeros(X.size), Z.ravel()], axis=1)
    uv, depth = camera.project(pts)
    # OpenCV samples with pixel centres at integers, arlight's are at +0.5
    mx = (uv[:, 0] - 0.5).reshape(nz, nx).astype(np.float32)
    my = (uv[:, 1] - 0.5).reshape(nz, nx).astype(np.float32)
    seen = ((depth > 0) & (uv[:, 0] >= 0.5) & (uv[:, 0] <= camera.width - 0.5)
            & (uv[:, 1] >= 0.5) & (uv[:, 1] <= camera.height - 0.5)).reshape(nz, nx)
    if camera.position[1] <= 0:
        seen[:] = False
    L = cv2.remap(np.ascontiguousarray(frame, np.float32), mx, my, cv2.INTER_LINEAR,
                  borderMode=cv2.BORDER_REPLICATE)
    if valid is not None:
        ok = cv2.remap(valid.astype(np.float32), mx, my, cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_REPLICATE)
        seen &= ok >= 0.999
    E = plane_irradiance(lights, pts).reshape(nz, nx, 3)
    rho = np.pi * L.astype(np.float64) / np.maximum(E, 1e-12)
    tex = np.where(seen[..., None], np.clip(rho, 0.0, 1.0), median[None, None])
    return AlbedoEstimate(median=median, pixels=pixels, texture=tex.astype(np.float32),
                          texel=float(size[0] / nx))
