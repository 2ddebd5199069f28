"""The differential irradiance cache: records, Tabellion's weight, splatting into a per-pixel
buffer and cache-miss detection by tiles (Kán thesis §4.2.1, §4.2.3, §4.2.4; Eq. 2.15, 4.11).

The cache is a *linear* vector of records (no spatial structure, Kán §4.2.4): records are
appended in the order they are created and splatted in that order. Everything here is NumPy
(deterministic sums in a fixed order, so a static scene splats bit for bit the same every
frame); the records' irradiance is computed by :mod:`arlight.tracing.irradiance_eval`.

* :class:`Records` — ``x_i``, ``n_i``, ``E_m``, ``E_d = E_m − E_r`` (W/m²), ``R_i`` (m), age
  (frames since evaluation), a per-record 32-bit key (its fixed random sequence) and a
  running id.
* :func:`tabellion_weight` — Eq. 2.15,
  ``w_i(x) = 1 − κ max{‖x − x_i‖ / (R_i/2), sqrt(1 − n·n_i) / sqrt(1 − cos 10°)}``.
* :func:`splat` — "rasterises" each record's footprint (the screen box of the disc of radius
  ``R_i / (2κ)`` where ``w_i > 0``) against the splat G-buffer's per-pixel position and
  normal, accumulating ``Σ w``, ``Σ w E_m`` and ``Σ w E_d`` per pixel (Kán §4.2.3; both
  irradiances are kept per pixel — real pixels use ``E_d``, virtual ones ``E_m``, and
  specular paths reprojected onto a pixel may need either).
* :class:`TileScanner` — Kán's cache-miss detection: the buffer cut into square tiles, each
  scanned linearly from where it stopped; the first pixel that needs irradiance and has zero
  accumulated weight becomes a new record, at most one per tile per iteration.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from arlight.scene.camera import Camera

COS_10 = math.cos(math.radians(10.0))
NORMAL_SCALE = 1.0 / math.sqrt(1.0 - COS_10)
"""``1 / sqrt(1 − cos 10°)`` of Eq. 2.15 (normals 10° apart reach the weight's limit)."""

_PAIR_CHUNK = 1 << 21  # (record, pixel) pairs evaluated at once (memory bound)


@dataclass
class Records:
    """A linear vector of cache records (NumPy, one row per record).

    Attributes:
        position: (N, 3) float64 world positions x_i (m).
        normal: (N, 3) float64 unit normals n_i (facing the camera that created them).
        e_mixed: (N, 3) float64 mixed irradiance E_m (W/m²), Kán Eq. 4.7.
        e_delta: (N, 3) float64 differential irradiance E_d = E_m − E_r (W/m²), Eq. 4.8.
        radius: (N,) float64 R_i, the minimum distance to the surfaces the record's rays hit
            (m; Tabellion & Lamorlette 2004), ``inf`` when every ray escaped.
        age: (N,) int64 frames since the record was last evaluated (Algorithm 4.1's t).
        key: (N,) uint32 the record's random sequence (re-evaluation reuses it).
        ident: (N,) int64 running record ids (creation order).
        stderr_mixed, stderr_delta: (N, 3) float64 standard errors of E_m and E_d (W/m²).
        batch: (N,) int64 the miss-detection iteration that created the record (running
            over frames); :func:`splat_batches` sums batch by batch, as they were created.
    """

    position: np.ndarray
    normal: np.ndarray
    e_mixed: np.ndarray
    e_delta: np.ndarray
    radius: np.ndarray
    age: np.ndarray
    key: np.ndarray
    ident: np.ndarray
    stderr_mixed: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    stderr_delta: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    batch: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    def __post_init__(self) -> None:
        n = len(self.position)
        if len(self.stderr_mixed) != n:
            self.stderr_mixed = np.zeros((n, 3))
        if len(self.stderr_delta) != n:
            self.stderr_delta = np.zeros((n, 3))
        if len(self.batch) != n:
            self.batch = np.zeros(n, np.int64)

    @staticmethod
    def empty() -> Records:
        z3 = np.zeros((0, 3))
        return Records(z3, z3, z3, z3, np.zeros(0), np.zeros(0, np.int64),
                       np.zeros(0, np.uint32), np.zeros(0, np.int64))

    def __len__(self) -> int:
        return len(self.position)

    def take(self, idx: np.ndarray) -> Records:
        """The records at ``idx`` (an index or boolean array), in that order."""
        return Records(*(getattr(self, f)[idx] for f in _FIELDS))

    def concat(self, other: Records) -> Records:
        """These records followed by ``other`` (the cache's append)."""
        return Records(*(np.concatenate([getattr(self, f), getattr(other, f)])
                         for f in _FIELDS))

    def with_values(self, idx: np.ndarray, other: Records) -> Records:
        """A copy whose rows ``idx`` take ``other``'s irradiance, radius and age."""
        out = replace(self, **{f: getattr(self, f).copy() for f in _VALUES})
        for f in _VALUES:
            getattr(out, f)[idx] = getattr(other, f)
        return out


_FIELDS = ("position", "normal", "e_mixed", "e_delta", "radius", "age", "key", "ident",
           "stderr_mixed", "stderr_delta", "batch")
_VALUES = ("e_mixed", "e_delta", "radius", "age", "stderr_mixed", "stderr_delta")


def tabellion_weight(x: np.ndarray, n: np.ndarray, xi: np.ndarray, ni: np.ndarray,
                     radius: np.ndarray, kappa: float) -> np.ndarray:
    """Tabellion's interpolation weight, Kán Eq. 2.15 (may be ≤ 0: no contribution).

    Args:
        x, n: (K, 3) receiving points (m) and unit normals.
        xi, ni: (K, 3) record positions and unit normals.
        radius: (K,) R_i (m).
        kappa: the accuracy κ (> 0; larger: smaller footprints, more records).
    """
    dist = np.linalg.norm(x - xi, axis=-1) / (0.5 * radius)
    # sqrt(1 − n·n_i) = ‖n − n_i‖ / √2 for unit normals: exactly 0 for equal normals, where
    # the dot product's rounding would give ~1e-4 (float32) and shrink the own-pixel weight
    dev = np.linalg.norm(n - ni, axis=-1) * (NORMAL_SCALE / math.sqrt(2.0))
    return 1.0 - kappa * np.maximum(dist, dev)


@dataclass
class SplatGeometry:
    """The per-pixel surface the splat buffer is defined on (the pinhole G-buffer).

    Attributes:
        position: (H·W, 3) float64 first-hit points through the pixel centres (m).
        normal: (H·W, 3) float64 unit normals facing the camera.
        needs: (H·W,) bool pixels that take indirect irradiance (a surface with a diffuse
            lobe was hit); only these can be cache misses.
        valid: (H·W,) bool pixels with a surface (splat weights are evaluated there).
        virtual: (H·W,) bool pixels whose surface is a virtual object.
        width, height: buffer size (px).
        albedo: (H·W, 3) float64 diffuse reflectance of the surface (0 on a miss).
    """

    position: np.ndarray
    normal: np.ndarray
    needs: np.ndarray
    valid: np.ndarray
    virtual: np.ndarray
    width: int
    height: int
    albedo: np.ndarray | None = None


@dataclass
class SplatBuffer:
    """Accumulated ``Σ w``, ``Σ w E_m``, ``Σ w E_d`` and, for the standard errors,
    ``Σ w² se²(E_m)``, ``Σ w² se²(E_d)`` per pixel (float64, flat)."""

    weight: np.ndarray
    w_mixed: np.ndarray
    w_delta: np.ndarray
    w2_var_mixed: np.ndarray
    w2_var_delta: np.ndarray

    @staticmethod
    def zeros(pixels: int) -> SplatBuffer:
        return SplatBuffer(np.zeros(pixels), *(np.zeros((pixels, 3)) for _ in range(4)))

    def add(self, other: SplatBuffer) -> SplatBuffer:
        return SplatBuffer(self.weight + other.weight, self.w_mixed + other.w_mixed,
                           self.w_delta + other.w_delta, self.w2_var_mixed + other.w2_var_mixed,
                           self.w2_var_delta + other.w2_var_delta)

    def variance(self) -> tuple[np.ndarray, np.ndarray]:
        """Variances of the interpolated ``(E_m, E_d)`` from the records' Monte Carlo noise
        (independent records: ``Σ w² se² / (Σ w)²``), ``(P, 3)``; 0 where no record
        contributes. The interpolation's bias is not in it."""
        w2 = np.square(self.weight)[:, None]
        safe = np.where(w2 > 0, w2, 1.0)
        return (np.where(w2 > 0, self.w2_var_mixed / safe, 0.0),
                np.where(w2 > 0, self.w2_var_delta / safe, 0.0))

    def irradiance(self) -> tuple[np.ndarray, np.ndarray]:
        """``(E_m, E_d)`` per pixel by Eq. 4.11, ``(P, 3)`` float64; 0 where no record
        contributes."""
        w = self.weight[:, None]
        safe = np.where(w > 0, w, 1.0)
        return (np.where(w > 0, self.w_mixed / safe, 0.0),
                np.where(w > 0, self.w_delta / safe, 0.0))


def effective_radius(records: Records, camera: Camera, kappa: float, min_px: float,
                     max_px: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``R_i`` clamped so each footprint spans ``[min_px, max_px]`` pixels (the screen-space
    clamp of irradiance-cache splatting; Tabellion's R_min/R_max), plus the records' pixel
    coordinates ``(N, 2)`` and camera depths ``(N,)``.

    The footprint of Eq. 2.15 is the disc ``‖x − x_i‖ < R_i / (2κ)``; at camera depth ``z``
    one pixel spans ``z / f`` metres.
    """
    uv, z = camera.project(records.position)
    zpos = np.where(z > 1e-9, z, 1e-9)
    px = zpos / float(camera.fy)  # metres per pixel at the record
    r = np.clip(records.radius, 2 * kappa * min_px * px, 2 * kappa * max_px * px)
    return r, uv, z


def footprint_boxes(records: Records, camera: Camera, kappa: float, min_px: float,
                    max_px: float) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
    """Clamped ``R_i`` and the inclusive pixel box ``(c0, c1, r0, r1)`` of each footprint
    (pixels whose centres lie in the screen square of the disc ``R_i/(2κ)``), clipped to the
    image; empty boxes have ``c1 < c0`` or ``r1 < r0``."""
    w_img, h_img = camera.width, camera.height
    radius, uv, z = effective_radius(records, camera, kappa, min_px, max_px)
    r_px = radius / (2 * kappa) * float(camera.fy) / np.where(z > 1e-9, z, 1e-9)
    front = (z > 1e-9) & np.all(np.isfinite(uv), axis=1)
    c0 = np.floor(np.where(front, uv[:, 0] - r_px, 0.0) - 0.5).astype(np.int64) + 1
    c1 = np.floor(np.where(front, uv[:, 0] + r_px, -1.0) - 0.5).astype(np.int64)
    r0 = np.floor(np.where(front, uv[:, 1] - r_px, 0.0) - 0.5).astype(np.int64) + 1
    r1 = np.floor(np.where(front, uv[:, 1] + r_px, -1.0) - 0.5).astype(np.int64)
    c0, c1 = np.clip(c0, 0, w_img), np.clip(c1, -1, w_img - 1)
    r0, r1 = np.clip(r0, 0, h_img), np.clip(r1, -1, h_img - 1)
    return radius, (c0, c1, r0, r1)


def splat(records: Records, geom: SplatGeometry, camera: Camera, kappa: float,
          min_px: float, max_px: float) -> SplatBuffer:
    """Splat ``records`` into a new buffer (Kán §4.2.3, weights Eq. 2.15).

    Each record touches the pixels whose centres lie in the screen box of its footprint
    (clipped to the image); the weight is evaluated against those pixels' G-buffer position
    and normal and only ``w > 0`` is accumulated. Sums run in record order (``np.bincount``),
    so equal inputs give bitwise equal buffers.
    """
    w_img, h_img = geom.width, geom.height
    out = SplatBuffer.zeros(w_img * h_img)
    if len(records) == 0:
        return out
    radius, (c0, c1, r0, r1) = footprint_boxes(records, camera, kappa, min_px, max_px)
    bw = np.maximum(c1 - c0 + 1, 0)
    bh = np.maximum(r1 - r0 + 1, 0)
    area = bw * bh
    n_pix = w_img * h_img
    # chunks of whole records, each with at most ~_PAIR_CHUNK pairs (one big record alone)
    ends = np.cumsum(area)
    start = 0
    while start < len(records):
        base = ends[start - 1] if start else 0
        stop = max(int(np.searchsorted(ends, base + _PAIR_CHUNK, side="right")), start + 1)
        idx = np.arange(start, stop)
        counts = area[idx]
        rec = np.repeat(idx, counts)
        if len(rec):
            local = np.arange(len(rec)) - np.repeat(np.cumsum(counts) - counts, counts)
            col = c0[rec] + local % bw[rec]
            row = r0[rec] + local // bw[rec]
            pix = row * w_img + col
            ok = geom.valid[pix]
            rec, pix = rec[ok], pix[ok]
            w = tabellion_weight(geom.position[pix], geom.normal[pix], records.position[rec],
                                 records.normal[rec], radius[rec], kappa)
            pos = w > 0
            rec, pix, w = rec[pos], pix[pos], w[pos]
            out.weight += np.bincount(pix, weights=w, minlength=n_pix)
            w2 = w * w
            for c in range(3):
                out.w_mixed[:, c] += np.bincount(pix, weights=w * records.e_mixed[rec, c],
                                                 minlength=n_pix)
                out.w_delta[:, c] += np.bincount(pix, weights=w * records.e_delta[rec, c],
                                                 minlength=n_pix)
                out.w2_var_mixed[:, c] += np.bincount(
                    pix, weights=w2 * np.square(records.stderr_mixed[rec, c]), minlength=n_pix)
                out.w2_var_delta[:, c] += np.bincount(
                    pix, weights=w2 * np.square(records.stderr_delta[rec, c]), minlength=n_pix)
        start = stop
    return out


def splat_batches(records: Records, geom: SplatGeometry, camera: Camera, kappa: float,
                  min_px: float, max_px: float, splat_fn=None,
                  start: SplatBuffer | None = None) -> SplatBuffer:
    """:func:`splat` batch by batch (runs of equal ``records.batch``), the buffers added in
    order — bitwise the buffer the miss loop built when it splatted each new batch onto the
    previous ones, so a static scene's next frame splats the same bits without re-splatting
    the whole cache in a fixed order each frame. ``splat_fn``: :func:`splat` (default) or
    the Dr.Jit :func:`arlight.tracing.irradiance_splat.splat_dr`; ``start``: the buffer the
    batches are added to (default zeros)."""
    splat_fn = splat_fn or splat
    buf = start if start is not None else SplatBuffer.zeros(geom.width * geom.height)
    if len(records) == 0:
        return buf
    cuts = np.flatnonzero(np.diff(records.batch)) + 1
    for idx in np.split(np.arange(len(records)), cuts):
        buf = buf.add(splat_fn(records.take(idx), geom, camera, kappa, min_px, max_px))
    return buf


class TileScanner:
    """Cache-miss detection over the splat buffer (Kán §4.2.4).

    The buffer is cut into ``tile × tile`` pixel tiles; each keeps the position where its
    linear (row-major) scan stopped. :meth:`misses` returns, per tile, the first pixel from
    there on that needs irradiance and has zero accumulated weight — at most one new record
    per tile per iteration — and moves the tile's cursor to it (that pixel is covered once
    its record is splatted, so the next scan starts there); a tile with none is finished.
    """

    def __init__(self, width: int, height: int, tile: int):
        if tile < 1:
            raise ValueError(f"tile must be >= 1 px, got {tile}")
        self.width, self.height, self.tile = width, height, tile
        ty, tx = -(-height // tile), -(-width // tile)
        self.tiles = ty * tx
        # pixel index of every (tile, position-in-scan); -1 for padding beyond the image
        rr, cc = np.meshgrid(np.arange(ty * tile), np.arange(tx * tile), indexing="ij")
        pix = np.where((rr < height) & (cc < width), rr * width + cc, -1)
        self.order = pix.reshape(ty, tile, tx, tile).transpose(0, 2, 1, 3).reshape(
            self.tiles, tile * tile)
        self.cursor = np.zeros(self.tiles, np.int64)
        self.iterations = 0

    def misses(self, weight: np.ndarray, needs: np.ndarray) -> np.ndarray:
        """Pixel indices of new records (tile order), advancing the tiles' cursors."""
        self.iterations += 1
        ok = self.order >= 0
        safe = np.where(ok, self.order, 0)
        cand = ok & needs[safe] & (weight[safe] == 0)
        cand &= np.arange(self.order.shape[1])[None, :] >= self.cursor[:, None]
        has = cand.any(axis=1)
        first = np.argmax(cand, axis=1)
        self.cursor = np.where(has, first, self.order.shape[1])
        return self.order[has, first[has]]


def invalidate_near(records: Records, boxes: list[tuple[np.ndarray, np.ndarray]],
                    distance: float) -> np.ndarray:
    """Boolean (N,): records within ``distance`` (m) of any axis-aligned box ``(lo, hi)``
    (the moved objects' bounds before and after the move)."""
    hit = np.zeros(len(records), bool)
    for lo, hi in boxes:
        d = np.maximum(np.maximum(lo - records.position, records.position - hi), 0.0)
        hit |= np.linalg.norm(d, axis=1) <= distance
    return hit


__all__ = ["COS_10", "NORMAL_SCALE", "Records", "SplatBuffer", "SplatGeometry", "TileScanner",
           "effective_radius", "footprint_boxes", "invalidate_near", "splat", "splat_batches",
           "tabellion_weight"]
