"""Irradiance splatting in Dr.Jit: the fast path of :func:`arlight.tracing.irradiance_cache.
splat`, which it must match (Kán §4.2.3, Eq. 2.15, 4.11).

A GPU rasteriser scatters each record's quad into the pixels; float atomics would make the
sums depend on thread timing, so this gathers instead: the records are binned by the screen
bins (``bin_px`` square) their footprint boxes overlap (NumPy, a stable sort keeps record order
inside a bin), and one lane per pixel walks its bin's list in order, testing the record's box
and accumulating ``Σ w``, ``Σ w E_m``, ``Σ w E_d`` for ``w > 0`` — the same pairs and weights as
the NumPy reference, summed in the same order per pixel (float32), so equal inputs give
bitwise equal buffers.
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.rays import np3
from arlight.jit import aligned, columns, ensure_variant
from arlight.scene.camera import Camera
from arlight.tracing.irradiance_cache import (
    NORMAL_SCALE,
    Records,
    SplatBuffer,
    SplatGeometry,
    footprint_boxes,
)

BIN_PX = 8
"""Side of the screen bins records are sorted into, pixels."""


def _vec(cls, a: np.ndarray):
    return cls(*columns(a, np.float32))


def splat_dr(records: Records, geom: SplatGeometry, camera: Camera, kappa: float,
             min_px: float, max_px: float, bin_px: int = BIN_PX) -> SplatBuffer:
    """Splat ``records`` into a new buffer (float32 sums returned as float64)."""
    ensure_variant()
    w_img, h_img = geom.width, geom.height
    out = SplatBuffer.zeros(w_img * h_img)
    if len(records) == 0:
        return out
    radius, (c0, c1, r0, r1) = footprint_boxes(records, camera, kappa, min_px, max_px)
    keep = (c1 >= c0) & (r1 >= r0)
    nbx, nby = -(-w_img // bin_px), -(-h_img // bin_px)
    bx0, bx1 = c0 // bin_px, np.maximum(c1, c0) // bin_px
    by0, by1 = r0 // bin_px, np.maximum(r1, r0) // bin_px
    nbw = np.where(keep, bx1 - bx0 + 1, 0)
    nbh = np.where(keep, by1 - by0 + 1, 0)
    counts = nbw * nbh
    rec = np.repeat(np.arange(len(records)), counts)
    if len(rec) == 0:
        return out
    local = np.arange(len(rec)) - np.repeat(np.cumsum(counts) - counts, counts)
    bins = (by0[rec] + local // nbw[rec]) * nbx + bx0[rec] + local % nbw[rec]
    order = np.argsort(bins, kind="stable")
    rec_sorted, bins_sorted = rec[order], bins[order]
    starts = np.searchsorted(bins_sorted, np.arange(nbx * nby), side="left")
    ends = np.searchsorted(bins_sorted, np.arange(nbx * nby), side="right")

    pix = np.flatnonzero(geom.valid)
    col, row = pix % w_img, pix // w_img
    lane_bin = (row // bin_px) * nbx + col // bin_px
    busy = ends[lane_bin] > starts[lane_bin]  # lanes only for pixels in bins with records
    pix, col, row, lane_bin = pix[busy], col[busy], row[busy], lane_bin[busy]
    if len(pix) == 0:
        return out
    # aligned copies: one compiled kernel whatever the number of records (arlight.jit)
    j0 = mi.UInt32(aligned(starts[lane_bin], np.uint32))
    j1 = mi.UInt32(aligned(ends[lane_bin], np.uint32))
    colv, rowv = mi.Int32(aligned(col, np.int32)), mi.Int32(aligned(row, np.int32))
    x, n = _vec(mi.Point3f, geom.position[pix]), _vec(mi.Vector3f, geom.normal[pix])

    lst = mi.UInt32(aligned(rec_sorted, np.uint32))
    t_pos, t_nrm = _vec(mi.Point3f, records.position), _vec(mi.Vector3f, records.normal)
    t_em, t_ed = _vec(mi.Color3f, records.e_mixed), _vec(mi.Color3f, records.e_delta)
    t_vm = _vec(mi.Color3f, np.square(records.stderr_mixed))  # inf for one-ray records
    t_vd = _vec(mi.Color3f, np.square(records.stderr_delta))
    t_half_r = mi.Float(aligned(0.5 * radius, np.float32))
    t_box = [mi.Int32(aligned(b, np.int32)) for b in (c0, c1, r0, r1)]
    k = float(kappa)
    ns = float(NORMAL_SCALE / math.sqrt(2.0))
    m = len(pix)

    def cond(j, ws, wm, wd, vm, vd):
        return j < j1

    def body(j, ws, wm, wd, vm, vd):
        act = j < j1
        r = dr.gather(mi.UInt32, lst, j, act)
        a0, a1, b0, b1 = (dr.gather(mi.Int32, t, r, act) for t in t_box)
        act &= (colv >= a0) & (colv <= a1) & (rowv >= b0) & (rowv <= b1)
        xi = dr.gather(mi.Point3f, t_pos, r, act)
        ni = dr.gather(mi.Vector3f, t_nrm, r, act)
        hr = dr.gather(mi.Float, t_half_r, r, act)
        w = 1.0 - k * dr.maximum(dr.norm(x - xi) / hr, dr.norm(n - ni) * ns)
        act &= w > 0.0
        ws = ws + dr.select(act, w, 0.0)
        wm = wm + dr.select(act, w * dr.gather(mi.Color3f, t_em, r, act), 0.0)
        wd = wd + dr.select(act, w * dr.gather(mi.Color3f, t_ed, r, act), 0.0)
        vm = vm + dr.select(act, w * w * dr.gather(mi.Color3f, t_vm, r, act), 0.0)
        vd = vd + dr.select(act, w * w * dr.gather(mi.Color3f, t_vd, r, act), 0.0)
        return j + 1, ws, wm, wd, vm, vd

    zc = dr.zeros(mi.Color3f, m)
    _, ws, wm, wd, vm, vd = dr.while_loop(
        state=(mi.UInt32(j0), dr.zeros(mi.Float, m), zc, mi.Color3f(zc), mi.Color3f(zc),
               mi.Color3f(zc)), cond=cond, body=body, label="dic_splat")
    dr.eval(ws, wm, wd, vm, vd)
    out.weight[pix] = np.asarray(ws, np.float64)
    out.w_mixed[pix] = np3(wm)
    out.w_delta[pix] = np3(wd)
    out.w2_var_mixed[pix] = np3(vm)
    out.w2_var_delta[pix] = np3(vd)
    return out


__all__ = ["BIN_PX", "splat_dr"]
