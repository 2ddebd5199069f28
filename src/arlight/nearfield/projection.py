"""Projecting the fisheye cameras into the radiance atlas and merging them (Rohmer §4.1).

Per covered texel ``x`` (normal ``n``) and camera ``i`` (centre ``c_i``, main direction
``d_i``): the texel is seen when the segment ``c_i``–``x`` crosses no proxy geometry (the
exact form of Rohmer's depth-map test), ``x`` faces the camera and lies in the lens's field
of view. Its weight is

    w_i = cos α_i · cos β_i,   cos α_i = ⟨d_i, x̂ − c_i⟩⁺,   cos β_i = ⟨n, c_i − x̂⟩⁺

(clamped: the fisheye border is low resolution, steep views are unreliable) and the merged
radiance is ``Σ w_i L_i / Σ w_i`` with ``L_i`` the camera's HDR image sampled bilinearly at
the projected pixel. Texels no camera sees get 0 (Rohmer §8: they "lose light").

Everything but the sampling depends on the rig and the proxy only: :func:`camera_taps` (the
weights, the visibility rays and the projected pixels' bilinear taps) is computed once per
rig and proxy (:mod:`arlight.nearfield.projection_cache`), and an update only samples each
image at its taps and accumulates ``Σ w_i L_i`` in place (:func:`accumulate`,
:func:`combine`). :func:`project_camera` + :func:`merge` is the same from scratch; the two
give bitwise the same result (same taps, same arithmetic, same order of the sums).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from arlight.errors import InputError
from arlight.nearfield.atlas import AtlasGeometry
from arlight.nearfield.raytrace import segment_visible


class RigCamera(Protocol):
    """What projection needs of a rig camera (:class:`arlight.nearfield.cameras.RigCamera`
    satisfies it; a protocol so that ``cameras`` may import this module without a circle)."""

    name: str
    model: Any  # project(u) -> (pixels, inside); world_from_camera
    position: np.ndarray

    @property
    def axis(self) -> np.ndarray: ...

    @property
    def size(self) -> tuple[int, int]: ...


@dataclass
class BilinearTaps:
    """Where the bilinear samples at ``K`` pixel positions of a ``size`` image come from.

    Attributes:
        size: (width, height) of the image, pixels.
        i00, i01, i10, i11: (K,) flat pixel indices ``y·width + x`` of the neighbours
            (x0, y0), (x1, y0), (x0, y1), (x1, y1).
        fx, fy: (K, 1) fractional offsets from (x0, y0), in [0, 1].
    """

    size: tuple[int, int]
    i00: np.ndarray
    i01: np.ndarray
    i10: np.ndarray
    i11: np.ndarray
    fx: np.ndarray
    fy: np.ndarray

    def __len__(self) -> int:
        return len(self.i00)


def bilinear_taps(size: tuple[int, int], xy: np.ndarray) -> BilinearTaps:
    """The taps of bilinear samples at pixel coordinates ``xy (N, 2)`` of a ``size = (w, h)``
    image (pixel centres at +0.5; clamped to the border)."""
    w, h = int(size[0]), int(size[1])
    x = np.clip(xy[:, 0] - 0.5, 0.0, w - 1.0)
    y = np.clip(xy[:, 1] - 0.5, 0.0, h - 1.0)
    x0 = np.minimum(np.floor(x).astype(np.int64), w - 2 if w > 1 else 0)
    y0 = np.minimum(np.floor(y).astype(np.int64), h - 2 if h > 1 else 0)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    return BilinearTaps((w, h), y0 * w + x0, y0 * w + x1, y1 * w + x0, y1 * w + x1,
                        (x - x0)[:, None], (y - y0)[:, None])


def apply_taps(image: np.ndarray, taps: BilinearTaps) -> np.ndarray:
    """The bilinear samples ``(K, C)`` of ``image (H, W, C)`` at ``taps`` (made for its size)."""
    h, w = image.shape[:2]
    if (w, h) != taps.size:
        raise ValueError(f"taps for a {taps.size[0]}×{taps.size[1]} image applied to {w}×{h}")
    flat = image.reshape(h * w, -1)
    fx, fy = taps.fx, taps.fy
    return ((1 - fy) * ((1 - fx) * flat[taps.i00] + fx * flat[taps.i01])
            + fy * ((1 - fx) * flat[taps.i10] + fx * flat[taps.i11]))


def bilinear(image: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Bilinear samples ``(N, C)`` of ``image (H, W, C)`` at pixel coordinates ``xy (N, 2)``
    (pixel centres at +0.5; clamped to the border)."""
    h, w = image.shape[:2]
    return apply_taps(image, bilinear_taps((w, h), xy))


@dataclass
class CameraProjection:
    """One camera's contribution on the covered texels (flat, in ``covered`` order).

    Attributes:
        weight: (N,) w_i (0 where unseen).
        radiance: (N, 3) sampled radiance, W/(sr·m²) (0 where unseen).
    """

    weight: np.ndarray
    radiance: np.ndarray


def camera_weights(geom: AtlasGeometry, cam: RigCamera, proxy) -> tuple[np.ndarray,
                                                                        np.ndarray]:
    """``(w (N,), pixel (N, 2))`` of ``cam`` over the covered texels (module docstring);
    ``proxy`` is the Mitsuba scene of the proxy mesh (visibility)."""
    mask = geom.covered
    x = geom.position[mask]
    n = geom.normal[mask]
    v = x - cam.position
    dist = np.linalg.norm(v, axis=1)
    u = v / np.maximum(dist, 1e-30)[:, None]
    cos_a = np.clip(u @ cam.axis, 0.0, 1.0)
    cos_b = np.clip(-np.einsum("ni,ni->n", u, n), 0.0, 1.0)
    w = cos_a * cos_b
    pix, inside = cam.model.project(u)
    w = np.where(inside & (dist > 1e-6), w, 0.0)
    todo = np.flatnonzero(w > 0)
    if len(todo):
        seen = segment_visible(proxy, np.broadcast_to(cam.position, (len(todo), 3)),
                               x[todo])
        w[todo[~seen]] = 0.0
    return w, pix


@dataclass
class CameraTaps:
    """What one camera's projection keeps between updates (rig and proxy only).

    Attributes:
        weight: (N,) w_i over the covered texels (0 where unseen).
        seen: (K,) indices of the texels with w_i > 0.
        taps: the bilinear taps of the seen texels' projected pixels.
    """

    weight: np.ndarray
    seen: np.ndarray
    taps: BilinearTaps


def camera_taps(geom: AtlasGeometry, cam: RigCamera, proxy) -> CameraTaps:
    """Weights, visibility and bilinear taps of ``cam`` over the covered texels (the part of
    the projection that does not depend on the image; ``proxy``: Mitsuba scene of the proxy
    mesh)."""
    w, pix = camera_weights(geom, cam, proxy)
    seen = np.flatnonzero(w > 0)
    return CameraTaps(w, seen, bilinear_taps(cam.size, pix[seen]))


def check_image(image: np.ndarray, cam: RigCamera) -> np.ndarray:
    """``image`` as float32 ``(H, W, ≥3)``; InputError unless it matches the camera's size
    and holds finite, non-negative values."""
    img = np.asarray(image, np.float32)
    w_px, h_px = cam.size
    if img.ndim != 3 or img.shape[:2] != (h_px, w_px) or img.shape[2] < 3:
        raise InputError(f"image of shape {img.shape} does not match the calibration's "
                         f"{w_px}×{h_px} (RGB)", field=f"cameras.{cam.name}.image")
    if not np.all(np.isfinite(img)) or np.any(img < 0):
        raise InputError("HDR image holds negative or non-finite values",
                         field=f"cameras.{cam.name}.image")
    return img


def _check_seen(taps: CameraTaps, name: str) -> None:
    if len(taps.seen) == 0:
        raise InputError("the camera sees nothing of the proxy (no texel in its field of "
                         "view faces it unoccluded); check its position and look direction",
                         field=f"cameras.{name}")


def sample_camera(taps: CameraTaps, image: np.ndarray, name: str = "camera"
                  ) -> CameraProjection:
    """One camera's contribution from its cached ``taps`` and a checked ``image``
    (:func:`check_image`): the radiance sampled at the seen texels, 0 elsewhere.

    Raises:
        InputError: the camera sees no texel of the proxy (``name`` is the camera's).
    """
    _check_seen(taps, name)
    rad = np.zeros((len(taps.weight), 3))
    rad[taps.seen] = apply_taps(image[..., :3], taps.taps)
    return CameraProjection(taps.weight, rad)


def accumulate(acc: np.ndarray, taps: CameraTaps, image: np.ndarray,
               name: str = "camera") -> None:
    """``acc (N, 3) += w_i · L_i`` on the texels the camera sees (in place; only those are
    touched). Cameras accumulated in rig order and then :func:`combine` d give bitwise
    :func:`merge` of their :func:`sample_camera` projections (the unseen texels' terms are
    exact zeros there) without the full-size per-camera arrays.

    Raises:
        InputError: the camera sees no texel of the proxy (``name`` is the camera's).
    """
    _check_seen(taps, name)
    seen = taps.seen
    acc[seen] += taps.weight[seen, None] * apply_taps(image[..., :3], taps.taps)


def combine(acc: np.ndarray, weights: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """``(radiance (N, 3), weight sum (N,))`` from the accumulated ``Σ w_i L_i`` and the
    cameras' weights ``w_i (N,)``: ``acc / Σ w_i`` (0 where no camera sees the texel)."""
    ws = np.sum(weights, axis=0)
    rad = np.where(ws[:, None] > 0, acc / np.maximum(ws, 1e-300)[:, None], 0.0)
    return rad, ws


def project_camera(geom: AtlasGeometry, cam: RigCamera, image: np.ndarray,
                   proxy) -> CameraProjection:
    """Weights and sampled radiance of one camera (module docstring), nothing cached.

    Raises:
        InputError: the image does not match the camera's size, holds non-finite or
            negative values, or the camera sees no texel of the proxy.
    """
    img = check_image(image, cam)
    return sample_camera(camera_taps(geom, cam, proxy), img, cam.name)


def merge(projections: list[CameraProjection]) -> tuple[np.ndarray, np.ndarray]:
    """``(radiance (N, 3), weight sum (N,))``: the w-weighted mean over cameras (0 where no
    camera sees the texel)."""
    acc = np.sum([p.weight[:, None] * p.radiance for p in projections], axis=0)
    return combine(acc, [p.weight for p in projections])


__all__ = ["BilinearTaps", "CameraProjection", "CameraTaps", "accumulate", "apply_taps",
           "bilinear", "bilinear_taps", "camera_taps", "camera_weights", "check_image",
           "combine", "merge", "project_camera", "sample_camera"]
